"""The paper's accelerometer closed forms, physics corrected, with σ (eq. 11-34).

Two positions (eq. 11-14) and the n-position sine/cosine least squares with the additive base
tilt (eq. 15-34). Corrections (docs/method.md §2): ``f_z = +g cos a sin b`` (eq. 5, 12), the
signs of the x coefficients (eq. 17), principal-value arctangents (eq. 23) and signed scale
factors instead of square roots (eq. 22, 30, 34).
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.linalg import block_diag

from canimucal.errors import ModelError
from canimucal.model.paper.common import (
    ACCEL_BIAS_NAMES,
    ACCEL_SCALE_NAMES,
    ANGLE_TOL_RAD,
    MIN_SENSITIVITY,
    TILT_CHANNEL_NAMES,
    TILT_NAMES,
    ClosedFormResult,
    FloatArray,
    check_g,
    pose_label,
    propagate_covariance,
)
from canimucal.model.positions import PositionAverage, poses_of

logger = logging.getLogger(__name__)

_MAX_CONDITION = 1e10
"""Largest condition number of a Fourier design matrix accepted as non-singular."""


class _AccelScaleMixin(ClosedFormResult):
    """Accessors for accelerometer biases and diagonal scale factors."""

    @property
    def bias(self) -> FloatArray:
        """Accelerometer biases (counts)."""
        return self._pick(ACCEL_BIAS_NAMES)

    @property
    def bias_sigma(self) -> FloatArray:
        """σ of the biases (counts)."""
        return self._pick_sigma(ACCEL_BIAS_NAMES)

    @property
    def scale(self) -> FloatArray:
        """Signed diagonal of K (counts per m/s²); an inverted axis is negative."""
        return self._pick(ACCEL_SCALE_NAMES)

    @property
    def scale_sigma(self) -> FloatArray:
        """σ of the diagonal of K (counts per m/s²)."""
        return self._pick_sigma(ACCEL_SCALE_NAMES)

    @property
    def K(self) -> FloatArray:
        """Diagonal K (counts per m/s²); cross-axis terms are not estimated (zero)."""
        return np.diag(self.scale)


@dataclass(frozen=True, eq=False)
class TwoPositionAccelResult(_AccelScaleMixin):
    """Biases and diagonal K from two positions (eq. 11-14)."""


@dataclass(frozen=True, eq=False)
class FourierAccelResult(_AccelScaleMixin):
    """Biases, diagonal K and base tilt from n ≥ 5 positions (eq. 17-34).

    Besides the combined ``base_tilt.alpha0``/``beta0`` (inverse-variance weighted), the
    per-channel estimates ``base_tilt.alpha0.{x,y,z}`` and ``base_tilt.beta0.{y,z}`` are in
    ``names``. ``chi2`` is the weighted residual sum of squares of the three channel fits,
    ``dof`` its degrees of freedom (``n − 3`` for x plus ``2 (n − 5)`` for y and z).
    """

    chi2: float = float("nan")
    dof: int = 0

    @property
    def alpha0(self) -> float:
        """Combined base tilt alpha0 (rad)."""
        return self.value(TILT_NAMES[0])

    @property
    def beta0(self) -> float:
        """Combined base tilt beta0 (rad)."""
        return self.value(TILT_NAMES[1])

    @property
    def alpha0_sigma(self) -> float:
        """σ of the combined alpha0 (rad)."""
        return self.sigma(TILT_NAMES[0])

    @property
    def beta0_sigma(self) -> float:
        """σ of the combined beta0 (rad)."""
        return self.sigma(TILT_NAMES[1])


def two_position_accel(
    level: PositionAverage, tilted: PositionAverage, g: float
) -> TwoPositionAccelResult:
    """Accelerometer biases and diagonal K from (0, 0) and (alpha, beta), psi = 0 (eq. 11-14).

    ``g`` in m/s². The estimator is linear in the means, so the covariance is exact.
    Raises ModelError if psi ≠ 0, if the first position is not level, or if alpha, beta or
    cos(alpha) vanish (a scale factor would not be seen).
    """
    check_g(g)
    _check_two_position_input(level, tilted)
    alpha, beta = tilted.pose.alpha, tilted.pose.beta
    d1 = g * np.sin(alpha)  # k11 sensitivity, eq. (12)
    d2 = g * (np.cos(alpha) * np.cos(beta) - 1.0)  # k22, eq. (13)
    d3 = g * np.cos(alpha) * np.sin(beta)  # k33, eq. (12) with eq. (5) corrected
    for d, what in (
        (d1, "sin(alpha)"),
        (d2, "cos(alpha)cos(beta) - 1"),
        (d3, "cos(alpha)sin(beta)"),
    ):
        if abs(d) < MIN_SENSITIVITY * g:
            raise ModelError(f"tilted position {pose_label(tilted)} is degenerate: {what} = 0")
    m = np.zeros((6, 6))  # parameters = m @ [Ux1, Uy1, Uz1, Ux2, Uy2, Uz2]
    m[0, 0] = 1.0  # Ux0 = <Ux1>, eq. (11)
    m[2, 2] = 1.0  # Uz0 = <Uz1>, eq. (11)
    m[3, [0, 3]] = 1.0 / d1, -1.0 / d1  # k11 = (Ux0 - <Ux2>)/(g sin a), eq. (12)
    m[4, [1, 4]] = 1.0 / d2, -1.0 / d2  # k22 = (<Uy1> - <Uy2>)/(g(ca cb - 1)), eq. (13)
    m[5, [2, 5]] = -1.0 / d3, 1.0 / d3  # k33 = (<Uz2> - Uz0)/(g ca sb), eq. (12) corrected
    m[1] = m[4] * g  # Uy0 = <Uy1> + k22 g, eq. (14)
    m[1, 1] += 1.0
    means = np.concatenate([level.mean_accel, tilted.mean_accel])
    cov = block_diag(level.cov_accel, tilted.cov_accel)
    return TwoPositionAccelResult(ACCEL_BIAS_NAMES + ACCEL_SCALE_NAMES, m @ means, m @ cov @ m.T)


def fourier_accel(averages: Sequence[PositionAverage], g: float) -> FourierAccelResult:
    """Biases, diagonal K and base tilt by the paper's sine/cosine least squares (eq. 17-34).

    The additive tilt model (eq. 15): x channel on ``[1, sin a, cos a]``, y and z on
    ``[1, ca cb, ca sb, sa cb, sa sb]``, each weighted by the means' variances. alpha0 comes
    out three times (x, y, z) and beta0 twice (y, z), each with its σ; the combined values
    are their inverse-variance weighted means. σ from a central-difference Jacobian of the
    whole estimator with respect to the stacked means. psi must be 0 everywhere.
    """
    check_g(g)
    avgs = list(averages)
    if len(avgs) < 5:
        raise ModelError(f"the Fourier method needs at least 5 positions, got {len(avgs)}")
    for i, avg in enumerate(avgs):
        _check_accel(avg, f"position {i}")
        if abs(avg.pose.psi) > ANGLE_TOL_RAD:
            raise ModelError(f"position {i} has psi = {np.rad2deg(avg.pose.psi):.3f} deg; need 0")
    design_x, design_yz = _fourier_designs(poses_of(avgs))
    _check_design(design_x, "x channel [1, sin a, cos a]")
    _check_design(design_yz, "y/z channels [1, ca cb, ca sb, sa cb, sa sb]")
    means = np.array([a.mean_accel for a in avgs])
    covs = [a.cov_accel for a in avgs]
    weights = np.column_stack(
        [_channel_weights(np.array([c[k, k] for c in covs])) for k in range(3)]
    )

    def estimate(flat: FloatArray) -> FloatArray:
        return _fourier_raw(flat.reshape(-1, 3), design_x, design_yz, weights, g)

    raw, raw_cov = propagate_covariance(estimate, means.ravel(), block_diag(*covs))
    combine = _tilt_combination(np.diag(raw_cov)[6:])
    chi2 = _fourier_chi2(means, design_x, design_yz, weights)
    logger.debug("fourier_accel: %d positions, chi2 %.3g", len(avgs), chi2)
    return FourierAccelResult(
        ACCEL_BIAS_NAMES + ACCEL_SCALE_NAMES + TILT_NAMES + TILT_CHANNEL_NAMES,
        combine @ raw,
        combine @ raw_cov @ combine.T,
        chi2=chi2,
        dof=(len(avgs) - 3) + 2 * (len(avgs) - 5),
    )


def _fourier_designs(poses: FloatArray) -> tuple[FloatArray, FloatArray]:
    sa, ca = np.sin(poses[:, 0]), np.cos(poses[:, 0])
    sb, cb = np.sin(poses[:, 1]), np.cos(poses[:, 1])
    ones = np.ones_like(sa)
    design_x = np.column_stack([ones, sa, ca])  # eq. (17)-(20)
    design_yz = np.column_stack([ones, ca * cb, ca * sb, sa * cb, sa * sb])  # eq. (24)-(26)
    return design_x, design_yz


def _fourier_raw(
    means: FloatArray, design_x: FloatArray, design_yz: FloatArray, weights: FloatArray, g: float
) -> FloatArray:
    """``[bx, by, bz, k11, k22, k33, a0x, a0y, a0z, b0y, b0z]`` from the means."""
    cx = _wls(design_x, means[:, 0], weights[:, 0])
    cy = _wls(design_yz, means[:, 1], weights[:, 1])
    cz = _wls(design_yz, means[:, 2], weights[:, 2])
    a0x = np.arctan(cx[2] / cx[1])  # eq. (23) corrected: principal value of C2x/C1x
    k11 = -(cx[1] * np.cos(a0x) + cx[2] * np.sin(a0x)) / g  # eq. (22), sign kept
    b0y = -np.arctan(cy[2] / cy[1])  # eq. (28)
    a0y = -np.arctan(cy[3] / cy[1])  # eq. (29)
    k22 = -np.sign(cy[1]) * np.linalg.norm(cy[1:]) / g  # eq. (30), sign of -C1y
    b0z = np.arctan(cz[1] / cz[2])  # eq. (32)
    a0z = -np.arctan(cz[4] / cz[2])  # eq. (33)
    k33 = np.sign(cz[2]) * np.linalg.norm(cz[1:]) / g  # eq. (34), sign of C2z
    return np.array([cx[0], cy[0], cz[0], k11, k22, k33, a0x, a0y, a0z, b0y, b0z])


def _fourier_chi2(
    means: FloatArray, design_x: FloatArray, design_yz: FloatArray, weights: FloatArray
) -> float:
    chi2 = 0.0
    for k, design in enumerate((design_x, design_yz, design_yz)):
        residual = means[:, k] - design @ _wls(design, means[:, k], weights[:, k])
        chi2 += float(np.sum(weights[:, k] * residual**2))
    return chi2


def _wls(design: FloatArray, y: FloatArray, weights: FloatArray) -> FloatArray:
    root = np.sqrt(weights)
    coef, *_ = np.linalg.lstsq(design * root[:, None], y * root, rcond=None)
    return np.asarray(coef, dtype=float)


def _channel_weights(variances: FloatArray) -> FloatArray:
    """Inverse variances, or equal weights if any variance is not positive (noiseless data)."""
    if np.all(variances > 0):
        return 1.0 / variances
    return np.ones_like(variances)


def _tilt_combination(tilt_variances: FloatArray) -> FloatArray:
    """Linear map from the 11 raw estimates to the 13 reported (combined tilts inserted)."""
    combine = np.zeros((13, 11))
    combine[:6, :6] = np.eye(6)
    combine[6, 6:9] = _channel_weights(tilt_variances[:3])  # alpha0 from x, y, z
    combine[7, 9:11] = _channel_weights(tilt_variances[3:])  # beta0 from y, z
    combine[6] /= combine[6].sum()
    combine[7] /= combine[7].sum()
    combine[8:, 6:] = np.eye(5)
    return combine


def _check_two_position_input(level: PositionAverage, tilted: PositionAverage) -> None:
    _check_accel(level, "level position")
    _check_accel(tilted, "tilted position")
    for avg, label in ((level, "level position"), (tilted, "tilted position")):
        if abs(avg.pose.psi) > ANGLE_TOL_RAD:
            raise ModelError(f"{label} has psi = {np.rad2deg(avg.pose.psi):.3f} deg; need 0")
    if abs(level.pose.alpha) > ANGLE_TOL_RAD or abs(level.pose.beta) > ANGLE_TOL_RAD:
        raise ModelError(f"first position must be level (0, 0), got {pose_label(level)}")


def _check_accel(avg: PositionAverage, label: str) -> None:
    mean, cov = np.asarray(avg.mean_accel), np.asarray(avg.cov_accel)
    if mean.shape != (3,) or cov.shape != (3, 3):
        raise ModelError(f"{label}: accel mean must be (3,) and covariance (3, 3)")
    if not (np.all(np.isfinite(mean)) and np.all(np.isfinite(cov))):
        raise ModelError(f"{label}: accel mean or covariance is not finite")


def _check_design(design: FloatArray, what: str) -> None:
    rank = int(np.linalg.matrix_rank(design))
    if rank < design.shape[1]:
        raise ModelError(f"{what}: design is singular (rank {rank} < {design.shape[1]})")
    condition = float(np.linalg.cond(design))
    if condition > _MAX_CONDITION:
        raise ModelError(f"{what}: design is near-singular (condition {condition:.3g})")
