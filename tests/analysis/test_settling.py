"""Settling after each move against bias drift: the transient is trimmed, a walk is named."""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from canimucal.analysis.discrepancy import _drift_tests
from canimucal.analysis.drift import allan_walk_upper, drift_test
from canimucal.analysis.report import analyse_recording, analysis_document
from canimucal.analysis.settling import fit_settling, trim_mask
from canimucal.analysis.simulated import simulate_plan_recording
from canimucal.io.grouping import position_rows
from canimucal.io.recording import Recording
from canimucal.model.vocabulary.plans import RECOMMENDED
from canimucal.runtime.inputs import read_recording
from canimucal.sim.effects import hide_effect
from canimucal.sim.truth import Truth

Array = np.ndarray[Any, np.dtype[np.float64]]

DATA = Path(__file__).resolve().parents[3] / "shared" / "data"
HAND_HELD = (DATA / "imutk_xsens_acc.mat", DATA / "imutk_xsens_gyro.mat")


def _windows(rng: np.random.Generator, tau: float, amp: float, n_pos: int = 8) -> list[Any]:
    """Windows of 20 s at 100 Hz, white σ = 3, a transient of ``amp`` σ-units per axis."""
    out = []
    for p in range(n_pos):
        t = np.arange(2000) / 100.0 + 50.0 * p
        x = rng.normal(0.0, 3.0, (t.size, 3))
        if tau > 0:
            x += np.exp(-(t - t[0]) / tau)[:, None] * rng.normal(0.0, amp * 3.0, 3)
        out.append((t, x))
    return out


def test_settling_interval_covers_the_time_constant() -> None:
    # 40 seeds, nominal 95 %: fewer than 34 covered has binomial probability < 1 %
    rng = np.random.default_rng(140)
    fits = [fit_settling(_windows(rng, 1.5, 3.0)) for _ in range(40)]
    assert all(f.found for f in fits)
    covered = sum(f.tau_ci95_s[0] <= 1.5 <= f.tau_ci95_s[1] for f in fits)
    assert covered >= 34, covered
    assert all(np.all(f.trim_s >= 3 * f.tau_ci95_s[1]) for f in fits)


def test_white_noise_shows_no_settling() -> None:
    # α = 1 % per fit: 3 or more false alarms in 40 has binomial probability < 1 %
    rng = np.random.default_rng(141)
    found = [fit_settling(_windows(rng, 0.0, 0.0)).found for _ in range(40)]
    assert sum(found) <= 2


def test_trim_mask_keeps_the_tail_and_at_least_half() -> None:
    t = np.arange(100) / 10.0
    assert trim_mask(t, 2.0).sum() == 80
    assert trim_mask(t, 50.0).sum() == 50  # at most half the window (4.95 s) is cut
    assert trim_mask(t, 0.0).all()


def _doc(seed: int) -> dict[str, Any]:
    doc = Truth.random(np.random.default_rng(seed), cross_axis_max=0.0, tilt_max_deg=0.0)
    out = doc.to_dict()
    out["temperature"] = {"start_c": 25.0}
    return out


def _with_settling(rec: Recording, tau: float, amp: float, seed: int) -> Recording:
    """Add a decaying step of ``amp`` counts (random per axis) at every position's start."""
    rng = np.random.default_rng(seed)
    accel, gyro = rec.accel.copy(), rec.gyro.copy()
    for p in np.unique(rec.position[rec.position >= 0]):
        rows = np.flatnonzero(rec.position == p)
        e = np.exp(-(rec.t[rows] - rec.t[rows[0]]) / tau)[:, None]
        accel[rows] += e * rng.normal(0.0, amp, 3)
        gyro[rows] += e * rng.normal(0.0, amp, 3)
    return dataclasses.replace(rec, accel=accel, gyro=gyro)


def test_settling_after_moves_is_trimmed_not_called_drift() -> None:
    covered = 0
    for seed in (142, 143, 144, 145):
        clean = simulate_plan_recording(Truth.from_dict(_doc(seed)), RECOMMENDED, seed=seed)
        rec = _with_settling(clean, 2.0, 60.0, seed)
        # untrimmed, the transients make the within-position slopes fail the drift test
        rows, _ = position_rows(rec)
        assert drift_test([(rec.t[r], rec.accel[r]) for r in rows]).p_value < 1e-6
        a = analyse_recording(rec, g=9.81, tolerance_deg=0.1)
        assert "bias_drift" not in [f.effect for f in a.result.findings]
        assert not a.result.drift_found
        for sensor in ("accel", "gyro"):
            fit = a.session.settling[sensor]
            assert fit.found and fit.tau_s == pytest.approx(2.0, rel=0.02)
            covered += fit.tau_ci95_s[0] <= 2.0 <= fit.tau_ci95_s[1]
        assert any("settling after each move" in w for w in a.result.warnings)
        noise = analysis_document(a)["noise"]
        assert noise["settling"]["accel"]["found"] and noise["limiting_axis"][:5] in (
            "accel",
            "gyro.",
        )
        per_axis = noise["best_averaging_s_per_axis"]
        assert len(per_axis["accel"]) == 3
        # the headline is the largest per-axis optimum, never the Allan fit's unclipped 1e4
        assert noise["best_averaging_s"] == max(max(v) for v in per_axis.values()) <= 120.0
        assert not np.any(a.result.params.accel_random_walk)
        assert not np.any(a.result.params.gyro_random_walk)
    # 8 nominal 95 % intervals: fewer than 6 covering has binomial probability < 1 %
    assert covered >= 6, covered


@pytest.mark.parametrize("seed", [145, 146, 147])
def test_a_random_walk_is_named_bias_drift(seed: int) -> None:
    rng = np.random.default_rng(seed)
    doc, hidden = hide_effect(_doc(seed), "bias_drift", rng, {}, low=8.0, high=10.0)
    rec = simulate_plan_recording(Truth.from_dict(doc), RECOMMENDED, seed=seed)
    a = analyse_recording(rec, g=9.81, tolerance_deg=0.1)
    drift = [f for f in a.result.findings if f.effect == "bias_drift"]
    assert [f.sensor for f in drift] == ["accel"]
    axis = int(hidden.entry[-2])
    assert a.result.params.accel_random_walk[axis] == pytest.approx(hidden.size, rel=0.6)
    assert not a.session.settling["accel"].found


def test_hand_held_poses_give_no_bias_drift() -> None:
    """imu_tk's hand-placed Xsens poses: their trends are not a wandering bias.

    The file's ~50 s static start bounds the random walk (Allan, 95 %); the slopes inside the
    hand-held poses ask for a walk ≥ 9× that bound on accel z (the test's own check below),
    and none of it may be named ``bias_drift`` nor reach the truth file.
    """
    if not all(p.exists() for p in HAND_HELD):
        pytest.skip(f"imu_tk data absent ({HAND_HELD[0].parent})")
    rec = read_recording(HAND_HELD[0], second=HAND_HELD[1])
    static = max(position_rows(rec)[0], key=len)
    bound = allan_walk_upper([(rec.t[static], rec.accel[static])])
    a = analyse_recording(rec, g=9.81744)
    slopes = _drift_tests(a.session, None)["accel"]
    assert slopes.p_value < 1e-10
    assert np.max(slopes.random_walk / bound) > 5.0
    assert "bias_drift" not in [f.effect for f in a.result.findings]
    assert not np.any(a.result.params.accel_random_walk)
    assert not np.any(a.result.params.gyro_random_walk)
    # the trends put the tests on the fit's own residual scale (F); a finding's σ must be on
    # it too: one entry's Wald z² never exceeds its group's Wald q·F in the same model
    cross = next(f for f in a.result.findings if f.effect == "cross_axis")
    z = float(re.search(r"\(([0-9.]+)σ", cross.evidence).group(1))
    group = re.search(r"; F ([0-9.]+) on (\d+) dof$", cross.evidence)
    assert group, cross.evidence  # the group test carries this finding (docs/real-data.md)
    assert z * z <= 1.001 * float(group.group(1)) * int(group.group(2)), cross.evidence
