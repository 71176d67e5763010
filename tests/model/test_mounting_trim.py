"""Floor slope and mounting trim, told apart (docs/method.md §3, eq. T1–T4; issue 22 item 1).

Offline sweeps: per-position averages straight from the sensor model (the simulator's
physics, ``C = R_m · C_pose · T0``) through the joint fit a session runs, 20 fixed seeds per
plan, each with a floor slope within ±3° and a mounting trim within ±2° about each axis, the
operator's pose errors from the plan's tolerances and an Earth rate the fit is not told.

- Vehicle plan (K within its 1 % prior): slope and trim recovered within 4σ on every seed;
  Σz² of each over the seeds inside the χ² band (docs/design.md §8); the fits' χ² p-values
  uniform (Kolmogorov–Smirnov, and at most two below 0.01: a binomial chance of three or
  more of 1e-3).
- Recommended plan (full K): the trim is not identifiable beside a free K, which absorbs it:
  the fit's K is the unit's K·R_m within its σ (Mahalanobis over the nine entries, χ² band),
  the slope within 4σ, p-values uniform.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.stats import chi2, kstest

from canimucal.model.frames import trim_dcm
from canimucal.model.joint import JointResult, solve_joint
from canimucal.model.layout import TRIM_NAMES, JointSpec
from canimucal.model.plan import cramer_rao, plan_prior
from canimucal.model.sensor import AccelParams, GyroParams
from canimucal.model.vocabulary.plans import builtin_plan
from canimucal.runtime.wiring import spec_for_plan
from canimucal.sim.averages import simulate_averages
from tests.support.chi2_band import chi2_ratio_band, mahalanobis

ACCEL_LSB, GYRO_LSB = 0.0047884033203125, 0.0010642251536550791
LATITUDE, G = np.deg2rad(50.45), 9.811
SEEDS = range(20)
SLOPE_MAX_DEG, TRIM_MAX_DEG = 3.0, 2.0
SLOPE_NAMES = ("base_tilt.alpha0", "base_tilt.beta0")


@dataclasses.dataclass(frozen=True)
class Draw:
    """One seed's truth and the fit of its averages."""

    accel: AccelParams
    slope: np.ndarray
    trim: np.ndarray
    fit: JointResult

    @property
    def p_value(self) -> float:
        return float(chi2.sf(self.fit.chi2, self.fit.dof))

    def z(self, names: tuple[str, ...], truth: np.ndarray) -> np.ndarray:
        return np.array(
            [(self.fit.value(n) - t) / self.fit.sigma(n) for n, t in zip(names, truth, strict=True)]
        )


def _draw(plan_name: str, seed: int) -> Draw:
    plan = builtin_plan(plan_name)
    spec = spec_for_plan(plan_name, "mems")
    prior = plan_prior(plan, spec, ACCEL_LSB) if plan.prior_k_sigma else None
    spread = np.sqrt(3.0) * (plan.prior_k_sigma or 0.01)  # within the prior's own spread
    rng = np.random.default_rng(seed)
    k = (np.eye(3) + rng.uniform(-spread, spread, (3, 3))) / ACCEL_LSB
    accel = AccelParams(rng.uniform(-50, 50, 3), k)
    s = np.diag(1 + rng.uniform(-0.03, 0.03, 3)) / GYRO_LSB
    gyro = GyroParams(rng.uniform(-50, 50, 3), s, np.zeros((3, 3)))
    slope = np.deg2rad(rng.uniform(-SLOPE_MAX_DEG, SLOPE_MAX_DEG, 2))
    trim = np.deg2rad(rng.uniform(-TRIM_MAX_DEG, TRIM_MAX_DEG, 3))
    averages = simulate_averages(
        plan.positions, accel, rng, g=G, gyro=gyro, latitude=LATITUDE, alpha0=slope[0],
        beta0=slope[1], trim=trim, accel_noise_density=1.5e-3 / ACCEL_LSB,
        gyro_noise_density=1.2e-4 / GYRO_LSB,
    )  # fmt: skip
    fit = solve_joint(
        averages, spec, g=G, latitude=None, accel_lsb=ACCEL_LSB, gyro_lsb=GYRO_LSB,
        allow_undetermined=True, prior=prior, unknown_earth_rate=True,
    )  # fmt: skip
    return Draw(accel, slope, trim, fit)


def _uniform(p: np.ndarray) -> None:
    assert kstest(p, "uniform").pvalue > 0.01, p
    assert np.sum(p < 0.01) <= 2, p


def test_vehicle_plan_recovers_floor_slope_and_trim_within_their_sigma() -> None:
    draws = [_draw("vehicle", seed) for seed in SEEDS]
    assert all(d.fit.converged for d in draws)
    z = np.array([d.z(SLOPE_NAMES + TRIM_NAMES, np.r_[d.slope, d.trim]) for d in draws])
    assert np.all(np.abs(z) < 4.0), z
    low, high = chi2_ratio_band(len(draws), comparisons=z.shape[1])
    ratio = np.sum(z**2, axis=0) / len(draws)
    assert np.all((low < ratio) & (ratio < high)), (ratio, low, high)
    _uniform(np.array([d.p_value for d in draws]))


def test_recommended_plan_absorbs_the_trim_in_k_and_recovers_the_slope() -> None:
    draws = [_draw("recommended", seed) for seed in SEEDS]
    z = np.array([d.z(SLOPE_NAMES, d.slope) for d in draws])
    assert np.all(np.abs(z) < 4.0), z
    names = [f"accel.K[{i}][{j}]" for i in range(3) for j in range(3)]
    distances = []
    for d in draws:
        index = [d.fit.names.index(n) for n in names]
        error = d.fit.values[index] - (d.accel.K @ trim_dcm(d.trim)).ravel()  # eq. (T5)
        distances.append(mahalanobis(error, d.fit.covariance[np.ix_(index, index)]))
    low, high = chi2_ratio_band(9 * len(draws))
    assert low < np.sum(distances) / (9 * len(draws)) < high, distances
    _uniform(np.array([d.p_value for d in draws]))


def test_what_each_plan_determines_of_the_trim() -> None:
    """Vehicle: the trim beside the slope, barely correlated with it; recommended: nothing."""
    vehicle = builtin_plan("vehicle")
    spec = JointSpec(accel_k="full", trim=True)
    k = 1.0 / ACCEL_LSB
    prior = {n: s for n, (_m, s) in plan_prior(vehicle, spec, ACCEL_LSB).items()}
    table = cramer_rao(
        vehicle, spec, k_nominal_counts_per_ms2=k, noise_density=1.5e-3 * k,
        include_tolerance=True, prior_sigma=prior,
    )  # fmt: skip
    assert not table.separability.undetermined
    index = [table.separability.names.index(n) for n in SLOPE_NAMES + TRIM_NAMES]
    corr = table.separability.correlation[np.ix_(index[:2], index[2:])]
    assert np.max(np.abs(corr)) < 0.05, corr  # the turns separate slope and trim
    sigma_deg = [np.rad2deg(table.bound(n).sigma) for n in TRIM_NAMES]
    assert sigma_deg == pytest.approx([0.57, 0.57, 1.51], abs=0.01)  # docs/method.md §3
    free = cramer_rao(builtin_plan("recommended"), spec, k_nominal_counts_per_ms2=k)
    assert set(TRIM_NAMES) <= set(free.separability.undetermined)  # K·R_m absorbs R_m
