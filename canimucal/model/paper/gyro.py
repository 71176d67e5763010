"""The paper's gyro closed forms, physics corrected, with σ (eq. 36-48).

MEMS grade: biases only, the Earth rate neglected (eq. 36). Navigation grade: biases and
diagonal scale factors from the Earth rate seen in two positions (eq. 45-48), with the Earth
rate of the right-handed level frame, ``w_L = [0, -Ω sin φ, Ω cos φ]`` (eq. 40-41 as
corrected in docs/method.md §2).
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.linalg import block_diag

from canimucal.errors import ModelError
from canimucal.model.frames import EARTH_RATE_RAD_S, earth_rate_level, position_dcm
from canimucal.model.paper.common import (
    GYRO_BIAS_NAMES,
    GYRO_SCALE_NAMES,
    MIN_SENSITIVITY,
    ClosedFormResult,
    FloatArray,
    pose_label,
)
from canimucal.model.positions import PositionAverage

logger = logging.getLogger(__name__)


class _GyroBiasMixin(ClosedFormResult):
    """Accessors for gyro biases."""

    @property
    def bias(self) -> FloatArray:
        """Gyro biases (counts)."""
        return self._pick(GYRO_BIAS_NAMES)

    @property
    def bias_sigma(self) -> FloatArray:
        """σ of the gyro biases (counts)."""
        return self._pick_sigma(GYRO_BIAS_NAMES)


@dataclass(frozen=True, eq=False)
class GyroBiasResult(_GyroBiasMixin):
    """Gyro biases with the Earth rate neglected (eq. 36).

    With several positions, ``chi2`` (``dof = 3 (n − 1)``) tests whether the means agree, i.e.
    whether neglecting the Earth rate and the tilts was justified.
    """

    chi2: float = float("nan")
    dof: int = 0


@dataclass(frozen=True, eq=False)
class NavGyroResult(_GyroBiasMixin):
    """Gyro biases and diagonal S from the Earth rate in two positions (eq. 45-48).

    ``earth_rate_body`` holds the body-frame Earth rate (rad/s) of each position, one row each.
    """

    earth_rate_body: FloatArray = field(default_factory=lambda: np.full((2, 3), np.nan))

    @property
    def scale(self) -> FloatArray:
        """Signed diagonal of S (counts per rad/s)."""
        return self._pick(GYRO_SCALE_NAMES)

    @property
    def scale_sigma(self) -> FloatArray:
        """σ of the diagonal of S (counts per rad/s)."""
        return self._pick_sigma(GYRO_SCALE_NAMES)

    @property
    def relative_scale_sigma(self) -> FloatArray:
        """σ(s_ii)/|s_ii|: how weakly the Earth rate determines each scale factor."""
        return self.scale_sigma / np.abs(self.scale)

    @property
    def S(self) -> FloatArray:
        """Diagonal S (counts per rad/s); cross-axis terms are not estimated (zero)."""
        return np.diag(self.scale)


def mems_gyro_bias(averages: Sequence[PositionAverage]) -> GyroBiasResult:
    """Gyro biases ``B = <V>`` with the Earth rate neglected (eq. 36).

    One position: its mean and covariance. Several: the generalised-least-squares mean
    ``(Σ Σ_i⁻¹)⁻¹ Σ Σ_i⁻¹ <V_i>`` (plain mean if a covariance is singular).
    """
    avgs = list(averages)
    if not avgs:
        raise ModelError("need at least 1 position with gyro data, got 0")
    means, covs = _gyro_data(avgs)
    if len(avgs) == 1:
        return GyroBiasResult(GYRO_BIAS_NAMES, means[0], covs[0], chi2=0.0, dof=0)
    covs_arr = np.array(covs)
    try:
        np.linalg.cholesky(covs_arr)  # every Σ_i positive definite
        infos = np.linalg.inv(covs_arr)  # Σ_i⁻¹
    except np.linalg.LinAlgError:
        logger.debug("mems_gyro_bias: a singular covariance, using the plain mean")
        plain_cov = covs_arr.sum(axis=0) / len(avgs) ** 2
        return GyroBiasResult(GYRO_BIAS_NAMES, means.mean(axis=0), plain_cov)
    cov = np.linalg.inv(infos.sum(axis=0))
    bias = cov @ np.einsum("nij,nj->i", infos, means)  # eq. (36), GLS mean over positions
    residuals = means - bias
    chi2 = float(np.einsum("ni,nij,nj->", residuals, infos, residuals))
    return GyroBiasResult(GYRO_BIAS_NAMES, bias, cov, chi2=chi2, dof=3 * (len(avgs) - 1))


def nav_gyro_two_position(
    level: PositionAverage,
    tilted: PositionAverage,
    latitude: float,
    heading: float = 0.0,
) -> NavGyroResult:
    """Gyro biases and diagonal S from the Earth rate in two positions (eq. 45-48, corrected).

    ``w_i = C_i w_L`` with ``w_L = earth_rate_level(latitude, heading)`` and ``C_i`` the
    position's DCM (eq. 40-41 corrected, docs/method.md §2). Each axis k is the 2x2 solve of
    ``<V_ik> = B_k + s_kk w_ik`` (eq. 47-48); eq. (45)-(46), ``Bx = <Vx1>`` and
    ``s11 = (<Vx2> - Bx)/wx2``, are its special case ``wx1 = 0`` (level first position at
    heading 0). Linear in the means, so σ is exact.

    Example (the paper's figure, a test reproduces it): φ = 50.45°, positions (0, 0) and
    (45°, 5°), heading 0, angle random walk 0.002 °/√h, 300 s each: Δw_z = 0.045 Ω and
    σ(s33)/s33 = √2·N/√300/Δw_z ≈ 1.44 %, whatever the LSB when the noise is input-referred and
    quantization is ignored.
    """
    if not (np.isfinite(latitude) and abs(latitude) <= np.pi / 2):
        raise ModelError(f"latitude must be within ±90 deg, got {np.rad2deg(latitude)} deg")
    if not np.isfinite(heading):
        raise ModelError(f"heading must be finite, got {heading}")
    means, covs = _gyro_data([level, tilted])
    w_level = earth_rate_level(latitude, heading)
    rates = np.array([position_dcm(*a.pose.angles) @ w_level for a in (level, tilted)])
    delta = rates[1] - rates[0]
    for k in range(3):
        if abs(delta[k]) < MIN_SENSITIVITY * EARTH_RATE_RAD_S:
            raise ModelError(
                f"Earth rate on gyro axis {k} is the same in both positions: s{k + 1}{k + 1} unseen"
            )
    m = _two_position_solve(rates)
    stacked = np.concatenate(means)
    result = NavGyroResult(
        GYRO_BIAS_NAMES + GYRO_SCALE_NAMES,
        m @ stacked,
        m @ block_diag(*covs) @ m.T,
        earth_rate_body=rates,
    )
    logger.debug("nav_gyro_two_position: relative σ(s) %s", result.relative_scale_sigma)
    return result


def _two_position_solve(rates: FloatArray) -> FloatArray:
    """Linear map ``[V1, V2] -> [B, diag S]`` of the per-axis 2x2 solves (eq. 47-48)."""
    delta = rates[1] - rates[0]
    m = np.zeros((6, 6))
    for k in range(3):
        w1, w2 = rates[0, k], rates[1, k]
        m[k, [k, k + 3]] = w2 / delta[k], -w1 / delta[k]  # B = (w2 V1 - w1 V2)/Δw, eq. (47)
        m[k + 3, [k, k + 3]] = -1.0 / delta[k], 1.0 / delta[k]  # s = (V2 - V1)/Δw, eq. (48)
    return m


def _gyro_data(avgs: Sequence[PositionAverage]) -> tuple[FloatArray, list[FloatArray]]:
    means, covs = [], []
    for i, avg in enumerate(avgs):
        if avg.mean_gyro is None or avg.cov_gyro is None:
            raise ModelError(f"position {i} {pose_label(avg)} has no gyro data")
        mean, cov = np.asarray(avg.mean_gyro, float), np.asarray(avg.cov_gyro, float)
        if mean.shape != (3,) or cov.shape != (3, 3):
            raise ModelError(f"position {i}: gyro mean must be (3,) and covariance (3, 3)")
        if not (np.all(np.isfinite(mean)) and np.all(np.isfinite(cov))):
            raise ModelError(f"position {i}: gyro mean or covariance is not finite")
        means.append(mean)
        covs.append(cov)
    return np.array(means), covs
