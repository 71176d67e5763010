"""The pose of the simulated unit against time: holds, smooth moves, and plan schedules.

A trajectory is a list of segments from "now" on. A move interpolates the angles
``(alpha, beta, psi)`` (radians) with the minimum-jerk profile ``s(τ) = 10τ³ − 15τ⁴ + 6τ⁵``,
whose rate and acceleration vanish at both ends, so the simulated gyros see a smooth bump.
A scheduled hold carries its position's index in the plan; moves, and any hold that is not a
plan position (the start, the end after the last position), carry ``-1``.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from canimucal.errors import InputError
from canimucal.model.positions import Plan, PlannedPosition, Pose

ALREADY_THERE_SIGMAS = 5.0
"""A unit within this many 1σ of the first position is there already (no move first)."""

_EPS_S = 1e-9
"""Boundary slack: a sample within 1 ns of a boundary belongs to the later segment."""

Array = NDArray[np.float64]


@dataclass(frozen=True)
class TrajectorySample:
    """Angles (n, 3) rad, angle rates (n, 3) rad/s, ``moving`` and plan ``index`` per time."""

    angles: Array
    rates: Array
    moving: NDArray[np.bool_]
    index: NDArray[np.int64]


def min_jerk(tau: ArrayLike) -> tuple[Array, Array]:
    """Minimum-jerk profile ``s(τ)`` and its derivative ``ds/dτ`` for τ clipped to [0, 1]."""
    t = np.clip(np.asarray(tau, dtype=float), 0.0, 1.0)
    s = t**3 * (10.0 - 15.0 * t + 6.0 * t * t)
    ds = 30.0 * t * t * (1.0 - t) ** 2
    return s, ds


class PoseTrajectory:
    """Piecewise pose of the unit: holds and minimum-jerk moves, starting from a pose."""

    def __init__(self, angles: ArrayLike = (0.0, 0.0, 0.0)) -> None:
        start = _angles(angles, "initial pose")
        self._starts = np.array([-np.inf])
        self._durations = np.array([np.inf])
        self._from = start[None, :].copy()
        self._to = start[None, :].copy()
        self._index = np.array([-1], dtype=np.int64)
        self._end_s: float | None = None

    @property
    def end_s(self) -> float | None:
        """Time the last scheduled position ends (``None`` without a schedule)."""
        return self._end_s

    def move_to(self, now_s: float, angles: ArrayLike, transient_s: float) -> None:
        """From ``now_s``, move to ``angles`` over ``transient_s`` and hold there (index -1)."""
        target = _angles(angles, "pose")
        current = self.sample(np.array([now_s])).angles[0]
        segments: list[tuple[float, float, Array, Array, int]] = []
        t = _add_move(segments, now_s, current, target, _transient(transient_s))
        segments.append((t, np.inf, target, target, -1))
        self._set(segments)
        self._end_s = None

    def follow(self, now_s: float, plan: Plan, transient_s: float) -> None:
        """From ``now_s``, visit the plan's positions in order, each held for its seconds.

        The unit moves between positions over ``transient_s`` and holds the last pose at
        the end, with index -1. It does not move before the first position when it is
        already there within that position's setting accuracy (:data:`ALREADY_THERE_SIGMAS`
        × its 1σ per angle): the operator set it there, and the schedule starts with the
        first hold, as a recorder that knows only the nominal plan expects.
        """
        if not plan.positions:
            raise InputError("schedule: the plan has no positions")
        transient = _transient(transient_s)
        current = self.sample(np.array([now_s])).angles[0]
        segments: list[tuple[float, float, Array, Array, int]] = []
        t = now_s
        for i, position in enumerate(plan.positions):
            if not (np.isfinite(position.seconds) and position.seconds > 0.0):
                raise InputError(f"schedule: position {i} seconds must be positive")
            target = _angles(position.angles, f"position {i}")
            there = i == 0 and np.all(
                np.abs(target - current) <= ALREADY_THERE_SIGMAS * position.tolerances
            )
            if not there:
                t = _add_move(segments, t, current, target, transient)
            segments.append((t, position.seconds, target, target, i))
            t += position.seconds
            current = target
        segments.append((t, np.inf, current, current, -1))
        self._set(segments)
        self._end_s = t

    def sample(self, t_s: ArrayLike) -> TrajectorySample:
        """Evaluate angles, angle rates, motion flag and plan index at times ``t_s``."""
        t = np.atleast_1d(np.asarray(t_s, dtype=float))
        seg = np.clip(np.searchsorted(self._starts, t + _EPS_S, side="right") - 1, 0, None)
        first = int(seg[0]) if seg.size else 0
        if seg.size and first == seg[-1] and not self._is_move(first):
            return self._hold(first, t.shape[0])  # fast path: the whole block in one hold
        start, duration = self._starts[seg], self._durations[seg]
        finite = np.isfinite(duration) & (duration > 0.0)
        moving = finite & (self._index[seg] < 0)
        safe = np.where(moving, duration, 1.0)
        s, ds = min_jerk(np.where(moving, (t - start) / safe, 0.0))
        delta = self._to[seg] - self._from[seg]
        angles = self._from[seg] + delta * s[:, None]
        rates = delta * (ds / safe)[:, None] * moving[:, None]
        return TrajectorySample(angles, rates, moving, self._index[seg].copy())

    def _is_move(self, seg: int) -> bool:
        return bool(self._index[seg] < 0 and 0.0 < self._durations[seg] < np.inf)

    def _hold(self, seg: int, n: int) -> TrajectorySample:
        return TrajectorySample(
            angles=np.broadcast_to(self._to[seg], (n, 3)),
            rates=np.zeros((n, 3)),
            moving=np.zeros(n, dtype=bool),
            index=np.full(n, self._index[seg], dtype=np.int64),
        )

    def _set(self, segments: list[tuple[float, float, Array, Array, int]]) -> None:
        self._starts = np.array([s[0] for s in segments])
        self._durations = np.array([s[1] for s in segments])
        self._from = np.array([s[2] for s in segments])
        self._to = np.array([s[3] for s in segments])
        self._index = np.array([s[4] for s in segments], dtype=np.int64)


def _add_move(
    segments: list[tuple[float, float, Array, Array, int]],
    t: float,
    current: Array,
    target: Array,
    transient_s: float,
) -> float:
    """Append a move from ``current`` to ``target`` at ``t`` if needed; return its end."""
    if transient_s > 0.0 and not np.array_equal(current, target):
        segments.append((t, transient_s, current, target, -1))
        return t + transient_s
    return t


def _angles(angles: ArrayLike, what: str) -> Array:
    a = np.asarray(angles, dtype=float).reshape(-1)
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise InputError(f"schedule: {what} must be three finite angles (alpha, beta, psi)")
    return a


def _transient(transient_s: float) -> float:
    t = float(transient_s)
    if not (np.isfinite(t) and t >= 0.0):
        raise InputError(f"schedule: transient_s must be a non-negative number, got {t!r}")
    return t


def set_by_operator(plan: Plan, rng: np.random.Generator) -> Plan:
    """Return the poses an operator really sets: each angle off by a draw from its 1σ.

    The draw is each position's ``tolerances`` (``psi_tolerance`` for the turn when the plan
    gives one), one rigid body for every unit that follows the result. The recording keeps
    the plan's nominal angles as labels, as in the field; only the simulated unit moves to
    the drawn ones.
    """
    positions = []
    for p in plan.positions:
        alpha, beta, psi = operator_angles(p, rng)
        positions.append(
            PlannedPosition(alpha, beta, psi, p.tolerance, p.seconds, psi_tolerance=p.psi_tolerance)
        )
    return dataclasses.replace(plan, positions=tuple(positions))


def operator_angles(pose: Pose, rng: np.random.Generator) -> Array:
    """Return the angles (rad) an operator really sets for ``pose``: each off by its 1σ."""
    return np.asarray(pose.angles + rng.normal(0.0, pose.tolerances), dtype=float)
