"""Local gravity from latitude and height: WGS-84 normal gravity (NIMA TR8350.2, §4)."""

from __future__ import annotations

import numpy as np

_GAMMA_EQUATOR = 9.7803253359  # m/s², normal gravity at the equator
_SOMIGLIANA_K = 0.00193185265241
_E2 = 0.00669437999013  # first eccentricity squared
_A = 6378137.0  # semi-major axis, m
_F = 1.0 / 298.257223563  # flattening
_M = 0.00344978650684  # ω²a²b/GM


def normal_gravity(latitude: float, height_m: float = 0.0) -> float:
    """Return normal gravity (m/s²) at geodetic ``latitude`` (radians) and ellipsoidal height.

    Somigliana's closed form on the ellipsoid (TR8350.2 eq. 4-1) and the second-order
    height correction (eq. 4-3).
    """
    s2 = float(np.sin(latitude)) ** 2
    gamma0 = _GAMMA_EQUATOR * (1.0 + _SOMIGLIANA_K * s2) / np.sqrt(1.0 - _E2 * s2)
    h = float(height_m)
    correction = 1.0 - 2.0 / _A * (1.0 + _F + _M - 2.0 * _F * s2) * h + 3.0 * h * h / _A**2
    return float(gamma0 * correction)
