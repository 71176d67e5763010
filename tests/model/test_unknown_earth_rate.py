"""Without a latitude the Earth rate is a nuisance of the joint fit, and clean fits pass χ².

Offline draws (position averages straight from the sensor model, fixed seeds): a unit within
the plan's prior, a floor slope (base tilt) within ±3° about each axis, the operator's angle
errors from the plan's tolerances, the Earth rate of latitude 50.45° that the fit is not told.
Left out of the model, the Earth rate piles every χ² p-value near 0; fitted as a nuisance
(``unknown_earth_rate``), the p-values of 20 clean fits pass a Kolmogorov–Smirnov test of
uniformity and at most two fall below 0.01 (binomial chance of three or more: 1e-3).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.stats import chi2, kstest

from canimucal.model.joint import solve_joint
from canimucal.model.plan import plan_prior
from canimucal.model.sensor import AccelParams, GyroParams
from canimucal.model.vocabulary.plans import builtin_plan
from canimucal.runtime.wiring import spec_for_plan
from canimucal.sim.averages import simulate_averages

ACCEL_LSB, GYRO_LSB = 0.0047884033203125, 0.0010642251536550791
LATITUDE, G = np.deg2rad(50.45), 9.811
SEEDS = range(20)


def _p_values(plan_name: str, seconds: float, nuisance: bool) -> np.ndarray:
    plan = builtin_plan(plan_name)
    positions = [dataclasses.replace(p, seconds=seconds) for p in plan.positions]
    spec = spec_for_plan(plan_name, "mems")
    prior = plan_prior(plan, spec, ACCEL_LSB) if plan.prior_k_sigma else None
    spread = np.sqrt(3.0) * (plan.prior_k_sigma or 0.01)  # within the prior's own spread
    out = []
    for seed in SEEDS:
        rng = np.random.default_rng(seed)
        accel = AccelParams(
            rng.uniform(-50, 50, 3), (np.eye(3) + rng.uniform(-spread, spread, (3, 3))) / ACCEL_LSB
        )
        s = np.diag(1 + rng.uniform(-0.03, 0.03, 3)) / GYRO_LSB
        gyro = GyroParams(rng.uniform(-50, 50, 3), s, np.zeros((3, 3)))
        alpha0, beta0 = np.deg2rad(rng.uniform(-3.0, 3.0, 2))
        averages = simulate_averages(
            positions, accel, rng, g=G, gyro=gyro, latitude=LATITUDE, alpha0=alpha0,
            beta0=beta0, accel_noise_density=1.5e-3 / ACCEL_LSB,
            gyro_noise_density=1.2e-4 / GYRO_LSB,
        )  # fmt: skip
        result = solve_joint(
            averages, spec, g=G, latitude=None, accel_lsb=ACCEL_LSB, gyro_lsb=GYRO_LSB,
            allow_undetermined=True, prior=prior, unknown_earth_rate=nuisance,
        )  # fmt: skip
        out.append(chi2.sf(result.chi2, result.dof))
    return np.array(out)


@pytest.mark.parametrize(("plan_name", "seconds"), [("vehicle", 120.0), ("recommended", 60.0)])
def test_clean_fits_without_a_latitude_give_uniform_p_values(
    plan_name: str, seconds: float
) -> None:
    p = _p_values(plan_name, seconds, nuisance=True)
    assert kstest(p, "uniform").pvalue > 0.01, p
    assert np.sum(p < 0.01) <= 2, p


def test_left_out_the_earth_rate_fails_the_fit() -> None:
    p = _p_values("vehicle", 120.0, nuisance=False)
    assert np.all(p < 1e-3), p
