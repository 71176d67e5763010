"""The gyro's S from the moves the procedure confirmed (docs/design.md §10, gyro from moves).

Each move the gyro check passed (:mod:`.movecheck`) and whose target position was then
accepted is kept as raw rows: from the acceptance of one position to the pose check of the
next, with the sample counters. At the solve they become moves between two still positions
(:func:`canimucal.analysis.gyro_moves.move_between`: the known change ``C_end C_startᵀ``,
the bias from the two positions' means, the Earth rate removed when the latitude is known),
and S is fitted to them (:func:`canimucal.model.moves.solve_moves`). The known attitude
change is uncertain by both positions' setting tolerances: each position's attitude error
(:func:`~canimucal.model.moves.attitude_covariance` of its angle tolerances: a turn about
the vertical set by eye, e.g. the vehicle plan's 5°, weighs little about that axis only)
and the error of its mean gyro (the covariance of the accepted average) are shared by the
two moves that touch it, and the fit weighs the moves with that full covariance (GLS,
eq. F1–F2 of :mod:`canimucal.model.moves`). Columns of S the moves do not turn about are
reported as not identifiable and held at nominal, never estimated.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from canimucal.analysis.calibrate import SiteConditions, Solution
from canimucal.analysis.gyro_moves import (
    GSensitivity,
    RecordingMoves,
    fit_recording_moves,
    g_sensitivity_of,
    g_unused_note,
    move_between,
    resample_rows,
    sample_clock,
    with_moves,
)
from canimucal.errors import InputError
from canimucal.model.moves import Move, PositionKey, Shared, attitude_covariance
from canimucal.model.positions import Pose, PositionAverage

Array = NDArray[np.float64]


@dataclass(frozen=True)
class ConfirmedMove:
    """A move the gyro confirmed: its raw rows and the two positions' poses and mean gyro.

    ``start_key``/``end_key`` are the two positions' indices in the plan, and
    ``start_cov``/``end_cov`` the covariance (counts²) of their mean gyro: the errors the
    move shares with its neighbours. Without them the move's attitude error is its own
    (``√(σ_a² + σ_b²)`` per axis, each the largest tolerance of the pose).
    """

    start: Pose
    end: Pose
    start_gyro: Array
    end_gyro: Array
    gyro: Array
    counter: Array
    label: str
    accel: Array | None = None
    start_key: int | None = None
    end_key: int | None = None
    start_cov: Array | None = None
    end_cov: Array | None = None


def pose_sigma_rad(pose: Pose) -> float:
    """1σ (rad) of a pose's attitude: the largest of its angle tolerances."""
    return float(np.max(pose.tolerances))


def build_moves(
    confirmed: Sequence[ConfirmedMove],
    site: SiteConditions,
    sample_rate_hz: float,
    g_sensitivity: GSensitivity | None = None,
    trim: Array | None = None,
) -> tuple[list[Move], list[Array], list[str], Shared | None]:
    """Turn confirmed moves into fit moves with their biases; notes say which were dropped.

    With ``g_sensitivity`` a move whose accelerometer rows are complete enough carries its
    specific force, and ``G f`` is removed from it (:func:`move_between`); ``trim`` (rad) is
    the mounting trim of the accelerometer fit, so the moves are the unit's. The last item
    holds the errors the moves share through their positions (None when none is keyed).
    """
    s0 = np.eye(3) / site.gyro_lsb
    moves: list[Move] = []
    biases: list[Array] = []
    notes: list[str] = []
    attitude: dict[PositionKey, Array] = {}
    mean_gyro: dict[PositionKey, Array] = {}
    for m in confirmed:
        if np.all(np.isfinite(m.counter)):
            clock = sample_clock(m.counter)
        else:
            clock = np.arange(m.gyro.shape[0], dtype=float)
        rows = resample_rows(m.gyro, clock, sample_rate_hz, m.label, notes)
        if rows is None:
            continue
        keys = None if m.start_key is None or m.end_key is None else (m.start_key, m.end_key)
        sigma = float(np.hypot(pose_sigma_rad(m.start), pose_sigma_rad(m.end)))
        if keys is not None:  # the poses' errors are shared with the neighbouring moves
            sigma = 0.0
            for key, pose, cov in ((keys[0], m.start, m.start_cov), (keys[1], m.end, m.end_cov)):
                if key not in attitude:
                    attitude[key] = attitude_covariance(pose.angles, pose.tolerances)
                if cov is not None and np.all(np.isfinite(cov)):
                    mean_gyro[key] = np.asarray(cov, dtype=float)
        force = None
        if g_sensitivity is not None and m.accel is not None:
            accel = resample_rows(m.accel, clock, sample_rate_hz, m.label, [])
            if accel is not None and accel.shape == rows.shape:
                force = g_sensitivity.force(accel)
        move, bias = move_between(
            rows,
            sample_rate_hz,
            site,
            s0,
            (m.start.angles, m.start_gyro),
            (m.end.angles, m.end_gyro),
            sigma,
            m.label,
            g_sensitivity,
            force,
            keys,
            trim,
        )
        moves.append(move)
        biases.append(bias)
    return moves, biases, notes, (Shared(attitude, mean_gyro) if attitude else None)


def fit_confirmed_moves(
    solution: Solution,
    confirmed: Sequence[ConfirmedMove],
    averages: Sequence[PositionAverage],
    site: SiteConditions,
    sample_rate_hz: float,
) -> Solution:
    """Return ``solution`` with gyro S from the confirmed moves (unseen columns held).

    Without a usable move the solution keeps its nominal S and says why in its warnings.
    """
    stds = [a.std_gyro for a in averages if a.std_gyro is not None]
    if not confirmed or not stds or solution.joint is None:
        return solution
    gs = g_sensitivity_of(solution, site)
    trim = solution.joint.trim  # the mounting trim: the moves as the unit turned them
    moves, biases, notes, shared = build_moves(confirmed, site, sample_rate_hz, gs, trim)
    rate_sigma = np.median(np.asarray(stds, dtype=float), axis=0)
    found = RecordingMoves(tuple(moves), tuple(biases), rate_sigma, tuple(notes), shared)
    try:
        fit = fit_recording_moves(found, site, None if gs is None else gs.G)
    except InputError as exc:
        return dataclasses.replace(solution, warnings=(*solution.warnings, str(exc)))
    return with_moves(solution, fit, (*found.notes, *g_unused_note(solution, gs)))
