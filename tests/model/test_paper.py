"""The paper's closed forms (canimucal.model.closed_form_*): truth, σ, sign, bad input.

Monte Carlo checks (fixed seeds, N_TRIALS = 200 draws of data that follow each estimator's
own model, angle errors off) and their margins, per parameter:

* mean error within 3 standard errors (3 σ/√200) of zero: a two-sided normal test, false
  alarm 0.27 % per parameter if the estimator is unbiased;
* empirical std within 15 % of the reported σ: (N−1)s²/σ² ~ χ²(199), so
  P(s/σ > 1.15) = 0.16 % and P(s/σ < 0.85) = 0.12 % (the std of s/σ is 1/√398 = 5 %, so
  ±15 % is ±3 of its σ);
* joint: Σ over trials of the Mahalanobis distance² of the error vector (p parameters) is
  χ²(200 p) when the reported covariance is right; accepted between its 0.05 % and 99.95 %
  quantiles; and the correlations, through the errors whitened with the reported covariance
  (off-diagonal sample covariances within 4/√200, see ``_check_joint``).

With fixed seeds these are deterministic; the margins say how unlikely a false failure is
for another seed; a σ off by 30 %, dropped correlations or an ignored heading fail them
(checked by mutating the estimators by hand).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import pytest
from numpy.typing import NDArray
from scipy.stats import chi2

from canimucal.errors import InputError, ModelError
from canimucal.model.frames import EARTH_RATE_RAD_S
from canimucal.model.paper.accel import (
    FourierAccelResult,
    fourier_accel,
    two_position_accel,
)
from canimucal.model.paper.common import (
    ACCEL_BIAS_NAMES,
    ACCEL_SCALE_NAMES,
    GYRO_BIAS_NAMES,
    GYRO_SCALE_NAMES,
    TILT_CHANNEL_NAMES,
    TILT_NAMES,
    ClosedFormResult,
)
from canimucal.model.paper.gyro import mems_gyro_bias, nav_gyro_two_position
from canimucal.model.positions import PlannedPosition, Pose, PositionAverage
from canimucal.model.sensor import DEFAULT_ACCEL_LSB, DEFAULT_GYRO_LSB, AccelParams, GyroParams
from canimucal.sim.averages import simulate_averages

N_TRIALS = 200
G = 9.80665
LATITUDE = np.deg2rad(50.45)
K_NOMINAL = 1.0 / DEFAULT_ACCEL_LSB  # 208.8 counts per m/s²
S_NOMINAL = 1.0 / DEFAULT_GYRO_LSB  # 939.7 counts per rad/s
NAV_ARW_RAD_S_SQRT_HZ = np.deg2rad(0.002) / 60.0  # 0.002 °/√h = 0.002/60 °/s/√Hz
FIVE_DEG = [(0.0, 0.0), (22.5, 0.0), (22.5, 2.5), (45.0, 2.5), (45.0, 5.0)]

Array = NDArray[np.float64]


def _positions(angles_deg: Sequence[tuple[float, float]], seconds: float) -> list[PlannedPosition]:
    return [PlannedPosition(np.deg2rad(a), np.deg2rad(b), seconds=seconds) for a, b in angles_deg]


def _accel(signs: Sequence[float]) -> AccelParams:
    scale = np.array(signs) * K_NOMINAL * np.array([1.01, 0.98, 1.02])
    return AccelParams(np.array([12.0, -30.0, 7.5]), np.diag(scale))


def _gyro(signs: Sequence[float], scale: float = S_NOMINAL) -> GyroParams:
    diag = np.array(signs) * scale * np.array([0.99, 1.02, 1.01])
    return GyroParams(np.array([3.0, -2.0, 0.5]), np.diag(diag), np.zeros((3, 3)))


def _simulate(
    plan: Sequence[PlannedPosition],
    rng: np.random.Generator,
    accel: AccelParams | None = None,
    **kwargs: Any,
) -> list[PositionAverage]:
    """``simulate_averages`` under the closed forms' own model: g = G, no angle errors."""
    params = _accel((1, 1, 1)) if accel is None else accel
    return simulate_averages(plan, params, rng, g=G, angle_errors=False, **kwargs)


def _run(
    trial: Callable[[np.random.Generator], ClosedFormResult], seed: int
) -> tuple[Array, Array, list[ClosedFormResult]]:
    rng = np.random.default_rng(seed)
    results = [trial(rng) for _ in range(N_TRIALS)]
    return np.array([r.values for r in results]), np.array([r.sigmas for r in results]), results


def _check_monte_carlo(
    values: Array, sigmas: Array, truth: Array, names: Sequence[str], results: list
) -> None:
    err = values - truth
    sigma = np.sqrt(np.mean(sigmas**2, axis=0))  # RMS of the reported σ over the trials
    assert np.all(sigma > 0)
    z_mean = err.mean(axis=0) / (sigma / np.sqrt(N_TRIALS))
    bad_mean = [(n, round(float(z), 2)) for n, z in zip(names, z_mean, strict=True) if abs(z) > 3]
    assert not bad_mean, f"mean error beyond 3 standard errors: {bad_mean}"
    ratio = err.std(axis=0, ddof=1) / sigma
    bad_std = [
        (n, round(float(r), 3)) for n, r in zip(names, ratio, strict=True) if abs(r - 1) > 0.15
    ]
    assert not bad_std, f"empirical std / reported σ outside 1 ± 0.15: {bad_std}"
    _check_joint(err, results, names)


def _check_joint(err: Array, results: list, names: Sequence[str]) -> None:
    # Redundant entries (the combined tilts) are linear in the others: leave them out.
    keep = [i for i, n in enumerate(names) if n not in TILT_NAMES]
    # The mean of the reported covariances: for the nonlinear Fourier estimator the y-channel
    # covariance has a thin direction (correlation eigenvalue ~4e-4) that a Jacobian taken at
    # each noisy estimate tilts a little, which inflates per-trial Mahalanobis distances
    # (measured: 7.1 instead of 4 on average) although σ and the correlations are right.
    cov = np.mean([r.covariance[np.ix_(keep, keep)] for r in results], axis=0)
    total = float(np.sum(err[:, keep] * np.linalg.solve(cov, err[:, keep].T).T))
    dof = N_TRIALS * len(keep)
    lo, hi = chi2.ppf([0.0005, 0.9995], dof)
    assert lo < total < hi, f"joint χ² {total:.0f} outside [{lo:.0f}, {hi:.0f}] (dof {dof})"
    # The χ² trace cannot see dropped correlations (tr(diag(Σ)⁻¹ Σ) = p too), so whiten the
    # errors with the reported covariance: if its correlations are right, the off-diagonal
    # sample covariances of the whitened errors are ~ N(0, 1/N). Bound 4/√N: p = 6e-5 per
    # pair, ≤ 0.35 % over the ≤ 55 pairs (measured max 3.0/√N over all cases here).
    whitened = np.linalg.solve(np.linalg.cholesky(cov), err[:, keep].T).T
    off = np.cov(whitened.T) - np.diag(np.diag(np.cov(whitened.T)))
    assert np.abs(off).max() < 4.0 / np.sqrt(N_TRIALS), "reported correlations are wrong"


# --- two positions, eq. (11)-(14) ---------------------------------------------------------


@pytest.mark.parametrize(
    ("tilted_deg", "signs", "seed"),
    [((45.0, 5.0), (1, 1, 1), 11), ((30.0, 8.0), (-1, 1, -1), 12)],
    ids=["paper-45-5", "inverted-x-z-30-8"],
)
def test_two_position_accel_monte_carlo(
    tilted_deg: tuple[float, float], signs: tuple[int, int, int], seed: int
) -> None:
    accel = _accel(signs)
    plan = _positions([(0.0, 0.0), tilted_deg], seconds=30.0)
    noise = np.array([1.0, 1.5, 0.8])  # counts/√Hz per axis

    def trial(rng: np.random.Generator) -> ClosedFormResult:
        avgs = _simulate(plan, rng, accel, accel_noise_density=noise)
        return two_position_accel(avgs[0], avgs[1], G)

    values, sigmas, results = _run(trial, seed)
    truth = np.concatenate([accel.bias, np.diag(accel.K)])
    _check_monte_carlo(values, sigmas, truth, results[0].names, results)
    assert np.all(np.sign(values[:, 3:]) == np.array(signs))


def test_two_position_accel_noiseless_inverted_y() -> None:
    accel = _accel((1, -1, 1))
    plan = _positions([(0.0, 0.0), (37.0, 6.0)], seconds=30.0)
    avgs = _simulate(plan, np.random.default_rng(0), accel, accel_noise_density=0.0)
    result = two_position_accel(avgs[0], avgs[1], G)
    assert result.names == ACCEL_BIAS_NAMES + ACCEL_SCALE_NAMES
    np.testing.assert_allclose(result.bias, accel.bias, atol=1e-9)
    np.testing.assert_allclose(result.K, accel.K, rtol=1e-12)
    np.testing.assert_array_equal(result.sigmas, np.zeros(6))


# --- Fourier least squares, eq. (17)-(34) -------------------------------------------------


@pytest.mark.parametrize(
    ("signs", "seed"), [((1, 1, 1), 21), ((1, -1, 1), 22)], ids=["upright", "inverted-y"]
)
def test_fourier_accel_monte_carlo(signs: tuple[int, int, int], seed: int) -> None:
    accel = _accel(signs)
    alpha0 = beta0 = np.deg2rad(-1.0)
    plan = _positions(FIVE_DEG, seconds=30.0)

    def trial(rng: np.random.Generator) -> ClosedFormResult:
        avgs = _simulate(
            plan,
            rng,
            accel,
            alpha0=alpha0,
            beta0=beta0,
            tilt_model="additive",
            accel_noise_density=1.0,
        )
        return fourier_accel(avgs, G)

    values, sigmas, results = _run(trial, seed)
    truth = np.concatenate([accel.bias, np.diag(accel.K), [alpha0, beta0]])
    truth = np.concatenate([truth, [alpha0] * 3 + [beta0] * 2])
    _check_monte_carlo(values, sigmas, truth, results[0].names, results)
    assert np.all(np.sign(values[:, 3:6]) == np.array(signs))
    # The combined tilt is at least as good as its best channel (inverse-variance weights).
    r = results[0]
    assert isinstance(r, FourierAccelResult)
    assert r.alpha0_sigma <= min(r.sigma(n) for n in TILT_CHANNEL_NAMES[:3]) + 1e-15
    assert r.beta0_sigma <= min(r.sigma(n) for n in TILT_CHANNEL_NAMES[3:]) + 1e-15
    # The paper's noise amplification on alpha0 from eq. (33): ≈ 100 (k·g·σ_angle / σ_mean).
    sigma_mean = 1.0 / np.sqrt(30.0)
    amplification = K_NOMINAL * G * r.sigma("base_tilt.alpha0.z") / sigma_mean
    assert 50 < amplification < 200


def test_fourier_accel_noiseless_recovers_truth_and_reports_fit() -> None:
    accel = _accel((-1, 1, -1))
    alpha0, beta0 = np.deg2rad(0.7), np.deg2rad(-1.3)
    plan = _positions([*FIVE_DEG, (10.0, 4.0), (40.0, -3.0)], seconds=30.0)
    avgs = _simulate(
        plan,
        np.random.default_rng(0),
        accel,
        alpha0=alpha0,
        beta0=beta0,
        tilt_model="additive",
        accel_noise_density=0.0,
    )
    result = fourier_accel(avgs, G)
    assert isinstance(result, FourierAccelResult)
    np.testing.assert_allclose(result.bias, accel.bias, atol=1e-8)
    np.testing.assert_allclose(result.scale, np.diag(accel.K), rtol=1e-10)
    for name in TILT_CHANNEL_NAMES:
        expected = alpha0 if "alpha0" in name else beta0
        assert result.value(name) == pytest.approx(expected, abs=1e-12)
    assert result.alpha0 == pytest.approx(alpha0, abs=1e-12)
    assert result.beta0 == pytest.approx(beta0, abs=1e-12)
    assert result.dof == (7 - 3) + 2 * (7 - 5)
    assert result.chi2 == pytest.approx(0.0, abs=1e-12)


def test_fourier_accel_misreads_a_rigid_tilt_as_bias_z() -> None:
    # The additive reading (eq. 15) applied to a rigid base tilt: at every position the z
    # channel sees ≈ k33·g·β0 more than the additive model says, a constant the fit takes as
    # bias z (docs/design.md §3: bias z against beta0, correlation −0.9996). Noiseless, and the fit
    # residual stays at zero: the paper's method cannot tell.
    accel = _accel((1, 1, 1))
    beta0 = np.deg2rad(-1.0)
    avgs = _simulate(
        _positions(FIVE_DEG, seconds=30.0),
        np.random.default_rng(0),
        accel,
        alpha0=np.deg2rad(-1.0),
        beta0=beta0,
        tilt_model="rigid",
        accel_noise_density=0.0,
    )
    result = fourier_accel(avgs, G)
    bias_z_error = result.bias[2] - accel.bias[2]
    assert bias_z_error == pytest.approx(accel.K[2, 2] * G * beta0, rel=0.05)  # ≈ −36 counts
    assert abs(result.value("base_tilt.beta0.z")) < np.deg2rad(0.1)  # the tilt is not seen
    assert result.value("base_tilt.alpha0.x") == pytest.approx(np.deg2rad(-1.0), abs=1e-5)


# --- MEMS gyro bias, eq. (36) -------------------------------------------------------------


@pytest.mark.parametrize("n_positions", [1, 3])
def test_mems_gyro_bias_monte_carlo(n_positions: int) -> None:
    # S = 0 switches the Earth-rate term off, so the data follow eq. (36) exactly.
    gyro = GyroParams(np.array([40.0, -12.0, 3.0]), np.zeros((3, 3)), np.zeros((3, 3)))
    plan = _positions([(0.0, 0.0), (22.5, 2.5), (45.0, 5.0)][:n_positions], seconds=30.0)
    noise = np.array([0.08, 0.1, 0.12])

    def trial(rng: np.random.Generator) -> ClosedFormResult:
        avgs = _simulate(
            plan,
            rng,
            gyro=gyro,
            latitude=LATITUDE,
            gyro_noise_density=noise,
        )
        return mems_gyro_bias(avgs)

    values, sigmas, results = _run(trial, 30 + n_positions)
    _check_monte_carlo(values, sigmas, gyro.bias, GYRO_BIAS_NAMES, results)
    expected_sigma = noise / np.sqrt(30.0 * n_positions)
    np.testing.assert_allclose(sigmas[0], expected_sigma, rtol=1e-12)


def test_mems_gyro_bias_chi2_sees_earth_rate() -> None:
    # A nominal S and a quiet gyro: the Earth rate (0.07 count) differs between the
    # positions by far more than σ = 0.003 count, so the consistency χ² is huge.
    plan = _positions([(0.0, 0.0), (45.0, 5.0), (90.0, 0.0)], seconds=300.0)
    avgs = _simulate(
        plan,
        np.random.default_rng(3),
        gyro=_gyro((1, 1, 1)),
        latitude=LATITUDE,
        gyro_noise_density=0.05,
    )
    result = mems_gyro_bias(avgs)
    assert result.dof == 6
    assert result.chi2 > chi2.ppf(0.9999, result.dof)


# --- navigation gyro from Earth rate, eq. (45)-(48) ---------------------------------------


@pytest.mark.parametrize(
    ("heading_deg", "signs", "seed"),
    [(0.0, (1, 1, 1), 41), (30.0, (1, 1, -1), 42)],
    ids=["heading-0", "heading-30-inverted-z"],
)
def test_nav_gyro_monte_carlo(heading_deg: float, signs: tuple[int, int, int], seed: int) -> None:
    gyro = _gyro(signs)
    heading = np.deg2rad(heading_deg)
    plan = _positions([(0.0, 0.0), (45.0, 5.0)], seconds=300.0)
    noise = NAV_ARW_RAD_S_SQRT_HZ * S_NOMINAL  # output-referred, counts/√Hz

    def trial(rng: np.random.Generator) -> ClosedFormResult:
        avgs = _simulate(
            plan,
            rng,
            gyro=gyro,
            latitude=LATITUDE,
            heading=heading,
            gyro_noise_density=noise,
        )
        return nav_gyro_two_position(avgs[0], avgs[1], LATITUDE, heading)

    values, sigmas, results = _run(trial, seed)
    truth = np.concatenate([gyro.bias, np.diag(gyro.S)])
    _check_monte_carlo(values, sigmas, truth, GYRO_BIAS_NAMES + GYRO_SCALE_NAMES, results)
    assert np.all(np.sign(values[:, 3:]) == np.array(signs))


def _nav_average(pose: Pose, mean: Array, cov: Array) -> PositionAverage:
    return PositionAverage(pose, 1, np.zeros(3), np.zeros((3, 3)), mean, cov)


@pytest.mark.parametrize("gyro_lsb", [DEFAULT_GYRO_LSB, 1e-7], ids=["mems-lsb", "nav-lsb"])
def test_nav_gyro_paper_s33_relative_sigma(gyro_lsb: float) -> None:
    """The paper's figure: σ(s33)/s33 ≈ 1.4 % for 0.002 °/√h, 2 x 300 s, φ = 50.45°.

    Noise input-referred (0.002 °/√h), output-referred as N/LSB counts/√Hz, no quantization:
    the relative σ does not depend on the LSB. Δw_z = 0.0451 Ω between (0, 0) and (45°, 5°).
    """
    s = 1.0 / gyro_lsb
    var_mean = (NAV_ARW_RAD_S_SQRT_HZ * s) ** 2 / 300.0
    cov = np.eye(3) * var_mean
    level = _nav_average(Pose(0.0, 0.0), np.zeros(3), cov)
    tilted = _nav_average(Pose(np.deg2rad(45.0), np.deg2rad(5.0)), np.full(3, s * 1e-5), cov)
    result = nav_gyro_two_position(level, tilted, LATITUDE)
    delta_z = result.earth_rate_body[1, 2] - result.earth_rate_body[0, 2]
    assert delta_z / EARTH_RATE_RAD_S == pytest.approx(0.0451, abs=5e-4)
    expected = np.sqrt(2.0 * var_mean) / abs(delta_z) / s
    assert result.scale_sigma[2] / s == pytest.approx(expected, rel=1e-12)
    assert result.scale_sigma[2] / s == pytest.approx(0.0144, abs=0.0005)  # "about 1.4 %"
    # x and y see far larger changes of the Earth rate: their σ is far smaller.
    assert np.all(result.scale_sigma[:2] < 0.2 * result.scale_sigma[2])


def test_nav_gyro_heading_zero_is_eq_45_46() -> None:
    gyro = _gyro((1, -1, 1))
    plan = _positions([(0.0, 0.0), (40.0, 6.0)], seconds=300.0)
    avgs = _simulate(
        plan,
        np.random.default_rng(8),
        gyro=gyro,
        latitude=LATITUDE,
        gyro_noise_density=1e-4,
    )
    result = nav_gyro_two_position(avgs[0], avgs[1], LATITUDE)
    v1, v2 = avgs[0].mean_gyro, avgs[1].mean_gyro
    assert v1 is not None and v2 is not None
    assert result.earth_rate_body[0, 0] == 0.0  # wx1 = 0 at heading 0
    bx = v1[0]  # eq. (45)
    s11 = (v2[0] - bx) / result.earth_rate_body[1, 0]  # eq. (46)
    assert result.bias[0] == pytest.approx(bx, rel=1e-12)
    assert result.scale[0] == pytest.approx(s11, rel=1e-12)


def test_nav_gyro_noiseless_heading_recovers_truth() -> None:
    gyro = _gyro((-1, 1, 1))
    plan = _positions([(0.0, 0.0), (45.0, 5.0)], seconds=300.0)
    heading = np.deg2rad(-70.0)
    avgs = _simulate(
        plan,
        np.random.default_rng(0),
        gyro=gyro,
        latitude=LATITUDE,
        heading=heading,
        gyro_noise_density=0.0,
    )
    result = nav_gyro_two_position(avgs[0], avgs[1], LATITUDE, heading)
    np.testing.assert_allclose(result.bias, gyro.bias, atol=1e-9)
    np.testing.assert_allclose(result.S, gyro.S, rtol=1e-8)


# --- the result object --------------------------------------------------------------------


def test_result_accessors() -> None:
    names = ("a", "b")
    result = ClosedFormResult(names, np.array([1.0, 2.0]), np.array([[4.0, 1.0], [1.0, 9.0]]))
    assert result.value("b") == 2.0
    assert result.sigma("b") == 3.0
    assert result.correlation("a", "b") == pytest.approx(1.0 / 6.0)
    assert result.as_dict() == {"a": (1.0, 2.0), "b": (2.0, 3.0)}
    with pytest.raises(KeyError, match="no estimate named 'c'"):
        result.value("c")
    with pytest.raises(ValueError, match="read-only"):
        result.values[0] = 5.0
    with pytest.raises(ValueError, match="2 names need 2 values"):
        ClosedFormResult(names, np.zeros(3), np.zeros((2, 2)))


# --- bad input ----------------------------------------------------------------------------


def _accel_average(alpha_deg: float, beta_deg: float, psi_deg: float = 0.0) -> PositionAverage:
    pose = Pose(np.deg2rad(alpha_deg), np.deg2rad(beta_deg), np.deg2rad(psi_deg))
    return PositionAverage(pose, 100, np.array([1.0, -200.0, 3.0]), np.eye(3) * 0.01)


@pytest.mark.parametrize(
    ("level", "tilted", "g", "message"),
    [
        ((0, 0, 0), (45, 5, 10), G, "psi = 10.000 deg"),
        ((0, 0, 3), (45, 5, 0), G, "level position has psi"),
        ((1, 0, 0), (45, 5, 0), G, "must be level"),
        ((0, 0, 0), (0, 5, 0), G, r"sin\(alpha\) = 0"),
        ((0, 0, 0), (45, 0, 0), G, r"cos\(alpha\)sin\(beta\) = 0"),
        ((0, 0, 0), (90, 5, 0), G, r"cos\(alpha\)sin\(beta\) = 0"),
        ((0, 0, 0), (45, 5, 0), 0.0, "g must be a positive"),
        ((0, 0, 0), (45, 5, 0), float("nan"), "g must be a positive"),
    ],
)
def test_two_position_accel_bad_input(
    level: tuple[float, ...], tilted: tuple[float, ...], g: float, message: str
) -> None:
    with pytest.raises(ModelError, match=message) as info:
        two_position_accel(_accel_average(*level), _accel_average(*tilted), g)
    assert isinstance(info.value, InputError) and info.value.exit_code == 2


def test_two_position_accel_rejects_non_finite_mean() -> None:
    bad = PositionAverage(Pose(0.0, 0.0), 1, np.array([np.nan, 0.0, 0.0]), np.eye(3))
    with pytest.raises(ModelError, match="not finite"):
        two_position_accel(bad, _accel_average(45, 5), G)


@pytest.mark.parametrize(
    ("angles", "message"),
    [
        (FIVE_DEG[:4], "needs at least 5 positions, got 4"),
        ([(a, 0.0) for a in (0, 10, 20, 30, 40)], r"y/z channels .* singular \(rank 3 < 5\)"),
        ([(0, 0), (0, 2), (30, 0), (30, 2), (30, 4)], r"x channel .* singular \(rank 2 < 3\)"),
    ],
)
def test_fourier_accel_bad_geometry(angles: list[tuple[float, float]], message: str) -> None:
    with pytest.raises(ModelError, match=message):
        fourier_accel([_accel_average(a, b) for a, b in angles], G)


def test_fourier_accel_rejects_psi() -> None:
    avgs = [_accel_average(a, b) for a, b in FIVE_DEG]
    avgs[3] = _accel_average(45, 2.5, psi_deg=90)
    with pytest.raises(ModelError, match="position 3 has psi = 90.000 deg"):
        fourier_accel(avgs, G)


def test_gyro_bad_input() -> None:
    no_gyro = _accel_average(0, 0)
    with pytest.raises(ModelError, match="got 0"):
        mems_gyro_bias([])
    with pytest.raises(ModelError, match="has no gyro data"):
        mems_gyro_bias([no_gyro])
    with pytest.raises(ModelError, match="has no gyro data"):
        nav_gyro_two_position(no_gyro, no_gyro, LATITUDE)
    cov = np.eye(3) * 1e-6
    level = _nav_average(Pose(0.0, 0.0), np.zeros(3), cov)
    tilted = _nav_average(Pose(np.deg2rad(45.0), np.deg2rad(5.0)), np.zeros(3), cov)
    with pytest.raises(ModelError, match="same in both positions: s11"):
        nav_gyro_two_position(level, level, LATITUDE)
    # At the equator the Earth rate is horizontal (along z): tilting about z and then x
    # never moves it onto body x, so s11 is unseen.
    with pytest.raises(ModelError, match="axis 0 is the same in both positions"):
        nav_gyro_two_position(level, tilted, 0.0)
    with pytest.raises(ModelError, match="latitude must be within"):
        nav_gyro_two_position(level, tilted, np.deg2rad(95.0))
    with pytest.raises(ModelError, match="heading must be finite"):
        nav_gyro_two_position(level, tilted, LATITUDE, float("inf"))
