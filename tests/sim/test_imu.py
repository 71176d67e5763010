"""The sensor simulator: physics against the model, noise statistics, effects, schedules.

Statistical checks use fixed seeds and chi-square / normal bounds at a stated false-alarm
probability, so they do not flake; each threshold is computed, not guessed.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import stats

from canimucal.errors import InputError
from canimucal.model.frames import (
    TiltModel,
    earth_rate_level,
    position_dcm,
    specific_force_level,
)
from canimucal.model.positions import Plan, PlannedPosition
from canimucal.model.sensor import DEFAULT_GYRO_LSB, AccelParams, GyroParams
from canimucal.sim.imu import ImuSimulator, SimBlock, body_rate
from canimucal.sim.schedule import min_jerk
from canimucal.sim.truth import Truth

DEG = np.pi / 180.0
QUIET = {"noise_density": [0.0] * 3, "quantization": 0.0}


def _truth(accel: dict[str, Any] | None = None, gyro: dict[str, Any] | None = None, **top: Any):
    return Truth.from_dict({"accel": accel or {}, "gyro": gyro or {}, **top})


def _unit_truth(**extra: Any) -> Truth:
    """A unit with an inverted y accelerometer, cross-axis terms, G, tilt and heading."""
    accel = {
        "bias": [12.0, -30.0, 7.5],
        "K": [[207.0, 1.5, -0.8], [0.6, -212.0, 2.1], [-1.2, 0.4, 204.0]],
    }
    gyro = {
        "bias": [-20.0, 14.0, 33.0],
        "S": [[950.0, 3.0, -2.0], [1.0, 925.0, 4.0], [-5.0, 2.0, -940.0]],
        "G": [[0.2, -0.1, 0.0], [0.05, 0.3, -0.2], [0.0, 0.1, -0.15]],
    }
    for key in ("accel", "gyro"):
        (accel if key == "accel" else gyro).update(extra.pop(key, {}))
    doc = {
        "accel": accel,
        "gyro": gyro,
        "latitude_deg": 37.0,
        "heading_deg": 25.0,
        "base_tilt_deg": {"alpha0": 0.8, "beta0": -0.6},
    }
    return Truth.from_dict({**doc, **extra})


def _expected(truth: Truth, alpha: float, beta: float, psi: float) -> tuple[np.ndarray, ...]:
    """Noise-free outputs from the model types and the frames (independent of the sim)."""
    c = position_dcm(alpha, beta, psi, truth.alpha0, truth.beta0, truth.tilt_model, truth.trim)
    f = c @ specific_force_level(truth.g)
    w = c @ earth_rate_level(truth.latitude, truth.heading)
    accel = AccelParams(np.array(truth.accel.bias), np.array(truth.accel.K))
    gyro = GyroParams(np.array(truth.gyro.bias), np.array(truth.gyro.S), np.array(truth.gyro.G))
    return accel.output(f), gyro.output(w, f), f


def _static(truth: Truth, pose: tuple[float, float, float], n: int, seed: int = 0) -> SimBlock:
    sim = ImuSimulator(truth, seed=seed)
    sim.set_pose(*pose, transient_s=0.0)
    return sim.next_block(n)


def _chi2_bounds(dof: int, p: float = 1e-6) -> tuple[float, float]:
    """Two-sided chi-square acceptance interval with false-alarm probability ``p``."""
    return float(stats.chi2.ppf(p / 2, dof)), float(stats.chi2.ppf(1 - p / 2, dof))


# --- static physics -------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("tilt_model", "trim_deg"),
    [("rigid", [0, 0, 0]), ("additive", [0, 0, 0]), ("rigid", [1.5, -2.0, 3.0])],
)
def test_noise_free_static_output_is_the_model(tilt_model: str, trim_deg: list[float]) -> None:
    truth = _unit_truth(accel=QUIET, gyro=QUIET, tilt_model=tilt_model, mounting_trim_deg=trim_deg)
    pose = (30 * DEG, -10 * DEG, 40 * DEG)
    block = _static(truth, pose, 10)
    u, v, _ = _expected(truth, *pose)
    np.testing.assert_allclose(block.accel, np.tile(u, (10, 1)), rtol=0, atol=1e-9)
    np.testing.assert_allclose(block.gyro, np.tile(v, (10, 1)), rtol=0, atol=1e-9)
    assert not block.saturated.any() and not block.moving.any()
    assert (block.position_index == -1).all()


def test_design_anchor_and_inverted_axis() -> None:
    truth = _truth({"nominal_lsb": 0.01, "K": np.diag([100.0, -100.0, 100.0]).tolist(), **QUIET})
    block = _static(truth, (90 * DEG, 0.0, 0.0), 1)
    # docs/design.md §2 anchor C(90°,0,0) f_L = [-g, 0, 0]; the inverted y axis reads 0 either way.
    np.testing.assert_allclose(block.accel[0], [-100 * truth.g, 0, 0], atol=1e-9)
    level = _static(truth, (0.0, 0.0, 0.0), 1)
    np.testing.assert_allclose(level.accel[0], [0, 100 * truth.g, 0], atol=1e-9)


def test_static_means_agree_with_model_within_sigma_over_seeds() -> None:
    truth = _unit_truth(sample_rate_hz=200)
    pose = (22.5 * DEG, 2.5 * DEG, -30 * DEG)
    u, v, _ = _expected(truth, *pose)
    sigma = np.concatenate(
        [
            truth.accel.noise_density * np.sqrt(200) * np.abs(np.diag(truth.accel.K)),
            truth.gyro.noise_density * np.sqrt(200) * np.abs(np.diag(truth.gyro.S)),
        ]
    )
    sigma = np.sqrt(sigma**2 + 1.0 / 12.0)  # plus rounding to 1 count (σ ≫ 1 count: dithered)
    n, seeds = 400, range(40)
    z = np.array(
        [
            (np.hstack([b.accel.mean(0), b.gyro.mean(0)]) - np.hstack([u, v]))
            / (sigma / np.sqrt(n))
            for b in (_static(truth, pose, n, seed) for seed in seeds)
        ]
    )
    lo, hi = _chi2_bounds(z.size)  # Σz² ~ χ²(240) if the means are right and σ is right
    assert lo < np.sum(z**2) < hi
    # 240 z-scores: P(any |z| > 5) = 240 · 5.7e-7 ≈ 1.4e-4
    assert np.max(np.abs(z)) < 5.0


# --- noise and effects ----------------------------------------------------------------------


def test_white_noise_per_sample_std_is_input_referred() -> None:
    density_a, density_g = [1e-3, 2e-3, 3e-3], [1e-4, 2e-4, 5e-5]
    truth = _unit_truth(
        sample_rate_hz=500,
        accel={"noise_density": density_a, "quantization": 0.0},
        gyro={"noise_density": density_g, "quantization": 0.0},
    )
    n = 20000
    block = _static(truth, (10 * DEG, 5 * DEG, 0.0), n, seed=3)
    expected = np.concatenate(
        [
            np.array(density_a) * np.sqrt(500) * np.abs(np.diag(truth.accel.K)),
            np.array(density_g) * np.sqrt(500) * np.abs(np.diag(truth.gyro.S)),
        ]
    )
    var = np.hstack([block.accel, block.gyro]).var(axis=0, ddof=1)
    lo, hi = _chi2_bounds(n - 1, p=1e-6)  # (n-1)s²/σ² ~ χ²(n-1): ±3.5 % at n = 20000
    ratio = (n - 1) * var / expected**2
    assert np.all((lo < ratio) & (ratio < hi)), ratio / (n - 1)


def test_quantization_steps() -> None:
    pose = (15 * DEG, 3 * DEG, 0.0)
    ones = _static(_truth(), pose, 200)
    np.testing.assert_array_equal(ones.accel, np.round(ones.accel))
    np.testing.assert_array_equal(ones.gyro, np.round(ones.gyro))
    halves = _static(_truth({"quantization": 0.5}, {"quantization": 0.25}), pose, 200)
    np.testing.assert_array_equal(halves.accel * 2, np.round(halves.accel * 2))
    np.testing.assert_array_equal(halves.gyro * 4, np.round(halves.gyro * 4))
    assert len(np.unique(halves.accel % 1.0)) == 2  # both .0 and .5 occur
    raw = _static(_truth({"quantization": 0.0}, {"quantization": 0.0}), pose, 200)
    assert np.mean(raw.accel != np.round(raw.accel)) > 0.99


def test_saturation_clips_to_int16_and_flags() -> None:
    truth = _truth({"bias": [40000.0, 0, 0]}, {"bias": [0, 0, -40000.0]})
    block = _static(truth, (0.0, 0.0, 0.0), 50)
    assert block.saturated.all()
    assert (block.accel[:, 0] == 32767).all() and (block.gyro[:, 2] == -32768).all()
    assert not _static(_truth(), (0.0, 0.0, 0.0), 50).saturated.any()
    # bias at the limit, level pose (f_x = 0), σ ≈ 4.4 counts: clipped iff noise rounds > 0.
    edge = _static(_truth({"bias": [32767.0, 0, 0]}), (0.0, 0.0, 0.0), 2000, seed=5)
    assert (edge.accel[edge.saturated, 0] == 32767).all()
    assert (edge.accel[:, 0] <= 32767).all() and (edge.accel[:, 0] >= 32767 - 40).all()
    p = stats.norm.sf(0.5 / (1.5e-3 * np.sqrt(200) * 2048 / 9.80665))  # P(x > 32767.5)
    lo, hi = stats.binom.ppf([1e-6, 1 - 1e-6], 2000, p)
    assert lo <= edge.saturated.sum() <= hi


def test_random_walk_variance_grows_linearly_with_time() -> None:
    q = np.array([2.0, 0.5, 1.0, 0.3, 1.5, 0.8])  # counts/√s, accel then gyro
    quiet = {"noise_density": [0.0] * 3, "quantization": 0.0}
    truth = _truth(
        {**quiet, "random_walk": q[:3].tolist()},
        {**quiet, "random_walk": q[3:].tolist()},
        sample_rate_hz=50,
    )
    sim = ImuSimulator(truth, seed=11)
    x = np.vstack(
        [np.hstack([b.accel, b.gyro]) for b in (sim.next_block(10000) for _ in range(20))]
    )
    x = x - x[0]  # static pose: everything but the walk is constant
    for lag_s in (1.0, 16.0):
        lag = int(lag_s * 50)
        d = x[lag::lag] - x[:-lag:lag]  # non-overlapping increments: independent N(0, q² lag)
        chi = np.sum(d**2, axis=0) / (q**2 * lag_s)
        lo, hi = _chi2_bounds(d.shape[0])
        assert np.all((lo < chi) & (chi < hi)), (lag_s, chi / d.shape[0])


def test_gauss_markov_bias_is_stationary_with_its_correlation_time() -> None:
    b = np.array([3.0, 1.0, 2.0, 0.5, 4.0, 1.5])  # counts
    tau_s = 0.5
    quiet = {"noise_density": [0.0] * 3, "quantization": 0.0, "correlation_time_s": [tau_s] * 3}
    truth = _truth(
        {**quiet, "bias_instability": b[:3].tolist()},
        {**quiet, "bias_instability": b[3:].tolist()},
        sample_rate_hz=100,
    )
    _, v, _ = _expected(truth, 0.0, 0.0, 0.0)
    u, _, _ = _expected(truth, 0.0, 0.0, 0.0)
    sim = ImuSimulator(truth, seed=17)
    blocks = [sim.next_block(10000) for _ in range(30)]  # 3000 s
    m = np.vstack([np.hstack([bl.accel - u, bl.gyro - v]) for bl in blocks])
    every = int(10 * tau_s * 100)  # 10 τ apart: correlation e^-10 ≈ 5e-5, independent
    pick = m[::every]
    lo, hi = _chi2_bounds(pick.shape[0])  # Σm²/B² ~ χ²(600), first sample included
    chi = np.sum(pick**2, axis=0) / b**2
    assert np.all((lo < chi) & (chi < hi)), chi / pick.shape[0]
    k = int(tau_s * 100)  # lag τ: autocorrelation e^-1
    r = np.sum(m[k:] * m[:-k], axis=0) / np.sum(m**2, axis=0)
    # Bartlett: var r_k ≈ [(1+φ²)(1-φ^2k)/(1-φ²) - 2kφ^2k]/n = 1.0e-4 here -> σ ≈ 0.010;
    # 5σ = 0.05 (the estimator's bias, ~1/(n(1-φ)), is below 1e-3).
    assert np.all(np.abs(r - np.exp(-1.0)) < 0.05), r


def test_gauss_markov_bias_is_stationary_from_the_first_sample() -> None:
    b = np.array([3.0, 1.0, 2.0, 0.5, 4.0, 1.5])
    quiet = {"noise_density": [0.0] * 3, "quantization": 0.0, "correlation_time_s": [5.0] * 3}
    truth = _truth(
        {**quiet, "bias_instability": b[:3].tolist()},
        {**quiet, "bias_instability": b[3:].tolist()},
    )
    u, v, _ = _expected(truth, 0.0, 0.0, 0.0)
    seeds = range(300)
    first = np.array(
        [
            np.hstack([blk.accel[0] - u, blk.gyro[0] - v])
            for blk in (ImuSimulator(truth, seed=s).next_block(1) for s in seeds)
        ]
    )
    lo, hi = _chi2_bounds(len(seeds))  # Σm₀²/B² ~ χ²(300) over seeds if m starts stationary
    chi = np.sum(first**2, axis=0) / b**2
    assert np.all((lo < chi) & (chi < hi)), chi / len(seeds)


def test_temperature_slope_of_the_bias() -> None:
    tc_a, tc_g = [2.0, -1.0, 0.5], [0.3, 0.0, -0.7]
    truth = _truth(
        {"temp_coeff": tc_a, "quantization": 0.0},
        {"temp_coeff": tc_g, "quantization": 0.0},
        sample_rate_hz=50,
        temperature={"start_c": 20.0, "rate_c_per_s": 0.05},
    )
    block = _static(truth, (0.0, 0.0, 0.0), 10000, seed=2)  # 200 s: +10 °C
    np.testing.assert_allclose(block.temp_c, 20.0 + 0.05 * block.t_s, rtol=0, atol=1e-12)
    y = np.hstack([block.accel, block.gyro])
    t = block.t_s - block.t_s.mean()
    slope = (t @ (y - y.mean(0))) / (t @ t)
    resid = y - y.mean(0) - np.outer(t, slope)
    sigma_slope = resid.std(axis=0, ddof=2) / np.sqrt(t @ t)
    z = (slope - 0.05 * np.array(tc_a + tc_g)) / sigma_slope
    assert np.all(np.abs(z) < 5.0), z  # 6 normal z-scores: P(any > 5) ≈ 3.4e-6


def test_temperature_profile_drives_output_exactly() -> None:
    profile = [[0.0, 20.0], [2.0, 30.0], [4.0, 25.0]]
    truth = _unit_truth(
        accel={**QUIET, "temp_coeff": [1.0, -2.0, 0.5]},
        gyro={**QUIET, "temp_coeff": [0.0, 3.0, -1.0]},
        sample_rate_hz=50,
        temperature={"start_c": 99.0, "profile": profile},
    )
    block = _static(truth, (0.0, 0.0, 0.0), 300)
    temp = np.interp(block.t_s, *np.array(profile).T)
    np.testing.assert_allclose(block.temp_c, temp)
    u, v, _ = _expected(truth, 0.0, 0.0, 0.0)
    np.testing.assert_allclose(block.accel - u, np.outer(temp - 20.0, [1.0, -2.0, 0.5]), atol=1e-9)
    np.testing.assert_allclose(block.gyro - v, np.outer(temp - 20.0, [0.0, 3.0, -1.0]), atol=1e-9)


def test_quadratic_acts_on_each_axis_own_specific_force() -> None:
    quad = [0.5, -0.2, 2.0]
    truth = _unit_truth(accel={**QUIET, "quadratic": quad}, gyro=QUIET)
    pose = (35 * DEG, 12 * DEG, 0.0)
    u, _, f = _expected(truth, *pose)
    block = _static(truth, pose, 3)
    np.testing.assert_allclose(block.accel[0], u + np.array(quad) * f**2, rtol=0, atol=1e-9)
    assert np.all(np.abs(np.array(quad) * f**2) > 1.0)  # the effect is visible on every axis


def test_tilt_models_differ_only_when_beta0_is_not_zero() -> None:
    pose = (45 * DEG, 5 * DEG, 0.0)

    def accel(tilt_model: str, alpha0: float, beta0: float) -> np.ndarray:
        t = _truth(
            QUIET,
            QUIET,
            tilt_model=tilt_model,
            base_tilt_deg={"alpha0": alpha0, "beta0": beta0},
        )
        return _static(t, pose, 1).accel[0]

    np.testing.assert_allclose(accel("rigid", 0.7, 0.0), accel("additive", 0.7, 0.0), atol=1e-9)
    diff = accel("rigid", 0.0, 1.0) - accel("additive", 0.0, 1.0)
    # At α0 = 0, from f = A2(β) A1(α) A2(β0) f_L against A2(β+β0) A1(α) f_L:
    # rigid − additive = g [sin α (1 − cos β0), sin β0 sin β (1 − cos α), sin β0 cos β (1 − cos α)]
    # (docs/method.md §1's first-order y and z terms, exact here; x is second order in β0).
    g, k = _truth().g, _truth().accel.K
    a, b, b0 = pose[0], pose[1], 1.0 * DEG
    df = g * np.array(
        [
            np.sin(a) * (1 - np.cos(b0)),
            np.sin(b0) * np.sin(b) * (1 - np.cos(a)),
            np.sin(b0) * np.cos(b) * (1 - np.cos(a)),
        ]
    )
    expected = k @ df
    np.testing.assert_allclose(diff, expected, rtol=1e-9, atol=1e-9)
    assert abs(diff[2]) > 5.0  # counts: clearly visible


# --- motion, schedules ----------------------------------------------------------------------


def _plan(*rows: tuple[float, float, float, float]) -> Plan:
    return Plan(
        "custom",
        tuple(PlannedPosition(a * DEG, b * DEG, p * DEG, seconds=s) for a, b, p, s in rows),
    )


def _run(sim: ImuSimulator, seconds: float, chunk: int = 37) -> SimBlock:
    n_total = int(round(seconds * sim.sample_rate_hz))
    blocks = []
    while n_total > 0:
        blocks.append(sim.next_block(min(chunk, n_total)))
        n_total -= chunk
    fields = ("t_s", "accel", "gyro", "temp_c", "saturated", "moving", "position_index")
    return SimBlock(**{f: np.concatenate([getattr(b, f) for b in blocks]) for f in fields})


def test_schedule_follows_plan_seconds_and_flags_transients() -> None:
    plan = _plan((10, 0, 0, 2.0), (20, 2, 0, 3.0), (20, 2, 90, 1.5))
    sim = ImuSimulator(_truth(sample_rate_hz=100), seed=1)
    sim.set_schedule(plan, transient_s=0.5)
    assert sim.moving and sim.current_position_index is None
    block = _run(sim, 10.0)
    for i, pos in enumerate(plan.positions):
        assert np.sum(block.position_index == i) == round(pos.seconds * 100)
    assert np.sum(block.moving) == 3 * 50  # three transitions of 0.5 s
    assert (block.position_index[block.moving] == -1).all()
    expected = np.repeat([-1, 0, -1, 1, -1, 2, -1], [50, 200, 50, 300, 50, 150, 200])
    np.testing.assert_array_equal(block.position_index, expected)
    assert sim.schedule_end_s == pytest.approx(8.0)
    assert not sim.moving and sim.current_position_index is None
    assert sim.pose.alpha == pytest.approx(20 * DEG) and sim.pose.psi == pytest.approx(90 * DEG)
    np.testing.assert_allclose(block.t_s, np.arange(1000) / 100.0, atol=1e-12)


def test_schedule_skips_the_first_move_when_already_there_and_reports_index() -> None:
    sim = ImuSimulator(_truth(sample_rate_hz=50), seed=1)
    sim.set_schedule(_plan((0, 0, 0, 1.0), (5, 0, 0, 1.0)), transient_s=0.4)
    assert sim.current_position_index == 0 and not sim.moving
    block = sim.next_block(50)
    assert (block.position_index == 0).all()
    assert sim.moving and sim.current_position_index is None
    sim.next_block(20)
    assert sim.current_position_index == 1 and sim.pose.alpha == pytest.approx(5 * DEG)


def test_set_pose_cancels_schedule_and_jumps_without_transient() -> None:
    sim = ImuSimulator(_truth(sample_rate_hz=50), seed=1)
    sim.set_schedule(_plan((10, 0, 0, 5.0)), transient_s=1.0)
    sim.next_block(10)
    sim.set_pose(0.1, 0.2, 0.3, transient_s=0.0)
    assert (sim.pose.alpha, sim.pose.beta, sim.pose.psi) == (0.1, 0.2, 0.3)
    assert sim.schedule_end_s is None
    block = sim.next_block(100)
    assert not block.moving.any() and (block.position_index == -1).all()


@pytest.mark.parametrize(
    ("target", "axis"),
    [((20.0, 0.0, 0.0), 2), ((0.0, -15.0, 0.0), 0), ((0.0, 0.0, 30.0), 1)],
)
def test_gyro_integral_over_a_transient_is_the_rotation_angle(
    target: tuple[float, float, float], axis: int
) -> None:
    """Positive alpha turns about +z, beta about +x, psi about +y (right-handed)."""
    truth = _truth(QUIET, QUIET, sample_rate_hz=1000)
    sim = ImuSimulator(truth, seed=0)
    alpha, beta, psi = (x * DEG for x in target)
    sim.set_pose(alpha, beta, psi, transient_s=0.8)
    block = _run(sim, 1.0, chunk=1000)
    rate = block.gyro * DEFAULT_GYRO_LSB  # S = I/lsb, no bias: rad/s
    angle = rate.sum(axis=0) / 1000.0  # the motion is smooth and zero at both ends
    expected = np.zeros(3)
    expected[axis] = target[np.argmax(np.abs(target))] * DEG
    # Earth rate over 1 s adds at most 7.3e-5 rad.
    np.testing.assert_allclose(angle, expected, atol=1e-4)
    assert block.moving.sum() == 800


@pytest.mark.parametrize("trim_deg", [[0, 0, 0], [2.0, -1.0, 3.0]])
def test_gyro_during_a_combined_move_matches_dcm_finite_differences(trim_deg: list[float]) -> None:
    truth = _unit_truth(accel=QUIET, gyro=QUIET, sample_rate_hz=1000, mounting_trim_deg=trim_deg)
    sim = ImuSimulator(truth, seed=0)
    sim.set_pose(30 * DEG, 10 * DEG, -20 * DEG, transient_s=0.0)
    sim.set_pose(-10 * DEG, 25 * DEG, 40 * DEG, transient_s=1.0)
    block = sim.next_block(1000)
    s = np.array(truth.gyro.S)
    w_meas = np.linalg.solve(
        s, (block.gyro - truth.gyro.bias - block_f(truth, block) @ truth.gyro.G.T).T
    ).T
    start, end = np.array([30, 10, -20]) * DEG, np.array([-10, 25, 40]) * DEG
    w_level = earth_rate_level(truth.latitude, truth.heading)
    for k in (150, 500, 777):
        h = 1e-6
        c = [_dcm_at(truth, start, end, block.t_s[k] + d) for d in (-h, 0.0, h)]
        skew = -((c[2] - c[0]) / (2 * h)) @ c[1].T  # [w]× from Ċ = −[w]× C
        w_fd = np.array([skew[2, 1], skew[0, 2], skew[1, 0]]) + c[1] @ w_level
        np.testing.assert_allclose(w_meas[k], w_fd, rtol=0, atol=1e-7)


def block_f(truth: Truth, block: SimBlock) -> np.ndarray:
    """Specific force recovered from the noise-free accelerometer output."""
    return np.linalg.solve(truth.accel.K, (block.accel - truth.accel.bias).T).T


def _dcm_at(truth: Truth, start: np.ndarray, end: np.ndarray, t: float) -> np.ndarray:
    s, _ = min_jerk(t / 1.0)
    a = start + (end - start) * float(s)
    return position_dcm(a[0], a[1], a[2], truth.alpha0, truth.beta0, truth.tilt_model, truth.trim)


@settings(derandomize=True, deadline=None, max_examples=40)
@given(
    st.lists(st.floats(-1.5, 1.5), min_size=3, max_size=3),
    st.lists(st.floats(-2.0, 2.0), min_size=3, max_size=3),
    st.floats(-0.05, 0.05),
    st.sampled_from(["rigid", "additive"]),
)
def test_body_rate_is_minus_dcm_derivative_times_transpose(
    angles: list[float], rates: list[float], beta0: float, tilt_model: TiltModel
) -> None:
    a, r = np.array(angles), np.array(rates)
    alpha0 = 0.02

    def dcm(x: np.ndarray) -> np.ndarray:
        return position_dcm(x[0], x[1], x[2], alpha0, beta0, tilt_model)

    h = 1e-6
    skew = -((dcm(a + h * r) - dcm(a - h * r)) / (2 * h)) @ dcm(a).T
    np.testing.assert_allclose(skew, -skew.T, atol=1e-7)  # a rotation: skew-symmetric
    w_fd = np.array([skew[2, 1], skew[0, 2], skew[1, 0]])
    w = body_rate(a[None, :], r[None, :], beta0 if tilt_model == "additive" else 0.0)[0]
    np.testing.assert_allclose(w, w_fd, atol=1e-6)


# --- determinism, API -----------------------------------------------------------------------


def _drifting_truth() -> Truth:
    drift = {"random_walk": [0.5] * 3, "bias_instability": [2.0] * 3, "quantization": 0.0}
    return _unit_truth(accel=drift, gyro={**drift, "correlation_time_s": [0.3] * 3})


def test_same_seed_same_samples_and_block_split_invariance() -> None:
    plan = _plan((10, 0, 0, 0.5), (20, 5, 0, 0.5))

    def run(seed: int, chunks: list[int]) -> np.ndarray:
        sim = ImuSimulator(_drifting_truth(), seed=seed)
        sim.set_schedule(plan, transient_s=0.3)
        blocks = [sim.next_block(n) for n in chunks]
        return np.vstack([np.hstack([b.accel, b.gyro]) for b in blocks])

    a = run(42, [300])
    np.testing.assert_array_equal(a, run(42, [300]))
    np.testing.assert_allclose(a, run(42, [1, 16, 17, 66, 200]), rtol=0, atol=1e-8)
    assert np.mean(a != run(43, [300])) > 0.9


def test_sample_rate_change_and_bad_arguments() -> None:
    sim = ImuSimulator(_truth(sample_rate_hz=200), seed=0)
    assert sim.sample_rate_hz == 200.0
    sim.next_block(100)
    assert sim.time_s == pytest.approx(0.5)
    sim.set_sample_rate(1000)
    block = sim.next_block(10)
    np.testing.assert_allclose(np.diff(block.t_s), 1e-3)
    assert block.t_s[0] == pytest.approx(0.5) and sim.time_s == pytest.approx(0.51)
    assert len(sim.next_block(0)) == 0
    with pytest.raises(InputError, match="sample rate"):
        sim.set_sample_rate(120)
    with pytest.raises(InputError, match="block size"):
        sim.next_block(-1)
    with pytest.raises(InputError, match="transient_s"):
        sim.set_pose(0.0, 0.0, transient_s=-1.0)
    with pytest.raises(InputError, match="seconds"):
        sim.set_schedule(_plan((0, 0, 0, 0.0)))
    with pytest.raises(InputError, match="no positions"):
        sim.set_schedule(Plan("custom", ()))
