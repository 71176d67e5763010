"""Per-position averages drawn straight from the sensor model, without sample streams.

The fast path for Monte Carlo studies of the estimators: the mean of ``T`` seconds of white
noise of density ``N`` (counts/√Hz) has standard deviation ``N/√T``, so a position's average
is the noise-free output plus one Gaussian draw. Angle-setting errors (each position's
``tolerance``) are drawn too when ``angle_errors`` is true.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike

from canimucal.model.frames import (
    TiltModel,
    earth_rate_level,
    position_dcm,
    specific_force_level,
)
from canimucal.model.positions import PlannedPosition, Pose, PositionAverage
from canimucal.model.sensor import AccelParams, GyroParams


def simulate_averages(
    positions: Sequence[PlannedPosition],
    accel: AccelParams,
    rng: np.random.Generator,
    *,
    g: float = 9.80665,
    gyro: GyroParams | None = None,
    latitude: float = 0.0,
    heading: float = 0.0,
    alpha0: float = 0.0,
    beta0: float = 0.0,
    tilt_model: TiltModel = "rigid",
    trim: ArrayLike | None = None,
    accel_noise_density: ArrayLike = 1.0,
    gyro_noise_density: ArrayLike = 1.0,
    sample_rate_hz: float = 200.0,
    angle_errors: bool = True,
) -> list[PositionAverage]:
    """Draw one :class:`PositionAverage` per planned position.

    Noise densities are output-referred, counts/√Hz (scalar or per axis). Angles in radians;
    ``trim`` ``(alpha_m, beta_m, psi_m)`` the unit's mounting trim in the vehicle (docs/method.md
    §3, eq. T1: ``C = R_m C_pose T0``).
    """
    f_level = specific_force_level(g)
    w_level = earth_rate_level(latitude, heading)
    na = np.broadcast_to(np.asarray(accel_noise_density, dtype=float), (3,))
    ng = np.broadcast_to(np.asarray(gyro_noise_density, dtype=float), (3,))
    out = []
    for p in positions:
        angles = p.angles
        if angle_errors:
            angles = angles + rng.normal(0.0, p.tolerances)
        c = position_dcm(
            angles[0], angles[1], angles[2], alpha0=alpha0, beta0=beta0,
            tilt_model=tilt_model, trim=trim,
        )  # fmt: skip
        f = c @ f_level
        cov_a = np.diag(na**2 / p.seconds)
        mean_a = accel.output(f) + rng.multivariate_normal(np.zeros(3), cov_a)
        mean_g = cov_g = std_g = None
        if gyro is not None:
            cov_g = np.diag(ng**2 / p.seconds)
            mean_g = gyro.output(c @ w_level, f) + rng.multivariate_normal(np.zeros(3), cov_g)
            std_g = ng * np.sqrt(sample_rate_hz)
        n = int(round(p.seconds * sample_rate_hz))
        out.append(
            PositionAverage(
                pose=Pose(p.alpha, p.beta, p.psi, p.tolerance, psi_tolerance=p.psi_tolerance),
                n=n,
                mean_accel=mean_a,
                cov_accel=cov_a,
                mean_gyro=mean_g,
                cov_gyro=cov_g,
                std_accel=na * np.sqrt(sample_rate_hz),
                std_gyro=std_g,
                seconds=p.seconds,
            )
        )
    return out
