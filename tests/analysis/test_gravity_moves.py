"""Gyro S from moves known only through gravity: imu_tk's kind of session.

Simulated: a session of still poses in many orientations with its labels removed, so only
the static intervals and gravity's direction at each are known; S (scales ±3 %, cross-axis
±1 %) is recovered within 4σ through ``solve``'s path. Real: imu_tk's Xsens session
(skipped when ``../shared/data`` is absent). Its truth is unknown, so the check is on moves
the fit did not see: fitted to every other move, S must carry gravity through the other
moves far better than the best common scale factor does, and come out near the Xsens
factory calibration published with the data (scales within 1 %).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from canimucal.analysis.calibrate import solve_scalar
from canimucal.analysis.gravity_moves import recording_gravity_moves
from canimucal.analysis.session_model import ModelChoice
from canimucal.analysis.simulated import simulate_plan_recording
from canimucal.analysis.solve import _unknown_pose_averages, site_of, solve_recording
from canimucal.io.calibration import Device
from canimucal.io.importers import read_imutk
from canimucal.model.gravity_moves import gravity_angle_deg, solve_gravity_moves, start_scale
from canimucal.model.positions import Plan, PlannedPosition
from canimucal.sim.truth import Truth

DATA = Path(__file__).resolve().parents[3] / "shared" / "data"
ACC, GYR = DATA / "imutk_xsens_acc.mat", DATA / "imutk_xsens_gyro.mat"
XSENS_FACTORY_SCALE = np.array([4778.0, 4758.0, 4766.0])
"""The Xsens unit's factory gyro scale (counts per rad/s), published beside imu_tk's data."""

POSES_DEG = [
    (0, 0, 0), (60, 0, 0), (60, 60, 0), (0, 60, 0), (-60, 60, 0), (-60, 0, 0),
    (-60, -60, 0), (0, -60, 0), (60, -60, 0), (90, 30, 0), (30, 90, 0), (0, 0, 0),
]  # fmt: skip
"""Still poses whose moves turn about every horizontal direction (no angle is recorded)."""


def _unlabelled(seed: int) -> tuple[Truth, object]:
    truth = Truth.random(np.random.default_rng(seed), sample_rate_hz=100)
    plan = Plan(
        "custom",
        tuple(PlannedPosition(*np.deg2rad(p), np.deg2rad(0.1), 4.0) for p in POSES_DEG),
    )
    rec = simulate_plan_recording(truth, plan, seed=seed, transient_s=2.0)
    blank = np.full(rec.n_rows, np.nan)
    rec = dataclasses.replace(
        rec, position=np.full(rec.n_rows, -1), alpha_deg=blank, beta_deg=blank, psi_deg=blank
    )
    return truth, rec


@pytest.mark.parametrize("seed", [0, 1])
def test_s_from_gravity_only_moves_within_4_sigma(seed: int) -> None:
    truth, rec = _unlabelled(seed)
    solved = solve_recording(rec, ModelChoice(model="full", gyro="moves"))
    gyro = solved.record.gyro
    assert gyro is not None and gyro.S is not None
    S = np.array(gyro.S, dtype=float)
    sigma = np.array(gyro.S_sigma, dtype=float)
    assert np.all(np.isfinite(S)), solved.solution.warnings
    # gravity defines the frame through the accelerometer: the scalar fit's triangular K
    # is the truth's K turned by R (u = K_tri R f), so the gyro's S is seen as S_true Rᵀ
    k_fit = solved.record.accel.K_matrix(rec.header.get("accel_lsb"))
    u, _, vt = np.linalg.svd(np.linalg.solve(k_fit, truth.accel.K))
    rotation = u @ vt
    z = (S - truth.gyro.S @ rotation.T) / sigma
    assert np.max(np.abs(z)) < 4.0, np.round(z, 2)
    assert np.max(sigma / np.abs(np.diag(truth.gyro.S))) < 0.01


@pytest.mark.skipif(not (ACC.is_file() and GYR.is_file()), reason=f"no imu_tk data in {DATA}")
def test_imutk_session_held_out_moves_carry_gravity_after_calibration() -> None:
    rec = read_imutk(ACC, GYR)
    choice = ModelChoice(model="full", g=9.81744)  # the local gravity of the Xsens set
    site, _ = site_of(rec, choice)
    scalar = solve_scalar(_unknown_pose_averages(rec), site, Device(serial=0), full=True)
    found = recording_gravity_moves(rec, scalar.record.accel, site.accel_lsb)
    assert len(found.moves) >= 30 and not found.notes
    fitted, held_out = found.moves[0::2], found.moves[1::2]
    s0 = np.eye(3) / site.gyro_lsb
    fit = solve_gravity_moves(fitted, s0, found.rate_sigma_counts)
    assert fit.identifiable.all(), fit.notes
    common = start_scale(fitted, s0) * s0  # the best a single scale factor does
    before = np.array([gravity_angle_deg(m, common) for m in held_out])
    after = np.array([gravity_angle_deg(m, fit.S_used()) for m in held_out])
    rms_before, rms_after = np.sqrt(np.mean(before**2)), np.sqrt(np.mean(after**2))
    assert rms_after < 0.5 * rms_before and rms_after < 1.0, (rms_before, rms_after)
    scale = np.diag(fit.S)
    np.testing.assert_allclose(scale, XSENS_FACTORY_SCALE, rtol=0.01)
    cross = (fit.S - np.diag(scale)) / scale[None, :]
    assert np.max(np.abs(cross)) < 0.05  # misalignment of a few %, in the accelerometer's axes
