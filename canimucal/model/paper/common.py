"""Shared parts of the paper's closed-form estimators: the result type and σ propagation.

The estimators (Avrutov & Pozniak 2023, physics corrected) live in
:mod:`canimucal.model.paper.accel` (eq. 11-34) and :mod:`canimucal.model.paper.gyro`
(eq. 36-48). Each takes :class:`~canimucal.model.positions.PositionAverage` objects and returns a
frozen :class:`ClosedFormResult`: the estimates *and* their covariance, propagated linearly from
the covariances of the means (counts²). Parameter names follow the calibration JSON
(``accel.bias[0]``, ``accel.K[1][1]``, ``gyro.S[2][2]``, ``base_tilt.alpha0``); angles are
radians. The corrections to the printed equations are those of docs/method.md §2.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from canimucal.errors import ModelError
from canimucal.model.positions import PositionAverage

FloatArray = NDArray[np.float64]

ACCEL_BIAS_NAMES = tuple(f"accel.bias[{i}]" for i in range(3))
ACCEL_SCALE_NAMES = tuple(f"accel.K[{i}][{i}]" for i in range(3))
GYRO_BIAS_NAMES = tuple(f"gyro.bias[{i}]" for i in range(3))
GYRO_SCALE_NAMES = tuple(f"gyro.S[{i}][{i}]" for i in range(3))
TILT_NAMES = ("base_tilt.alpha0", "base_tilt.beta0")
TILT_CHANNEL_NAMES = (
    "base_tilt.alpha0.x",  # eq. (23)
    "base_tilt.alpha0.y",  # eq. (29)
    "base_tilt.alpha0.z",  # eq. (33)
    "base_tilt.beta0.y",  # eq. (28)
    "base_tilt.beta0.z",  # eq. (32)
)

ANGLE_TOL_RAD = 1e-12
"""A planned angle below this is zero (poses are exact planned values, not measurements)."""

MIN_SENSITIVITY = 1e-9
"""Smallest |denominator| accepted, relative to g (accel) or Ω (gyro)."""


@dataclass(frozen=True, eq=False)
class ClosedFormResult:
    """Named estimates with their covariance (linear propagation from the means').

    ``values[i]`` is the estimate called ``names[i]``; ``covariance`` is in the same order.
    Units: counts for biases, counts per m/s² (accel) or per rad/s (gyro) for scale factors,
    radians for angles.
    """

    names: tuple[str, ...]
    values: FloatArray
    covariance: FloatArray

    def __post_init__(self) -> None:
        values = np.array(self.values, dtype=float)
        covariance = np.array(self.covariance, dtype=float)
        n = len(self.names)
        if values.shape != (n,) or covariance.shape != (n, n):
            raise ValueError(f"{n} names need {n} values and an {n}x{n} covariance")
        values.setflags(write=False)
        covariance.setflags(write=False)
        object.__setattr__(self, "values", values)
        object.__setattr__(self, "covariance", covariance)

    @property
    def sigmas(self) -> FloatArray:
        """Standard deviation of every estimate, in ``names`` order."""
        return np.sqrt(np.clip(np.diag(self.covariance), 0.0, None))

    def index(self, name: str) -> int:
        """Position of ``name`` in ``names`` (KeyError if absent)."""
        try:
            return self.names.index(name)
        except ValueError:
            raise KeyError(f"no estimate named {name!r}") from None

    def value(self, name: str) -> float:
        """Return the estimate called ``name``."""
        return float(self.values[self.index(name)])

    def sigma(self, name: str) -> float:
        """Return the standard deviation of the estimate called ``name``."""
        return float(self.sigmas[self.index(name)])

    def correlation(self, first: str, second: str) -> float:
        """Correlation coefficient of two estimates (NaN if either has zero variance)."""
        i, j = self.index(first), self.index(second)
        denominator = self.sigmas[i] * self.sigmas[j]
        return float(self.covariance[i, j] / denominator) if denominator > 0 else float("nan")

    def as_dict(self) -> dict[str, tuple[float, float]]:
        """``{name: (value, sigma)}`` for every estimate."""
        return {
            n: (float(v), float(s))
            for n, v, s in zip(self.names, self.values, self.sigmas, strict=True)
        }

    def _pick(self, names: Sequence[str]) -> FloatArray:
        return np.array([self.value(n) for n in names])

    def _pick_sigma(self, names: Sequence[str]) -> FloatArray:
        return np.array([self.sigma(n) for n in names])


def propagate_covariance(
    func: Callable[[FloatArray], FloatArray], x: FloatArray, cov_x: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """``func(x)`` and its covariance ``J cov_x Jᵀ`` with a central-difference Jacobian."""
    y = func(x)
    jac = np.empty((y.size, x.size))
    for i, step in enumerate(1e-6 * np.maximum(1.0, np.abs(x))):
        dx = np.zeros_like(x)
        dx[i] = step
        jac[:, i] = (func(x + dx) - func(x - dx)) / (2.0 * step)
    return y, jac @ cov_x @ jac.T


def check_g(g: float) -> None:
    """Raise ModelError unless ``g`` is a positive finite number (m/s²)."""
    if not (np.isfinite(g) and g > 0):
        raise ModelError(f"g must be a positive finite number, got {g!r}")


def pose_label(avg: PositionAverage) -> str:
    """``(alpha, beta) deg`` of a position, for error messages."""
    alpha, beta = np.rad2deg(avg.pose.alpha), np.rad2deg(avg.pose.beta)
    return f"({alpha:.3f}, {beta:.3f}) deg"
