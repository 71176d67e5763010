"""Traps of real logs (issue 21 items 9, 10): a file without gyro, samples logged repeatedly."""

from __future__ import annotations

import numpy as np
import pytest

from canimucal.analysis.repeats import repeated_rows, unique_samples
from canimucal.analysis.report import analyze
from canimucal.analysis.simulated import simulate_plan_recording
from canimucal.analysis.solve import solve_recording
from canimucal.analysis.static_noise import analyze_static
from canimucal.io.recording import Recording, recording_from_columns
from canimucal.model.positions import Plan, Pose, average_position
from canimucal.model.vocabulary.plans import RECOMMENDED
from canimucal.sim.truth import Truth
from tests.analysis.test_recording_analysis import SPREAD


def _truth(seed: int) -> Truth:
    return Truth.random(np.random.default_rng(seed), cross_axis_max=0.0, tilt_max_deg=0.0)


def _held(rec: Recording, times: int) -> Recording:
    """``rec`` as a logger polling ``times`` faster than the sensor samples would write it."""

    def rep(x: np.ndarray) -> np.ndarray:
        return np.repeat(x, times, axis=0)

    n = rec.n_rows * times
    header = dict(rec.header)
    header["sample_rate_hz"] = rec.sample_rate_hz * times
    return recording_from_columns(
        header,
        t=rec.t[0] + np.arange(n) / header["sample_rate_hz"],
        accel=rep(rec.accel),
        gyro=rep(rec.gyro),
        counter=np.arange(n) % 65536,
        position=rep(rec.position),
        alpha_deg=rep(rec.alpha_deg),
        beta_deg=rep(rec.beta_deg),
        psi_deg=rep(rec.psi_deg),
        temp_c=rep(rec.temp_c),
    )


def test_scalar_analysis_of_an_accelerometer_only_file() -> None:
    rec = simulate_plan_recording(_truth(2), SPREAD, seed=2)
    accel_only = recording_from_columns(
        {"sample_rate_hz": rec.sample_rate_hz, "g": rec.header["g"]}, t=rec.t, accel=rec.accel
    )
    a = analyze(accel_only)
    assert not a.session.known_positions and not a.session.has_gyro
    assert "gyro.bias[0]" not in a.result.base_values
    assert a.result.untestable["gyro_g_sensitivity"] == "no gyro data"
    k = np.diag(_truth(2).accel.K)
    got = np.array([a.result.base_values[f"accel.K[{i}][{i}]"] for i in range(3)])
    sig = np.array([a.result.base_sigmas[f"accel.K[{i}][{i}]"] for i in range(3)])
    assert np.all(np.abs(got - k) < 5 * sig)


@pytest.mark.parametrize("seed", [11, 12])
def test_repeated_samples_keep_the_sigma_of_the_unique_ones(seed: int) -> None:
    rec = simulate_plan_recording(_truth(seed), RECOMMENDED, seed=seed)
    held = _held(rec, 4)
    # taken as they are, the repeated rows make every σ of a mean about 2× too small
    rows = np.flatnonzero(held.position == 0)
    naive = average_position(Pose(0.0, 0.0), held.accel[rows])
    honest = average_position(Pose(0.0, 0.0), rec.accel[rec.position == 0])
    assert np.sqrt(np.diag(naive.cov_accel) / np.diag(honest.cov_accel)) == pytest.approx(
        0.5, rel=0.05
    )
    same, verdict = repeated_rows(held)
    assert verdict is not None and verdict.fraction == pytest.approx(0.75, abs=0.01)
    assert verdict.effective_hz == pytest.approx(rec.sample_rate_hz, rel=0.01)
    assert "75 % of samples repeat the previous one: effective rate ~200 Hz" in verdict.line()
    assert "1 of 4 unique samples" in verdict.line()
    reference = solve_recording(rec).solution
    solved = solve_recording(held)
    assert verdict.line() in solved.notes
    ratio = np.divide(solved.solution.record.accel.bias_sigma, reference.record.accel.bias_sigma)
    assert np.all(np.abs(ratio - 1.0) < 0.2), ratio
    a, b = analyze(held), analyze(rec)
    assert verdict.line() in a.notes and not b.notes
    for mine, theirs in zip(a.session.averages, b.session.averages, strict=True):
        within = np.sqrt(np.diag(mine.cov_accel) / np.diag(theirs.cov_accel))
        assert np.all(np.abs(within - 1.0) < 0.2), within
    for name, sigma in b.result.base_sigmas.items():
        assert a.result.base_sigmas[name] == pytest.approx(sigma, rel=0.2), name


def test_a_coarsely_quantised_quiet_sensor_is_not_taken_for_repeats() -> None:
    rec = simulate_plan_recording(_truth(13), RECOMMENDED, seed=13)
    coarse = recording_from_columns(
        rec.header, t=rec.t, accel=np.round(rec.accel / 16.0), gyro=np.round(rec.gyro / 16.0),
        position=rec.position, alpha_deg=rec.alpha_deg, beta_deg=rec.beta_deg,
        psi_deg=rec.psi_deg,
    )  # fmt: skip
    same, verdict = repeated_rows(coarse)
    assert same.mean() > 0.1  # the channels do repeat, each on its own
    assert verdict is None
    assert unique_samples(coarse)[0] is coarse


def test_allan_of_a_held_static_record_uses_the_unique_samples() -> None:
    truth = _truth(14)
    one_pose = Plan("custom", RECOMMENDED.positions[:1]).with_total_seconds(60.0)
    rec = simulate_plan_recording(truth, one_pose, seed=14)
    plain = analyze_static(rec)
    held = analyze_static(_held(rec, 4))
    assert held.warnings[0].startswith("75 % of samples repeat the previous one")
    assert held.sample_rate_hz == pytest.approx(plain.sample_rate_hz, rel=0.01)
    white = held.sensors["accel"].terms.white_noise_density
    assert white == pytest.approx(plain.sensors["accel"].terms.white_noise_density, rel=0.05)
