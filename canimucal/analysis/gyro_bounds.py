"""What a plan's moves can tell about the gyro's S: per entry, its bound or "not identifiable".

The moves are the plan's own: from each position to the next, a minimum-jerk interpolation
of the angles over ``transient_s`` (what the simulator and an operator do), seen by a
nominal gyro (``S = I/lsb``) with white noise of ``noise_counts_per_rt_hz``. The bound is the
covariance of :func:`canimucal.model.moves.solve_moves` on those noise-free moves (the
Cramér–Rao bound, with each position's angle tolerances and its averaged gyro's noise shared
by the two moves that touch it, as the session's fit weighs them, and the held columns'
prior), and
its identifiability rules are the fit's: a column the moves do not turn about, or see only
with a σ above ``max_relative_sigma`` of its scale, is reported as not identifiable.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from canimucal.model.frames import position_dcm
from canimucal.model.moves import (
    AXES,
    Move,
    PositionKey,
    Shared,
    attitude_covariance,
    path_turn,
    pose_move,
    solve_moves,
)
from canimucal.model.positions import Plan
from canimucal.model.sensor import DEFAULT_GYRO_LSB
from canimucal.sim.imu import body_rate
from canimucal.sim.schedule import min_jerk

Array = NDArray[np.float64]


@dataclass(frozen=True)
class GyroMoveBounds:
    """Bounds of S from a plan's moves.

    ``relative_sigma`` 3×3: σ of each entry as a fraction of the scale factor, ``nan`` in a
    column that is not identifiable; ``moves`` one line per move (which axes it turns
    about); ``seen_by`` per body axis, the moves turning more than 20° about it; ``notes``
    why a column is not identifiable.
    """

    plan: str
    relative_sigma: Array
    identifiable: NDArray[np.bool_]
    moves: tuple[str, ...]
    seen_by: tuple[tuple[str, ...], tuple[str, ...], tuple[str, ...]]
    notes: tuple[str, ...]


def plan_moves(
    plan: Plan,
    *,
    sample_rate_hz: float = 100.0,
    transient_s: float = 2.0,
    gyro_lsb: float = DEFAULT_GYRO_LSB,
) -> list[Move]:
    """Noise-free moves between consecutive positions of ``plan`` as a nominal gyro sees them."""
    n = max(int(round(transient_s * sample_rate_hz)) + 1, 3)
    s, ds = min_jerk(np.linspace(0.0, 1.0, n))
    out = []
    for i, (a, b) in enumerate(zip(plan.positions, plan.positions[1:], strict=False)):
        delta = b.angles - a.angles
        angles = a.angles + np.outer(s, delta)
        rates = np.outer(ds / transient_s, delta)
        counts = body_rate(angles, rates) / gyro_lsb
        c_a, c_b = position_dcm(*a.angles), position_dcm(*b.angles)
        label = f"{i + 1}→{i + 2}"
        out.append(pose_move(counts, 1.0 / sample_rate_hz, c_a, c_b, 0.0, label, None, (i, i + 1)))
    return out


def plan_shared(plan: Plan, noise_counts: NDArray[np.float64], sample_rate_hz: float) -> Shared:
    """Return the errors the plan's moves share through each position (keys: indices).

    Each position's attitude is set to within its tolerances, and its mean gyro averages
    ``seconds · sample_rate_hz`` samples of white noise ``noise_counts`` (counts per sample).
    """
    positions = plan.positions
    attitude: dict[PositionKey, Array] = {
        i: attitude_covariance(p.angles, p.tolerances) for i, p in enumerate(positions)
    }
    mean_gyro: dict[PositionKey, Array] = {
        i: np.diag(noise_counts**2) / max(p.seconds * sample_rate_hz, 1.0)
        for i, p in enumerate(plan.positions)
    }
    return Shared(attitude, mean_gyro)


def gyro_move_bounds(
    plan: Plan,
    *,
    sample_rate_hz: float = 100.0,
    transient_s: float = 2.0,
    noise_counts_per_rt_hz: float = 1.0,
    gyro_lsb: float = DEFAULT_GYRO_LSB,
) -> GyroMoveBounds:
    """Bound S from the plan's moves (module doc)."""
    moves = plan_moves(
        plan, sample_rate_hz=sample_rate_hz, transient_s=transient_s, gyro_lsb=gyro_lsb
    )
    s0 = np.eye(3) / gyro_lsb
    if not moves:
        nan = np.full((3, 3), np.nan)
        return GyroMoveBounds(plan.name, nan, np.zeros(3, bool), (), ((), (), ()), ("no moves",))
    noise = np.full(3, noise_counts_per_rt_hz * np.sqrt(sample_rate_hz))
    fit = solve_moves(
        moves, np.zeros(3), s0, noise, shared=plan_shared(plan, noise, sample_rate_hz)
    )
    turns = [np.rad2deg(path_turn(m, s0, np.zeros(3))) for m in moves]
    lines = tuple(
        f"{m.label}: turns " + ", ".join(f"{t[j]:.0f}° about {AXES[j]}" for j in range(3))
        for m, t in zip(moves, turns, strict=True)
    )
    seen = tuple(
        tuple(m.label for m, t in zip(moves, turns, strict=True) if t[j] > 20.0) for j in range(3)
    )
    return GyroMoveBounds(
        plan=plan.name,
        relative_sigma=fit.S_sigma * gyro_lsb,
        identifiable=fit.identifiable,
        moves=lines,
        seen_by=(seen[0], seen[1], seen[2]),
        notes=fit.notes,
    )
