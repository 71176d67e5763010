"""The vehicle plan: tilts ≤ 10°, turns on the spot, and a stated prior on K.

Honest σ: over fixed seeds, with the truth K drawn from the stated prior and the angle
errors from the plan's tolerances, the errors divided by the reported σ have unit variance.
With N seeds × p parameters the mean of z² is χ²(N·p)/(N·p): for 40 × 8 = 320 values its
standard error is √(2/320) = 0.079, so [0.7, 1.3] is a ≈ 4σ band.
"""

from __future__ import annotations

import numpy as np
import pytest

from canimucal.errors import ModelError
from canimucal.model.joint import solve_joint
from canimucal.model.layout import JointSpec
from canimucal.model.plan import cramer_rao, plan_prior
from canimucal.model.sensor import DEFAULT_ACCEL_LSB, AccelParams
from canimucal.model.vocabulary.plans import VEHICLE, builtin_plan
from canimucal.sim.averages import simulate_averages

G = 9.80665
K_NOM = 1.0 / DEFAULT_ACCEL_LSB


def test_vehicle_plan_stays_within_ten_degrees_and_turns_on_the_spot() -> None:
    plan = builtin_plan("vehicle")
    assert plan is VEHICLE
    tilts = np.rad2deg([[p.alpha, p.beta] for p in plan.positions])
    assert np.max(np.abs(tilts)) <= 10.0 + 1e-9
    turns = sorted({round(float(np.rad2deg(p.psi))) for p in plan.positions})
    assert turns == [0, 90, 180, 270]
    assert all(
        p.psi_tolerance is not None and np.isclose(np.rad2deg(p.psi_tolerance), 5.0)
        for p in plan.positions
        if p.psi != 0.0
    )
    assert plan.operator_minutes > plan.total_seconds / 60.0


def test_without_its_prior_the_vehicle_plan_cannot_separate_bias_y_from_k_yy() -> None:
    bare = cramer_rao(VEHICLE, JointSpec(), include_tolerance=True, prior_sigma={})
    assert any(
        f.correlation is not None and set(f.parameters) == {"accel.bias[1]", "accel.K[1][1]"}
        for f in bare.separability.findings
    )
    held = cramer_rao(VEHICLE, JointSpec(), include_tolerance=True)
    assert held.bound("accel.K[1][1]").prior_sigma == pytest.approx(0.01 * K_NOM)
    assert held.bound("accel.bias[1]").prior_sigma is None
    # the prior bounds what the data cannot: bias y to about g·σ(K_yy) (+ the noise)
    assert held.bound("accel.bias[1]").effect_counts == pytest.approx(0.01 * 2048, rel=0.2)
    assert held.worst_case_counts < bare.worst_case_counts


def _trial(seed: int, spec: JointSpec) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    prior = plan_prior(VEHICLE, spec, DEFAULT_ACCEL_LSB)
    k = np.eye(3) * K_NOM
    for name, (mean, sigma) in prior.items():
        i, j = int(name[8]), int(name[11])
        k[i, j] = mean + rng.normal(0.0, sigma)
    bias = rng.normal(0.0, 20.0, 3)
    tilt = rng.normal(0.0, np.deg2rad(0.5), 2)
    averages = simulate_averages(
        VEHICLE.positions,
        AccelParams(bias, k),
        rng,
        g=G,
        alpha0=tilt[0],
        beta0=tilt[1],
        accel_noise_density=1.0,
    )
    res = solve_joint(averages, spec, g=G, prior=prior)
    truth = {f"accel.bias[{i}]": bias[i] for i in range(3)}
    truth |= {f"accel.K[{i}][{j}]": k[i, j] for i in range(3) for j in range(3)}
    truth |= {"base_tilt.alpha0": tilt[0], "base_tilt.beta0": tilt[1]}
    errors = np.array([res.value(n) - truth[n] for n in res.names])
    sigmas = np.array([res.sigma(n) for n in res.names])
    return errors, sigmas


@pytest.mark.parametrize("accel_k", ["diag", "full"])
def test_vehicle_plan_sigma_is_honest_over_seeds(accel_k: str) -> None:
    spec = JointSpec(accel_k=accel_k)  # type: ignore[arg-type]
    z = np.array([np.divide(*_trial(seed, spec)) for seed in range(40)])
    assert np.all(np.isfinite(z))
    assert 0.7 < float(np.mean(z**2)) < 1.3
    # and per parameter: no σ off by more than a factor 1.6 (χ²(40)/40 within [0.45, 1.75])
    per_parameter = np.mean(z**2, axis=0)
    assert np.all((per_parameter > 0.4) & (per_parameter < 2.5)), per_parameter


def test_prior_counts_in_chi2_and_dof_and_rejects_a_bad_sigma() -> None:
    spec = JointSpec()
    prior = plan_prior(VEHICLE, spec, DEFAULT_ACCEL_LSB)
    rng = np.random.default_rng(1)
    averages = simulate_averages(
        VEHICLE.positions, AccelParams(np.zeros(3), np.eye(3) * K_NOM), rng
    )
    with_prior = solve_joint(averages, spec, g=G, prior=prior)
    assert with_prior.dof == 8 * 3 + 3 - 8
    bad = {"accel.K[1][1]": (K_NOM, 0.0)}
    with pytest.raises(ModelError, match="σ > 0"):
        solve_joint(averages, spec, g=G, prior=bad)
