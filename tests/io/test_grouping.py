"""Grouping a recording's rows into per-position averages."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from canimucal.errors import InputError
from canimucal.io.grouping import (
    has_angles,
    position_averages,
    position_labels,
    position_parts,
    position_rows,
    rows_count,
    rows_where,
)
from canimucal.io.recording import Recording, recording_from_columns
from canimucal.model.frames import position_dcm, specific_force_level
from canimucal.model.sensor import AccelParams

G = 9.80665
POSES_DEG = [(0.0, 0.0, 0.0), (22.5, 2.5, 0.0), (45.0, 5.0, 90.0)]


def _static_recording(rng: np.random.Generator, per_position: int = 400) -> Recording:
    """Motion rows (no label) between three static positions; accel from the sensor model."""
    accel_params = AccelParams(np.array([3.0, -7.0, 11.0]), np.diag([208.8, -209.0, 209.5]))
    acc: list[np.ndarray] = []
    temp: list[np.ndarray] = []
    pos: list[int] = []
    ang: list[tuple[float, float, float]] = []
    for label, (a, b, p) in enumerate(POSES_DEG):
        f = position_dcm(*np.deg2rad([a, b, p])) @ specific_force_level(G)
        acc.append(accel_params.output(f) + rng.normal(0, 2.0, (per_position, 3)))
        pos += [label] * per_position
        ang += [(a, b, p)] * per_position
        temp.append(np.full(per_position, 25.0 + label))
        moving = 50
        acc.append(rng.normal(0, 500, (moving, 3)))
        pos += [-1] * moving
        ang += [(np.nan,) * 3] * moving
        temp.append(np.full(moving, np.nan))
    n = len(pos)
    t = 1.7e9 + np.arange(n) / 200.0
    angles = np.array(ang)
    return recording_from_columns(
        {"sample_rate_hz": 200.0},
        t=t,
        accel=np.vstack(acc),
        gyro=rng.normal(0, 3, (n, 3)),
        counter=np.arange(n) % 65536,
        position=pos,
        alpha_deg=angles[:, 0],
        beta_deg=angles[:, 1],
        psi_deg=angles[:, 2],
        temp_c=np.concatenate(temp),
    )


def test_averages_follow_the_labels() -> None:
    rec = _static_recording(np.random.default_rng(10))
    averages = position_averages(rec, tolerance_deg=0.2)
    assert position_labels(rec) == [0, 1, 2]
    assert has_angles(rec)
    for label, avg in enumerate(averages):
        rows = rec.position == label
        np.testing.assert_allclose(avg.mean_accel, rec.accel[rows].mean(axis=0), rtol=1e-12)
        np.testing.assert_allclose(avg.pose.angles, np.deg2rad(POSES_DEG[label]), rtol=1e-15)
        assert avg.pose.tolerance == pytest.approx(np.deg2rad(0.2))
        assert avg.n == 400 and avg.seconds == pytest.approx(2.0)
        assert avg.temp_c == pytest.approx(25.0 + label)
        assert avg.lost == 0
        assert avg.mean_gyro is not None


def test_means_agree_with_the_model_within_their_covariance() -> None:
    """χ² of (mean − truth) with the averages' own covariance over 3 positions × 40 seeds.

    120 draws of a χ²(3): the sum is χ²(360), mean 360, σ = √720 ≈ 26.8; the acceptance
    band 360 ± 4σ (253..467) fails a correct implementation with probability ~6e-5.
    """
    accel_params = AccelParams(np.array([3.0, -7.0, 11.0]), np.diag([208.8, -209.0, 209.5]))
    total = 0.0
    for seed in range(40):
        rec = _static_recording(np.random.default_rng(100 + seed), per_position=200)
        for label, avg in enumerate(position_averages(rec)):
            f = position_dcm(*np.deg2rad(POSES_DEG[label])) @ specific_force_level(G)
            r = avg.mean_accel - accel_params.output(f)
            total += float(r @ np.linalg.solve(avg.cov_accel, r))
    assert 253.0 < total < 467.0, total


def test_lost_counts_missing_halves_and_counter_gaps_but_not_motion() -> None:
    n = 12
    counter = np.array([65530, 65531, 65533, 65534, 0, 1, 2, 3, 10, 11, 12, 13], dtype=float)
    position = np.array([0, 0, 0, 0, 0, -1, -1, -1, 0, 0, 0, 0])
    accel = np.ones((n, 3))
    accel[9] = np.nan  # one accel half lost
    gyro = np.ones((n, 3))
    gyro[3] = np.nan  # one gyro half lost
    counter[10] = np.nan  # unknown counter: skipped, no run break
    zeros = np.zeros(n)
    rec = recording_from_columns(
        {"sample_rate_hz": 200.0},
        t=np.arange(n) / 200.0,
        accel=accel + np.arange(n)[:, None],
        gyro=gyro,
        counter=counter,
        position=position,
        alpha_deg=zeros,
        beta_deg=zeros,
        psi_deg=zeros,
    )
    (avg,) = position_averages(rec)
    # gaps: 65531→65533 skips 1, 65534→0 skips 65535 (wrap); 11→(empty)→13 skips none;
    # the motion rows 1..3 → 10 are not lost.
    assert avg.lost == 2 + 2
    assert avg.n == 8  # nine labelled rows, one without accel


def test_recording_without_gyro_loses_nothing_for_it() -> None:
    n = 10
    zeros = np.zeros(n)
    rec = recording_from_columns(
        {"sample_rate_hz": 100.0},
        t=np.arange(n) / 100.0,
        accel=np.random.default_rng(0).normal(size=(n, 3)),
        position=np.zeros(n),
        alpha_deg=zeros,
        beta_deg=zeros,
        psi_deg=zeros,
    )
    (avg,) = position_averages(rec)
    assert avg.lost == 0 and avg.mean_gyro is None and avg.temp_c is None


def test_missing_angles_need_the_scalar_methods() -> None:
    n = 10
    rec = recording_from_columns(
        {"sample_rate_hz": 100.0},
        t=np.arange(n) / 100.0,
        accel=np.random.default_rng(0).normal(size=(n, 3)),
        position=[0] * 5 + [1] * 5,
    )
    assert not has_angles(rec)
    with pytest.raises(InputError, match="position 0 has no angles"):
        position_averages(rec)
    averages = position_averages(rec, require_angles=False)
    assert len(averages) == 2 and np.isnan(averages[0].pose.alpha)


def test_no_labelled_position_and_too_few_samples() -> None:
    rec = recording_from_columns({"sample_rate_hz": 100.0}, t=[0.0, 0.01], accel=np.ones((2, 3)))
    assert not has_angles(rec)
    with pytest.raises(InputError, match="no labelled position"):
        position_averages(rec)
    one = recording_from_columns(
        {"sample_rate_hz": 100.0},
        t=[0.0],
        accel=np.ones((1, 3)),
        position=[3],
        alpha_deg=[1.0],
        beta_deg=[0.0],
        psi_deg=[0.0],
    )
    with pytest.raises(InputError, match="position 3: a position needs at least two"):
        position_averages(one)


def test_bad_tolerance() -> None:
    rec = _static_recording(np.random.default_rng(1), per_position=10)
    with pytest.raises(InputError, match="tolerance_deg"):
        position_averages(rec, tolerance_deg=-1.0)


def test_position_parts_are_slices_of_one_run_else_the_rows() -> None:
    rec = _static_recording(np.random.default_rng(3))
    every = np.arange(rec.n_rows)
    parts, labelled = position_parts(rec)
    rows, _ = position_rows(rec)
    assert labelled and all(isinstance(p, slice) for p in parts)
    assert all(np.array_equal(every[p], r) for p, r in zip(parts, rows, strict=True))
    position = rec.position.copy()
    position[np.flatnonzero(position == 2)[-30:]] = 1  # label 1 again after label 2
    redone = replace(rec, position=position)
    parts, _ = position_parts(redone)
    rows, _ = position_rows(redone)
    assert isinstance(parts[0], slice) and isinstance(parts[2], slice)
    assert isinstance(parts[1], np.ndarray) and rows_count(parts[1]) == 430
    assert all(np.array_equal(every[p], r) for p, r in zip(parts, rows, strict=True))


def test_rows_where_keeps_one_run_a_slice() -> None:
    every = np.arange(100)
    for rows in (slice(10, 30), np.arange(10, 30), np.r_[5:15, 40:50]):
        for mask in (np.ones(20, bool), np.arange(20) >= 6, np.arange(20) % 3 > 0):
            picked = rows_where(rows, mask)
            assert np.array_equal(every[picked], every[rows][mask])
            assert rows_count(picked) == int(mask.sum())
            one_run = np.all(np.diff(every[rows][mask]) == 1)
            assert isinstance(picked, slice) == bool(one_run)
