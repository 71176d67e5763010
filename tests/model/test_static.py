"""Static-interval detection and block disturbance tests (canimucal.model.static)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation, Slerp
from scipy.stats import binom

from canimucal.errors import ModelError
from canimucal.model.frames import specific_force_level
from canimucal.model.sensor import DEFAULT_ACCEL_LSB
from canimucal.model.static import (
    StaticInterval,
    detect_disturbance,
    detect_static_intervals,
    disturbance_scores,
    moving_std,
)

FS = 100.0
XSENS = Path("/work/shared/data/imutk_xsens_acc.mat")
NOISE_COUNTS = 3.0


def synthetic_recording(
    seed: int, static_s: list[float], move_s: float = 1.5
) -> tuple[np.ndarray, list[tuple[int, int]]]:
    """Counts of static poses in random orientations joined by smooth (cosine-profile) turns.

    Returns ``(n, 3)`` accelerometer counts and the true static ``[start, stop)`` per pose.
    """
    rng = np.random.default_rng(seed)
    rots = Rotation.random(len(static_s), random_state=rng)
    f_level = specific_force_level(9.81)
    bias = rng.normal(0.0, 50.0, 3)
    pieces, truth, t0 = [], [], 0
    for i, seconds in enumerate(static_s):
        n = int(seconds * FS)
        pieces.append(np.tile(rots[i].apply(f_level), (n, 1)))
        truth.append((t0, t0 + n))
        t0 += n
        if i + 1 < len(static_s):
            m = int(move_s * FS)
            s = 0.5 - 0.5 * np.cos(np.pi * np.arange(1, m + 1) / (m + 1))
            turn = Slerp([0.0, 1.0], Rotation.concatenate([rots[i], rots[i + 1]]))(s)
            pieces.append(turn.apply(f_level))
            t0 += m
    f = np.vstack(pieces)
    counts = bias + f / DEFAULT_ACCEL_LSB + rng.normal(0.0, NOISE_COUNTS, f.shape)
    return counts, truth


POSES_S = [20.0, 3.0, 5.0, 8.0, 3.2, 6.0, 4.0, 10.0, 3.5, 7.0]


def test_finds_every_pose_of_a_synthetic_recording() -> None:
    """Ten poses of 3–20 s, two seeds: each found once, inside its true span give or take
    0.3 s (the slow ends of a cosine-profile turn look static), missing at most 1.2 s of it
    (half a window at each end, by design), and its mean within 0.5 count of the pose's true
    mean (σ of a mean ≈ 0.1–0.3 count: the detected ends add no visible motion)."""
    for seed in (1, 12):
        accel, truth = synthetic_recording(seed, POSES_S)
        found = detect_static_intervals(accel, FS)
        assert len(found) == len(truth)
        for got, (start, stop) in zip(found, truth, strict=True):
            assert start - 30 <= got.start and got.stop <= stop + 30, (got, start, stop)
            assert got.n >= (stop - start) - 120
            assert got.seconds(FS) == pytest.approx(got.n / FS)
            true_mean = accel[start:stop].mean(axis=0)
            assert np.all(np.abs(accel[got.start : got.stop].mean(axis=0) - true_mean) < 0.5)


def test_min_duration_drops_short_poses() -> None:
    accel, truth = synthetic_recording(2, POSES_S)
    found = detect_static_intervals(accel, FS, min_duration_s=4.5)
    # a pose is found when it lasts min_duration_s + window_s; none of POSES_S is within
    # 0.5 s of that edge
    assert len(found) == sum(1 for a, b in truth if (b - a) / FS - 1.0 >= 4.5)


def test_lost_samples_do_not_break_intervals() -> None:
    """1 % of rows lost: the same intervals are found (within 0.2 s at each end)."""
    accel, _ = synthetic_recording(3, POSES_S)
    clean = detect_static_intervals(accel, FS)
    holed = accel.copy()
    holed[np.random.default_rng(4).choice(len(accel), len(accel) // 100, replace=False)] = np.nan
    lossy = detect_static_intervals(holed, FS)
    assert len(lossy) == len(clean)
    for a, b in zip(clean, lossy, strict=True):
        assert abs(a.start - b.start) <= 20 and abs(a.stop - b.stop) <= 20


def test_gyro_motion_splits_an_interval_the_accelerometer_cannot_see() -> None:
    """A wobbling turn about the vertical leaves the accelerometer still; the gyro sees it."""
    rng = np.random.default_rng(5)
    n = 3000
    accel = np.array([10.0, -2000.0, 5.0]) + rng.normal(0.0, NOISE_COUNTS, (n, 3))
    gyro = rng.normal(0.0, 2.0, (n, 3))
    t = np.arange(1000) / FS
    gyro[1000:2000, 1] += 300.0 * np.sin(2 * np.pi * 0.5 * t)
    assert len(detect_static_intervals(accel, FS)) == 1
    split = detect_static_intervals(accel, FS, gyro=gyro)
    assert len(split) == 2
    assert split[0].stop <= 1000 + 10 and split[1].start >= 2000 - 10


def test_explicit_threshold_is_in_counts_of_total_moving_std() -> None:
    accel, _ = synthetic_recording(6, POSES_S)
    everything = detect_static_intervals(accel, FS, threshold=1e9)
    assert everything == [StaticInterval(0, len(accel))]
    assert detect_static_intervals(accel, FS, threshold=1e-3) == []


def test_moving_std_matches_direct_computation() -> None:
    x = np.random.default_rng(7).normal(0.0, [1.0, 2.0, 3.0], (500, 3)) + 1e4
    got = moving_std(x, 50)
    direct = [np.sqrt(np.sum(np.var(x[j : j + 50], axis=0, ddof=1))) for j in (0, 123, 450)]
    np.testing.assert_allclose(got[[0, 123, 450]], direct, rtol=1e-9)
    assert got.size == 451


def test_bad_input_raises_model_error() -> None:
    accel, _ = synthetic_recording(8, [3.0, 3.0])
    with pytest.raises(ModelError, match="sample_rate_hz"):
        detect_static_intervals(accel, -1.0)
    with pytest.raises(ModelError, match="window"):
        detect_static_intervals(accel[:50], FS)
    with pytest.raises(ModelError, match="gyro"):
        detect_static_intervals(accel, FS, gyro=accel[:10])
    with pytest.raises(ModelError, match="lost"):
        detect_static_intervals(np.full((500, 3), np.nan), FS)


@pytest.mark.skipif(not XSENS.exists(), reason=f"measured Xsens recording absent: {XSENS}")
def test_xsens_recording_has_its_hand_placed_poses() -> None:
    """imu_tk's Xsens set: ~50 s initial rest, then ~38 poses of 2–11 s (data/README.md)."""
    data = np.loadtxt(XSENS)
    found = detect_static_intervals(data[:, 1:], FS)
    assert 35 <= len(found) <= 45
    assert found[0].start < 100 and 45.0 <= found[0].seconds(FS) <= 55.0
    assert all(2.0 <= iv.seconds(FS) <= 14.0 for iv in found[1:])


def test_still_blocks_rarely_alarm() -> None:
    """2000 still blocks of 100 samples, six scores each at k = 5: per block the false-alarm
    chance is ≤ 3·1.4e-5 + 3·5.7e-7 = 4.4e-5 (χ² and normal tails), so ≥ 2 alarms has
    binomial probability 0.004."""
    rng = np.random.default_rng(9)
    sigma = np.array([3.0, 3.0, 4.0])
    alarms = 0
    for _ in range(2000):
        block = rng.normal(0.0, sigma, (100, 3))
        alarms += detect_disturbance(block, None, sigma, reference_mean_accel=np.zeros(3))
    assert binom.sf(1, 2000, 4.4e-5) < 0.005
    assert alarms <= 1


def test_motion_and_mean_shift_alarm() -> None:
    rng = np.random.default_rng(10)
    sigma = np.full(3, 3.0)
    block = rng.normal(0.0, sigma, (100, 3))
    assert not detect_disturbance(block, None, sigma, reference_mean_accel=np.zeros(3))
    bumped = block.copy()
    bumped[40:60, 0] += 30.0
    assert detect_disturbance(bumped, None, sigma)
    shifted = block + np.array([0.0, 0.0, 3.0])  # mean z = 3/(3/√100) = 10 ± 1
    assert not detect_disturbance(shifted, None, sigma)
    assert detect_disturbance(shifted, None, sigma, reference_mean_accel=np.zeros(3))
    gyro = rng.normal(0.0, 1.0, (100, 3))
    gyro[:, 2] += np.linspace(-10, 10, 100)
    assert detect_disturbance(block, gyro, sigma, np.ones(3))
    assert not detect_disturbance(block, gyro, sigma, None)


def test_scores_follow_their_formulas() -> None:
    rng = np.random.default_rng(11)
    block = rng.normal(1.0, 2.0, (50, 2))
    block[3] = np.nan
    scores = disturbance_scores(block, [2.0, 1.0], reference_mean=[0.0, 0.0], reference_n=200)
    rows = block[np.all(np.isfinite(block), axis=1)]
    n = rows.shape[0]
    var_z = (rows.var(axis=0, ddof=1) / np.array([4.0, 1.0]) - 1) * np.sqrt((n - 1) / 2)
    mean_z = np.abs(rows.mean(axis=0)) / (np.array([2.0, 1.0]) * np.sqrt(1 / n + 1 / 200))
    np.testing.assert_allclose(scores.variance_z, var_z)
    assert scores.mean_z is not None
    np.testing.assert_allclose(scores.mean_z, mean_z)
    assert scores.max_z == pytest.approx(max(var_z.max(), mean_z.max()))
    with pytest.raises(ModelError, match="reference_std"):
        disturbance_scores(block, [0.0, 1.0])
