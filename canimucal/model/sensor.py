"""Sensor error models (docs/design.md §2): accel ``U = b + K f``, gyro ``V = B + S w + G f``.

Units: outputs in counts, K counts per m/s², S counts per rad/s, G counts per m/s².
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

STANDARD_GRAVITY = 9.80665
"""Standard gravity (m/s²): a last-resort default only (docs/design.md §2)."""

DEFAULT_ACCEL_LSB = STANDARD_GRAVITY / 2048.0
"""Nominal accelerometer LSB for ±16 g on INT16, m/s² per count."""

DEFAULT_GYRO_LSB = float(np.pi / (180.0 * 16.4))
"""Nominal gyro LSB for ±2000 °/s on INT16, rad/s per count."""


@dataclass(frozen=True)
class AccelParams:
    """Accelerometer bias (counts) and scale/cross-axis matrix K (counts per m/s²)."""

    bias: NDArray[np.float64]
    K: NDArray[np.float64]

    @classmethod
    def nominal(cls, lsb: float = DEFAULT_ACCEL_LSB) -> AccelParams:
        """Zero bias and ``K = I / lsb`` (the sign of ``lsb`` is kept)."""
        return cls(np.zeros(3), np.eye(3) / lsb)

    def output(self, f_body: ArrayLike) -> NDArray[np.float64]:
        """Noise-free output for specific force ``f_body`` (``(3,)`` or ``(n, 3)``)."""
        f = np.asarray(f_body, dtype=float)
        return np.asarray(self.bias + f @ self.K.T, dtype=np.float64)

    def correct(self, counts: ArrayLike) -> NDArray[np.float64]:
        """Specific force from outputs: ``K⁻¹ (U − b)``."""
        u = np.asarray(counts, dtype=float)
        return np.asarray(np.linalg.solve(self.K, (u - self.bias).T).T, dtype=np.float64)


@dataclass(frozen=True)
class GyroParams:
    """Gyro bias (counts), scale/cross-axis S (counts per rad/s), g-sensitivity G."""

    bias: NDArray[np.float64]
    S: NDArray[np.float64]
    G: NDArray[np.float64]

    @classmethod
    def nominal(cls, lsb: float = DEFAULT_GYRO_LSB) -> GyroParams:
        """Zero bias, ``S = I / lsb``, ``G = 0``."""
        return cls(np.zeros(3), np.eye(3) / lsb, np.zeros((3, 3)))

    def output(self, w_body: ArrayLike, f_body: ArrayLike) -> NDArray[np.float64]:
        """Noise-free output for rate ``w_body`` and specific force ``f_body``."""
        w = np.asarray(w_body, dtype=float)
        f = np.asarray(f_body, dtype=float)
        return np.asarray(self.bias + w @ self.S.T + f @ self.G.T, dtype=np.float64)

    def correct(self, counts: ArrayLike, f_body: ArrayLike) -> NDArray[np.float64]:
        """Angular rate from outputs: ``S⁻¹ (V − B − G f)``."""
        v = np.asarray(counts, dtype=float) - self.bias - np.asarray(f_body, float) @ self.G.T
        return np.asarray(np.linalg.solve(self.S, v.T).T, dtype=np.float64)
