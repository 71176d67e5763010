"""Gyro S from the moves of a recording, folded into a solved calibration (docs/design.md §10).

Moves come from two sources:

- **Between labelled positions**: the samples from the last row of one position to the
  first row of the next, both with known angles. The known change is ``C_next C_prevᵀ``
  (``position_dcm``), uncertain by the angle tolerances of both ends: each position's
  attitude error (:func:`~canimucal.model.moves.attitude_covariance`) and the error of its
  mean gyro (half of each adjacent move's bias) are shared by the two moves that touch it,
  and the fit weighs the moves with that full covariance (:class:`~canimucal.model.moves.
  Shared`, eq. F1–F2 of :mod:`canimucal.model.moves`). A move with
  lost samples (counter jumps, else time steps beyond one sample interval, or NaN gyro
  rows) up to 1 % of its samples is filled by linear interpolation; one with more, or with
  a gap longer than :data:`MAX_GAP_S`, is dropped with a note.
- **Known turns** (:class:`KnownTurn`, imucal's ``*_rot`` sections): the turn's rows plus
  the still sample on each side, the known angle about the fixed axis, uncertain by the
  same ``√2 · tolerance``.

In a recording of several trials (its ``trial`` column, docs/design.md §5 Trials) the
positions are keyed by (trial, label): a move's two positions and their gyro means are its
own trial's, so each move is integrated with its trial's own bias, and the step from one
trial's last position to the next trial's first (the unit re-mounted) is no move.

The gyro bias is the one the static fit found. Around a move between positions, the local
bias is the mean of the two positions' gyro means (drift removed), less the Earth rate each
pose sees when the latitude is known; the Earth rate is then removed in the integration
(:func:`canimucal.model.moves.move_rotation`). Without a latitude, and for known turns, the
Earth rate stays in the bias (as imucal does), an error of at most Ω·T per move.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from canimucal.analysis.calibrate import SiteConditions, Solution
from canimucal.errors import InputError
from canimucal.io.calibration import AccelBlock, re_estimated
from canimucal.io.recording import Recording
from canimucal.model.frames import earth_rate_level, position_dcm, specific_force_level
from canimucal.model.moves import (
    AXES,
    Move,
    MovesFit,
    PositionKey,
    Shared,
    attitude_covariance,
    pose_move,
    solve_moves,
    turn_move,
)
from canimucal.model.vocabulary.constants import COUNTER_MODULUS

Array = NDArray[np.float64]

MAX_LOST_FRACTION = 0.01
"""A move may lose at most this fraction of its samples."""
MAX_GAP_S = 0.1
"""A move with a time gap longer than this is dropped."""


@dataclass(frozen=True)
class RecordingMoves:
    """The moves found in a recording, the bias used for each, and notes on dropped ones.

    ``shared``: the errors the moves between positions share through their positions.
    """

    moves: tuple[Move, ...]
    biases: tuple[Array, ...]
    rate_sigma_counts: Array
    notes: tuple[str, ...]
    shared: Shared | None = None


@dataclass(frozen=True)
class GSensitivity:
    """The gyro's G (counts per m/s²) and the accelerometer correction giving the force."""

    G: Array
    accel: AccelBlock
    accel_lsb: float

    def force(self, accel_counts: Array) -> Array:
        """Specific force (m/s²) of raw accelerometer rows, as the calibration corrects them."""
        return self.accel.correct(accel_counts, self.accel_lsb)


def g_sensitivity_of(solution: Solution, site: SiteConditions) -> GSensitivity | None:
    """G of a solution when the static fit determined every entry, else None."""
    gyro = solution.record.gyro
    if gyro is None or gyro.G is None or any(v is None for row in gyro.G for v in row):
        return None
    return GSensitivity(gyro.G_matrix(), solution.record.accel, site.accel_lsb)


def g_unused_note(solution: Solution, g_sensitivity: GSensitivity | None) -> tuple[str, ...]:
    """Say so when G was asked for but the positions left some of it undetermined."""
    joint = solution.joint
    if g_sensitivity is not None or joint is None:
        return ()
    if not any(n.startswith("gyro.G") for n in joint.names):
        return ()
    return (
        "gyro G is not determined by these positions: the moves are integrated with G f "
        "left in each move's bias",
    )


def recording_moves(
    rec: Recording,
    site: SiteConditions,
    *,
    tolerance_deg: float = 0.1,
    pose_moves: bool = True,
    pose_sigmas: Mapping[PositionKey, float | Sequence[float]] | None = None,
    g_sensitivity: GSensitivity | None = None,
    trim: Array | None = None,
) -> RecordingMoves:
    """Collect the moves of ``rec`` (module doc); ``pose_moves`` false keeps known turns only.

    ``pose_sigmas`` (a position's key, its label or ``(trial, label)`` → 1σ in rad of that
    position's angles, one for all three or
    ``(alpha, beta, psi)``) replaces ``tolerance_deg`` for the positions it names (a known
    turn keeps ``√2 · tolerance``). ``g_sensitivity`` removes ``G f`` from the moves between
    positions (:func:`move_between`); ``trim`` is the mounting trim the accelerometer fit
    found (the poses' rotations as the unit saw them, :func:`move_between`).
    """
    runs = _position_runs(rec)
    keys = [_key(rec, label, first) for label, first, _ in runs]
    if not runs:
        raise InputError(f"{rec.source or 'recording'}: gyro moves need labelled positions")
    fs = rec.sample_rate_hz
    s0 = np.eye(3) / site.gyro_lsb
    static = np.concatenate([rec.gyro[a : b + 1] for _, a, b in runs]).astype(np.float64)
    static = static[np.all(np.isfinite(static), axis=1)]
    sigma = np.median([np.nanstd(_f64(rec.gyro[a : b + 1]), axis=0, ddof=1) for _, a, b in runs], 0)
    moves: list[Move] = []
    biases: list[Array] = []
    notes: list[str] = []
    sigma_pose = float(np.sqrt(2.0) * np.deg2rad(tolerance_deg))
    attitude: dict[PositionKey, Array] = {}
    mean_gyro: dict[PositionKey, Array] = {}
    for turn in rec.turns:
        start, stop = max(turn.start - 1, 0), min(turn.stop + 1, rec.n_rows)
        rows = uniform_rows(rec, start, stop, turn.label, notes)
        if rows is None:
            continue
        moves.append(
            turn_move(rows, 1.0 / fs, turn.axis, np.deg2rad(turn.angle_deg), sigma_pose, turn.label)
        )
        biases.append(static.mean(axis=0))  # imucal's bias: all static samples stacked
    if pose_moves:
        for k, ((la, _, a_end), (lb, b_start, _)) in enumerate(zip(runs, runs[1:], strict=False)):
            ka, kb = keys[k], keys[k + 1]
            if _trial_of(ka) != _trial_of(kb):  # the unit re-mounted between trials: no move
                continue
            label = f"position {la} → {lb}" + _in_trial(ka)
            pair = _pose_move(
                rec, site, s0, (ka, a_end), (kb, b_start), label, notes, g_sensitivity, trim
            )
            if pair is None:
                continue
            moves.append(pair[0])
            biases.append(pair[1])
            for key, row in ((ka, a_end), (kb, b_start)):
                if key in attitude:
                    continue
                tol = np.deg2rad(tolerance_deg)
                if pose_sigmas is not None and key in pose_sigmas:
                    tol = np.asarray(pose_sigmas[key], dtype=float)
                angles = np.deg2rad(_angles_deg(rec, row))
                attitude[key] = attitude_covariance(angles, tol)
                rows_k = np.asarray(rec.gyro[_rows_of(rec, key)], dtype=np.float64)
                mean_gyro[key] = mean_covariance(rows_k)
    shared = Shared(attitude, mean_gyro) if attitude else None
    return RecordingMoves(tuple(moves), tuple(biases), sigma, tuple(notes), shared)


def mean_covariance(rows: Array) -> Array:
    """Covariance (counts²) of the mean of a still position's gyro rows (NaN rows dropped)."""
    finite = rows[np.all(np.isfinite(rows), axis=1)]
    if finite.shape[0] < 2:
        return np.zeros((3, 3))
    return np.asarray(np.cov(finite.T) / finite.shape[0], dtype=np.float64)


def _key(rec: Recording, label: int, row: int) -> PositionKey:
    """Return the key of the position of ``label`` at ``row`` (``(trial, label)`` with trials)."""
    if rec.trial is None:
        return label
    return (max(int(rec.trial[row]), -1), label)


def _trial_of(key: PositionKey) -> int | None:
    """Return the trial of a position's key (None: the recording has no trials)."""
    return key[0] if isinstance(key, tuple) else None


def _in_trial(key: PositionKey) -> str:
    return "" if not isinstance(key, tuple) else f" (trial {key[0]})"


def _rows_of(rec: Recording, key: PositionKey) -> NDArray[np.bool_]:
    """Rows of the position ``key``: its label's, of its own trial when there are trials.

    Each trial is a mounting of its own (its own gyro bias): a move's bias is its trial's.
    """
    if not isinstance(key, tuple):
        return np.asarray(rec.position == key)
    assert rec.trial is not None
    trial, label = key
    return np.asarray((rec.position == label) & (np.maximum(rec.trial, -1) == trial))


def _position_runs(rec: Recording) -> list[tuple[int, int, int]]:
    """``(label, first_row, last_row)`` of each unbroken run of one position label (and trial)."""
    pos = rec.position
    turned = np.diff(pos) != 0
    if rec.trial is not None:
        turned |= np.diff(rec.trial) != 0
    change = np.flatnonzero(turned) + 1
    starts = np.concatenate([[0], change])
    stops = np.concatenate([change, [pos.size]])
    return [
        (int(pos[a]), int(a), int(b) - 1) for a, b in zip(starts, stops, strict=True) if pos[a] >= 0
    ]


def uniform_rows(
    rec: Recording, start: int, stop: int, label: str, notes: list[str], *, accel: bool = False
) -> Array | None:
    """Gyro rows ``start:stop`` on the sample clock, lost samples interpolated (or None).

    Sample positions come from the counter (mod 65536) when the recording has one, else
    from the time column: CAN timestamps of a node run faster than real time are not the
    sample clock, its counter is.
    """
    fs = rec.sample_rate_hz
    counter = rec.counter[start:stop]
    if np.all(np.isfinite(counter)):
        clock = sample_clock(counter)
    else:
        clock = np.round((rec.t[start:stop] - rec.t[start]) * fs)
    data = rec.accel if accel else rec.gyro
    return resample_rows(np.asarray(data[start:stop], dtype=np.float64), clock, fs, label, notes)


def _f64(values: NDArray[np.floating]) -> Array:
    """Return ``values`` as float64 (the reader may keep samples as exact float32) for sums."""
    return np.asarray(values, dtype=np.float64)


def _angles_deg(rec: Recording, row: int) -> Array:
    """Return the angles of row ``row`` (degrees, float64)."""
    return np.array([rec.alpha_deg[row], rec.beta_deg[row], rec.psi_deg[row]], dtype=np.float64)


def sample_clock(counter: Array) -> Array:
    """Sample index of each row from the node's 16-bit counter (wraps at 65536)."""
    steps = np.diff(np.asarray(counter, dtype=float)) % COUNTER_MODULUS
    return np.concatenate([[0.0], np.cumsum(steps)])


def resample_rows(g: Array, clock: Array, fs: float, label: str, notes: list[str]) -> Array | None:
    """Gyro rows on the uniform sample clock, lost samples interpolated (or None, noted).

    ``clock`` is each row's sample index; a row with a NaN gyro counts as lost. Up to
    :data:`MAX_LOST_FRACTION` lost samples are filled linearly; more, or a gap longer than
    :data:`MAX_GAP_S`, drop the move with a note.
    """
    ok = np.all(np.isfinite(g), axis=1) & np.isfinite(clock)
    if ok.sum() < 2:
        notes.append(f"{label}: dropped, no gyro samples")
        return None
    clock, g = clock[ok], g[ok]
    gap = float(np.max(np.diff(clock))) / fs
    if gap > MAX_GAP_S or np.any(np.diff(clock) <= 0):
        notes.append(f"{label}: dropped, a time gap of {gap:.3f} s")
        return None
    n = int(clock[-1] - clock[0]) + 1
    lost = n - clock.size
    if lost > MAX_LOST_FRACTION * n:
        notes.append(f"{label}: dropped, {lost} of {n} samples lost (more than 1 %)")
        return None
    if lost == 0:
        return g
    grid = clock[0] + np.arange(n)
    return np.column_stack([np.interp(grid, clock, g[:, j]) for j in range(3)])


def _pose_move(
    rec: Recording,
    site: SiteConditions,
    s0: Array,
    start: tuple[PositionKey, int],
    end: tuple[PositionKey, int],
    label: str,
    notes: list[str],
    g_sensitivity: GSensitivity | None = None,
    trim: Array | None = None,
) -> tuple[Move, Array] | None:
    (la, a_end), (lb, b_start) = start, end
    pa, pb = np.deg2rad(_angles_deg(rec, a_end)), np.deg2rad(_angles_deg(rec, b_start))
    if not (np.all(np.isfinite(pa)) and np.all(np.isfinite(pb))):
        notes.append(f"{label}: dropped, a position without angles")
        return None
    rows = uniform_rows(rec, a_end, b_start + 1, label, notes)
    if rows is None:
        return None
    mean_a = np.nanmean(_f64(rec.gyro[_rows_of(rec, la)]), axis=0)
    mean_b = np.nanmean(_f64(rec.gyro[_rows_of(rec, lb)]), axis=0)
    force = None
    if g_sensitivity is not None:
        accel = uniform_rows(rec, a_end, b_start + 1, label, [], accel=True)
        if accel is not None and accel.shape == rows.shape:
            force = g_sensitivity.force(accel)
    return move_between(rows, rec.sample_rate_hz, site, s0, (pa, mean_a), (pb, mean_b),
                        0.0, label, g_sensitivity, force, (la, lb), trim)  # fmt: skip


def move_between(
    rows: Array,
    fs: float,
    site: SiteConditions,
    s0: Array,
    start: tuple[Array, Array],
    end: tuple[Array, Array],
    sigma_pose: float,
    label: str,
    g_sensitivity: GSensitivity | None = None,
    force: Array | None = None,
    positions: tuple[PositionKey, PositionKey] | None = None,
    trim: Array | None = None,
) -> tuple[Move, Array]:
    """Build the move from one still position to the next and its bias (counts).

    ``sigma_pose`` is the move's own 1σ per axis (rad), 0 when the positions' errors are
    given as shared (``positions``: their keys, :class:`~canimucal.model.moves.Shared`).

    ``start``/``end``: each position's angles ``(alpha, beta, psi)`` (rad) and mean gyro
    (counts). The bias is the mean of the two means, each less the Earth rate its pose sees
    through the nominal ``s0`` when the latitude is known (module doc). With
    ``g_sensitivity`` and the move's specific force ``force`` (m/s², one row per gyro row),
    each mean also loses ``G f`` of its still pose (``f = C f_L``) and the move carries
    ``force``, so the fit integrates ``S⁻¹ (V − B − G f)`` (eq. 35 with g-sensitivity).
    ``trim``: the unit's mounting trim ``(alpha_m, beta_m, psi_m)`` (rad), so each pose is
    ``R_m C_pose`` (docs/method.md §3, eq. T1) and the move the unit turns is
    ``R_m (C_b C_aᵀ) R_mᵀ``: the gyro's S is fitted in the unit's own axes, as K is, and the
    device's alignment turns both outputs into the vehicle's (without it S would hold the
    trim and the alignment would count it twice).
    """
    (pa, mean_a), (pb, mean_b) = start, end
    ca = position_dcm(pa[0], pa[1], pa[2], trim=trim)
    cb = position_dcm(pb[0], pb[1], pb[2], trim=trim)
    earth = None
    if site.latitude is not None:
        w_level = earth_rate_level(site.latitude, site.heading)
        mean_a = mean_a - s0 @ (ca @ w_level)
        mean_b = mean_b - s0 @ (cb @ w_level)
        earth = ca @ w_level
    move = pose_move(rows, 1.0 / fs, ca, cb, sigma_pose, label, earth, positions)
    if g_sensitivity is not None and force is not None:
        f_level = specific_force_level(site.g)
        mean_a = mean_a - g_sensitivity.G @ (ca @ f_level)
        mean_b = mean_b - g_sensitivity.G @ (cb @ f_level)
        move = dataclasses.replace(move, specific_force=np.asarray(force, dtype=float))
    return move, 0.5 * (mean_a + mean_b)


def fit_recording_moves(
    found: RecordingMoves, site: SiteConditions, G: Array | None = None
) -> MovesFit:
    """Fit S to the moves, each with its own bias (counts); ``G`` held (moves with a force)."""
    if not found.moves:
        raise InputError("gyro moves: the recording has no usable move; " + "; ".join(found.notes))
    shifted = [
        dataclasses.replace(m, gyro=m.gyro - b + found.biases[0])
        for m, b in zip(found.moves, found.biases, strict=True)
    ]
    s0 = np.eye(3) / site.gyro_lsb
    return solve_moves(
        shifted, found.biases[0], s0, found.rate_sigma_counts, G=G, shared=found.shared
    )


def with_moves(solution: Solution, fit: MovesFit, notes: Sequence[str]) -> Solution:
    """Return the solution with gyro S from the moves (unseen columns held, with the reason)."""
    joint = solution.joint
    if joint is None:
        raise InputError("gyro moves need positions with known angles (the joint fit)")
    keep = [
        i
        for i, n in enumerate(joint.names)
        if n not in joint.undetermined and not n.startswith("gyro.S")
    ]
    names = [joint.names[i] for i in keep]
    cov_joint = joint.covariance[np.ix_(keep, keep)]
    s_names = [f"gyro.S[{i}][{j}]" for i in range(3) for j in range(3) if fit.identifiable[j]]
    s_values = [fit.S[i, j] for i in range(3) for j in range(3) if fit.identifiable[j]]
    k = len(names)
    cov = np.zeros((k + len(s_names), k + len(s_names)))
    cov[:k, :k] = cov_joint
    cov[k:, k:] = fit.covariance
    held = {n: r for n, r in joint.undetermined.items() if not n.startswith("gyro.S")}
    for j in np.flatnonzero(~fit.identifiable):
        for i in range(3):
            held[f"gyro.S[{i}][{j}]"] = (
                f"the moves turn {fit.turned_deg[j]:.1f}° about body {AXES[j]}: not identifiable"
            )
    record = re_estimated(
        solution.record, [*names, *s_names], np.concatenate([joint.values[keep], s_values]),
        cov, held,
    )  # fmt: skip
    undetermined = {n: r for n, r in solution.undetermined.items() if not n.startswith("gyro.S")}
    undetermined.update({n: r for n, r in held.items() if n.startswith("gyro.S")})
    warnings = (*solution.warnings, *notes, *fit.notes)
    return dataclasses.replace(
        solution, record=record, undetermined=undetermined, warnings=warnings
    )


def solve_gyro_moves(
    rec: Recording,
    solution: Solution,
    site: SiteConditions,
    *,
    pose_moves: bool = True,
    pose_sigmas: Mapping[PositionKey, float | Sequence[float]] | None = None,
) -> tuple[Solution, MovesFit]:
    """Estimate S from the recording's moves and put it in the solution's record.

    The moves are those of the poses as the unit saw them, with the mounting trim of the
    solution's fit where it has one (the vehicle plan's).
    """
    gs = g_sensitivity_of(solution, site)
    trim = None if solution.joint is None else solution.joint.trim
    found = recording_moves(
        rec, site, pose_moves=pose_moves, pose_sigmas=pose_sigmas, g_sensitivity=gs, trim=trim
    )
    fit = fit_recording_moves(found, site, None if gs is None else gs.G)
    return with_moves(solution, fit, (*found.notes, *g_unused_note(solution, gs))), fit
