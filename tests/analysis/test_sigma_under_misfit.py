"""σ that survive misfit (issue 21 items 6, 7): Birge inflation, acceptance that says why."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from canimucal.analysis.acceptance import AcceptanceLimits, check_acceptance
from canimucal.analysis.calibrate import MISFIT_P
from canimucal.analysis.pose_scatter import accel_dof, with_tolerance
from canimucal.analysis.simulated import simulate_plan_recording
from canimucal.analysis.solve import solve_recording
from canimucal.io.grouping import position_averages
from canimucal.io.recording import Recording, recording_from_columns
from canimucal.model.joint import solve_joint
from canimucal.model.layout import JointSpec
from canimucal.model.vocabulary.plans import FIVE, RECOMMENDED
from canimucal.sim.truth import Truth


def _recording(seed: int, push_counts: float = 0.0) -> Recording:
    """The recommended plan, poses set exactly and said so (tolerance_deg 0 in the header);
    with ``push_counts`` every position's accelerometer pushed by ±that many counts per axis
    (an effect no model term describes)."""
    truth = Truth.random(np.random.default_rng(seed), cross_axis_max=0.0, tilt_max_deg=0.0)
    rec = simulate_plan_recording(truth, RECOMMENDED, seed=seed, angle_errors=False)
    accel = np.array(rec.accel)
    rng = np.random.default_rng(seed + 100)
    for k in np.unique(rec.position[rec.position >= 0]):
        accel[rec.position == k] += rng.choice([-push_counts, push_counts], 3)
    header = {**rec.header, "tolerance_deg": 0.0}
    return recording_from_columns(
        header, t=rec.t, accel=accel, gyro=rec.gyro, counter=rec.counter,
        position=rec.position, alpha_deg=rec.alpha_deg, beta_deg=rec.beta_deg,
        psi_deg=rec.psi_deg, temp_c=rec.temp_c,
    )  # fmt: skip


@pytest.mark.parametrize("seed", [3, 4])
def test_an_unmodelled_effect_inflates_the_sigma_and_fails_acceptance_with_the_reason(
    seed: int,
) -> None:
    clean = solve_recording(_recording(seed))
    quality = clean.solution.quality
    assert quality is not None and not quality.rejected and quality.inflation == 1.0
    assert clean.verdict is not None and clean.verdict.report.passed
    pushed = solve_recording(_recording(seed, push_counts=2.0))
    quality = pushed.solution.quality
    assert quality is not None and quality.rejected and quality.p_value < MISFIT_P
    assert quality.inflation == pytest.approx(np.sqrt(quality.chi2 / quality.dof))
    assert quality.inflation > 5.0
    ratio = np.divide(pushed.record.accel.bias_sigma, clean.record.accel.bias_sigma)
    assert np.allclose(ratio, quality.inflation, rtol=0.05), (ratio, quality.inflation)
    assert "the model does not fit, σ inflated ×" in quality.line()
    assert pushed.verdict is not None and not pushed.verdict.report.passed
    assert "model does not fit: χ²/dof " in pushed.verdict.text


def test_a_calibration_that_determined_nothing_never_passes() -> None:
    solved = solve_recording(_recording(5)).solution
    assert solved.joint is not None
    nothing = dataclasses.replace(
        solved, joint=dataclasses.replace(solved.joint, undetermined=dict.fromkeys(
            solved.joint.names, "not determined by these positions"))
    )  # fmt: skip
    report = check_acceptance(nothing, AcceptanceLimits(), 9.80665 / 2048.0, 9.81)
    assert not report.passed
    assert any(
        c.name == "accelerometer parameters determined" and not c.passed for c in report.checks
    )


def test_the_pose_scatter_counts_the_accelerometer_dof_only() -> None:
    spec = JointSpec(accel_k="diag", tilt="none", gyro="mems")
    # five positions: 15 accelerometer residuals less 6 parameters; the gyro's 15 add none
    assert accel_dof(len(FIVE.positions), spec) == 9
    assert accel_dof(len(RECOMMENDED.positions), spec) == 18


@pytest.mark.parametrize("tolerance_deg", [0.1, 0.6])
def test_a_precise_gyro_holds_nothing_of_the_accelerometer_at_nominal(
    tolerance_deg: float,
) -> None:
    """The five-position plan with full K and the tilt (1 accelerometer dof): with the gyro in
    the fit and a 0.6° scatter every accelerometer bias and K entry, and the tilt, used to be
    held at nominal (their information below 1e-10 of the gyro bias's at the effects' scale)
    while the same fit without the gyro held none; the rank is now judged at each parameter's
    own precision, and the gyro changes nothing about what the accelerometer determines."""
    truth = Truth.random(np.random.default_rng(0))
    rec = simulate_plan_recording(truth, FIVE, seed=0)
    averages = with_tolerance(position_averages(rec), float(np.deg2rad(tolerance_deg)))
    site = {
        "g": truth.g, "latitude": truth.latitude, "accel_lsb": truth.accel.nominal_lsb,
        "gyro_lsb": truth.gyro.nominal_lsb, "allow_undetermined": True,
        "unknown_earth_rate": True,
    }  # fmt: skip
    held = {}
    for gyro in ("none", "mems"):
        res = solve_joint(averages, JointSpec(accel_k="full", tilt="rigid", gyro=gyro), **site)
        held[gyro] = {n for n in res.undetermined if not n.startswith("gyro.")}
    assert held["mems"] == held["none"] == set(), held
