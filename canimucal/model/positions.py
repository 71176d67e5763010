"""Poses, plans and per-position averages: the data every estimator consumes.

Angles are radians here (degrees live only in files and flags). Sensor values are counts.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

DEFAULT_TOLERANCE_RAD = float(np.deg2rad(0.1))
"""Default angle-setting tolerance of one position (docs/design.md §3: 0.1°)."""

DEFAULT_SECONDS = 30.0
"""Default averaging time of one position."""

DEFAULT_SETUP_SECONDS = 60.0
"""Operator time to set up one position on a bench (move the unit, let it settle)."""


@dataclass(frozen=True)
class Pose:
    """One position of the procedure: tilt ``alpha`` about z, ``beta`` about x, turn ``psi``.

    ``tolerance`` is the 1σ angle-setting error (radians) assumed for each angle;
    ``psi_tolerance`` (keyword only) overrides it for the turn ``psi`` (a vehicle turned on
    the spot is set to a few degrees, its tilts far better).
    """

    alpha: float
    beta: float
    psi: float = 0.0
    tolerance: float = DEFAULT_TOLERANCE_RAD
    psi_tolerance: float | None = field(default=None, kw_only=True)

    @classmethod
    def from_deg(cls, alpha: float, beta: float, psi: float = 0.0, tolerance: float = 0.1) -> Pose:
        """Build a pose from degrees (angles and the 1σ ``tolerance``)."""
        alpha, beta, psi, tolerance = np.deg2rad([alpha, beta, psi, tolerance]).tolist()
        return cls(alpha, beta, psi, tolerance)

    @property
    def angles(self) -> NDArray[np.float64]:
        """``[alpha, beta, psi]`` in radians."""
        return np.array([self.alpha, self.beta, self.psi])

    @property
    def tolerances(self) -> NDArray[np.float64]:
        """1σ setting error of ``[alpha, beta, psi]`` in radians."""
        psi_tol = self.tolerance if self.psi_tolerance is None else self.psi_tolerance
        return np.array([self.tolerance, self.tolerance, psi_tol])


@dataclass(frozen=True)
class PlannedPosition(Pose):
    """A pose with the averaging time the plan gives it."""

    seconds: float = DEFAULT_SECONDS


@dataclass(frozen=True)
class Plan:
    """A named sequence of positions (``two``, ``five``, ``recommended``, ``vehicle``, ``custom``).

    ``prior_k_sigma`` is the relative 1σ of a factory K the plan relies on for what its poses
    cannot separate (None: the data alone); ``setup_seconds`` the operator's time to set up
    one position, for :attr:`operator_minutes`.
    """

    name: str
    positions: tuple[PlannedPosition, ...]
    prior_k_sigma: float | None = None
    setup_seconds: float = DEFAULT_SETUP_SECONDS

    @property
    def operator_minutes(self) -> float:
        """Minutes of the operator's time: setting up each position plus its averaging."""
        return (self.total_seconds + self.setup_seconds * len(self.positions)) / 60.0

    @property
    def total_seconds(self) -> float:
        """Total averaging time of the plan."""
        return float(sum(p.seconds for p in self.positions))

    def with_total_seconds(self, total: float) -> Plan:
        """Return the same poses with the averaging time spread equally to ``total`` seconds."""
        each = total / len(self.positions)
        return replace(
            self,
            positions=tuple(
                PlannedPosition(
                    p.alpha, p.beta, p.psi, p.tolerance, each, psi_tolerance=p.psi_tolerance
                )
                for p in self.positions
            ),
        )


@dataclass(frozen=True)
class PositionAverage:
    """What one static position contributes: the mean outputs and their uncertainty.

    ``cov_accel``/``cov_gyro`` are covariances **of the mean** (counts²). Gyro fields are
    ``None`` when no gyro data were recorded.
    """

    pose: Pose
    n: int
    mean_accel: NDArray[np.float64]
    cov_accel: NDArray[np.float64]
    mean_gyro: NDArray[np.float64] | None = None
    cov_gyro: NDArray[np.float64] | None = None
    std_accel: NDArray[np.float64] = field(default_factory=lambda: np.full(3, np.nan))
    std_gyro: NDArray[np.float64] | None = None
    seconds: float = 0.0
    temp_c: float | None = None
    lost: int = 0
    trial: int | None = None
    """Which trial (mounting of the unit, the recording's ``trial`` column) the position
    belongs to; None: the recording has no trials. The joint fit gives each trial its own
    biases (:mod:`canimucal.model.joint`)."""


def average_position(
    pose: Pose,
    accel: ArrayLike,
    gyro: ArrayLike | None = None,
    sample_rate_hz: float | None = None,
    temp_c: float | None = None,
    lost: int = 0,
) -> PositionAverage:
    """Average the samples of one static position.

    ``accel`` and ``gyro`` are ``(n, 3)`` count arrays; rows with NaN (a lost PDO half) are
    dropped per sensor. The covariance of the mean is the sample covariance over ``n``.
    """
    a = _finite_rows(np.asarray(accel, dtype=float))
    if a.shape[0] < 2:
        raise ValueError("a position needs at least two accelerometer samples")
    mean_a, cov_a, std_a = _mean_cov(a)
    mean_g = cov_g = std_g = None
    if gyro is not None:
        gy = _finite_rows(np.asarray(gyro, dtype=float))
        if gy.shape[0] >= 2:
            mean_g, cov_g, std_g = _mean_cov(gy)
    seconds = a.shape[0] / sample_rate_hz if sample_rate_hz else 0.0
    return PositionAverage(
        pose=pose,
        n=int(a.shape[0]),
        mean_accel=mean_a,
        cov_accel=cov_a,
        mean_gyro=mean_g,
        cov_gyro=cov_g,
        std_accel=std_a,
        std_gyro=std_g,
        seconds=seconds,
        temp_c=temp_c,
        lost=lost,
    )


def _finite_rows(x: NDArray[np.float64]) -> NDArray[np.float64]:
    if x.ndim != 2 or x.shape[1] != 3:
        raise ValueError(f"samples must be an (n, 3) array, got shape {x.shape}")
    finite = np.all(np.isfinite(x), axis=1)
    return x if bool(finite.all()) else x[finite]  # no copy of a position without losses


def _mean_cov(
    x: NDArray[np.float64],
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    n = x.shape[0]
    cov = np.cov(x, rowvar=False, ddof=1)
    return x.mean(axis=0), cov / n, np.sqrt(np.diag(cov))


def poses_of(averages: Sequence[PositionAverage]) -> NDArray[np.float64]:
    """``(n, 3)`` array of the ``[alpha, beta, psi]`` of each average."""
    return np.array([a.pose.angles for a in averages])
