"""From a recording to per-position averages: rows grouped by their ``position`` label.

Angles come from the recording (degrees in the file, radians in the :class:`Pose`). A
recording without angles for its positions supports only the scalar ``|f| = g`` methods:
check :func:`has_angles` first, or ask for poses with NaN angles (``require_angles=False``).

``lost`` of a position counts its samples with a PDO half missing: rows with an empty accel
or gyro half (gyro only when the recording has gyro data at all) plus the samples absent
altogether, seen as gaps in the wrapping 16-bit sample counter between consecutive rows.
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Iterator

import numpy as np
from numpy.typing import NDArray

from canimucal.errors import InputError
from canimucal.io.recording import Recording
from canimucal.model.positions import Pose, PositionAverage, average_position
from canimucal.model.static import detect_static_intervals
from canimucal.model.vocabulary.constants import COUNTER_MODULUS

logger = logging.getLogger(__name__)


def position_labels(recording: Recording) -> list[int]:
    """Return the distinct position labels of ``recording``, ascending (empty rows skipped)."""
    labels = np.unique(recording.position[recording.position >= 0])
    return [int(x) for x in labels.tolist()]


def label_rows(position: NDArray[np.int64]) -> dict[int, NDArray[np.intp]]:
    """Row indices of every label ``>= 0``, ascending labels, rows in file order.

    Found from the runs of equal labels (:func:`label_runs`); never a sort or a scan of
    every row per position (issue 23).
    """
    return {
        label: np.concatenate([np.arange(a, b, dtype=np.intp) for a, b in spans])
        for label, spans in label_runs(position).items()
    }


def label_runs(position: NDArray[np.int64]) -> dict[int, list[tuple[int, int]]]:
    """Return the runs ``[start, stop)`` of every label ``>= 0`` in file order, ascending labels.

    One comparison of each row with the next (a session's labels come in runs).
    """
    n = position.shape[0]
    if n == 0:
        return {}
    change = np.flatnonzero(position[1:] != position[:-1]) + 1
    starts = np.concatenate([[0], change])
    stops = np.concatenate([change, [n]])
    labels = position[starts]
    keep = labels >= 0
    runs: dict[int, list[tuple[int, int]]] = {}
    for label, a, b in zip(
        labels[keep].tolist(), starts[keep].tolist(), stops[keep].tolist(), strict=True
    ):
        runs.setdefault(int(label), []).append((a, b))
    return {label: runs[label] for label in sorted(runs)}


def position_rows(recording: Recording) -> tuple[list[NDArray[np.intp]], bool]:
    """Row indices of each position and whether they come from labels.

    The one place that decides: the recording's position labels when it has any, else the
    static intervals :func:`~canimucal.model.static.detect_static_intervals` finds (quiet on
    the accelerometer, and on the gyro when the recording has gyro data).
    """
    by_label = label_rows(recording.position)
    if by_label:
        return list(by_label.values()), True
    if np.all(np.isfinite(recording.accel), axis=1).sum() < 3:
        raise InputError(f"{recording.source or 'recording'}: no accelerometer samples")
    gyro = recording.gyro if np.isfinite(recording.gyro).any() else None
    found = detect_static_intervals(recording.accel, recording.sample_rate_hz, gyro=gyro)
    logger.info("no position labels: %d static intervals detected", len(found))
    return [np.arange(s.start, s.stop) for s in found], False


Rows = slice | NDArray[np.intp]
"""The rows of one position: a slice when they are one run (views of the columns, no index
array), else their indices, increasing."""


def position_parts(recording: Recording) -> tuple[list[Rows], bool]:
    """As :func:`position_rows`, each position a slice when its rows are one run.

    A session's positions are one run each: a long recording's grouping then holds no index
    array of its rows (76 MiB at 10⁷ rows) and its windows are views (issue 23).
    """
    runs = label_runs(recording.position)
    if not runs:
        found, _ = position_rows(recording)  # static intervals: each one run
        return [slice(int(r[0]), int(r[-1]) + 1) if r.size else r for r in found], False
    parts: list[Rows] = []
    for spans in runs.values():
        if len(spans) == 1:
            parts.append(slice(*spans[0]))
        else:
            parts.append(np.concatenate([np.arange(a, b, dtype=np.intp) for a, b in spans]))
    return parts, True


MIN_SPLIT_ROWS = 20
"""A still interval cut by a trial boundary keeps only pieces of at least this many rows (a
mean of a few rows, with a covariance from as few, would weigh as a position)."""


def interval_trials(recording: Recording, parts: list[Rows]) -> list[tuple[int | None, Rows]]:
    """Each unlabelled position's rows with its trial (the ``trial`` column), in order.

    A still interval the detector found across a trial boundary is split there (a unit
    re-mounted between trials is a new position); a piece of it shorter than
    :data:`MIN_SPLIT_ROWS` is dropped. With fewer than two trials among the rows every part
    keeps trial None, as a file without the column.
    """
    if recording.trial is None:
        return [(None, rows) for rows in parts]
    keyed = np.where(recording.trial < 0, -1, recording.trial)
    out: list[tuple[int | None, Rows]] = []
    for rows in parts:
        index = np.arange(rows.start, rows.stop) if isinstance(rows, slice) else rows
        values = keyed[index]
        _, first = np.unique(values, return_index=True)
        pieces = values[np.sort(first)].tolist()
        for trial in pieces:
            mine = values == trial
            if len(pieces) == 1 or int(np.count_nonzero(mine)) >= MIN_SPLIT_ROWS:
                out.append((int(trial), rows_where(rows, mine)))
    if len({trial for trial, _ in out}) < 2:
        return [(None, rows) for rows in parts]
    return out


def rows_count(rows: Rows) -> int:
    """Return the number of rows in ``rows``."""
    if isinstance(rows, slice):
        return int(rows.stop - rows.start)
    return int(rows.size)


def rows_where(rows: Rows, mask: NDArray[np.bool_]) -> Rows:
    """Return the rows of ``rows`` where ``mask`` (one entry a row) holds, a slice if one run."""
    if isinstance(rows, slice):
        if bool(mask.all()):
            return rows
        picked = np.flatnonzero(mask) + rows.start
    else:
        picked = rows[mask]
    if picked.size and int(picked[-1]) - int(picked[0]) + 1 == picked.size:
        return slice(int(picked[0]), int(picked[-1]) + 1)
    return picked


def average_rows(recording: Recording, rows: Rows) -> PositionAverage:
    """Average ``rows`` as one position of unknown orientation (NaN angles: scalar fit only)."""
    gyro = recording.gyro[rows] if np.isfinite(recording.gyro).any() else None
    return average_position(
        Pose(np.nan, np.nan, np.nan), recording.accel[rows], gyro, recording.sample_rate_hz
    )


def has_angles(recording: Recording) -> bool:
    """Tell whether there are labelled positions and every one carries its angles."""
    labelled = recording.position >= 0
    if not labelled.any():
        return False
    columns = (recording.alpha_deg, recording.beta_deg, recording.psi_deg)
    return not any(np.any(labelled & ~np.isfinite(angle)) for angle in columns)


def position_averages(
    recording: Recording, *, tolerance_deg: float = 0.1, require_angles: bool = True
) -> list[PositionAverage]:
    """One :class:`PositionAverage` per position label, in ascending label order.

    With trials (the recording's ``trial`` column, docs/design.md §5) one per trial and
    label, ascending trials then labels, each carrying its ``trial`` (rows of an empty trial
    cell form a trial of their own, ``-1``). ``tolerance_deg`` becomes each pose's 1σ
    angle-setting error. A labelled position without
    angles raises :class:`InputError` unless ``require_angles`` is false, in which case its
    pose has NaN angles (for the scalar methods only).
    """
    if not np.isfinite(tolerance_deg) or tolerance_deg < 0:
        raise InputError(f"tolerance_deg must be a finite number >= 0, got {tolerance_deg}")
    by_label = label_runs(recording.position)
    if not by_label:
        raise InputError(f"{recording.source or 'recording'}: no labelled position")
    tolerance_rad = float(np.deg2rad(tolerance_deg))
    with_gyro = bool(np.isfinite(recording.gyro).any())
    if recording.trial is None:
        return [
            _average_one(
                recording, label, _rows_of(spans), tolerance_rad, require_angles, with_gyro
            )
            for label, spans in by_label.items()
        ]
    out = []
    for trial, label, rows in trial_label_rows(recording.position, recording.trial):
        average = _average_one(recording, label, rows, tolerance_rad, require_angles, with_gyro)
        out.append(dataclasses.replace(average, trial=trial))
    return out


def trial_label_rows(
    position: NDArray[np.int64], trial: NDArray[np.int64]
) -> list[tuple[int, int, NDArray[np.intp]]]:
    """``(trial, label, rows)`` of every labelled position of every trial, ascending.

    A row whose trial cell is empty (< 0) belongs to trial -1; rows in file order.
    """
    keyed = np.where(trial < 0, -1, trial)
    out = []
    for t in np.unique(keyed[position >= 0]).tolist():
        mine = np.flatnonzero(keyed == t)
        for label, rows in label_rows(position[mine]).items():
            out.append((int(t), label, mine[rows]))
    return out


def _rows_of(spans: list[tuple[int, int]]) -> NDArray[np.intp] | slice:
    """Return a label's rows: a slice for one run (views, no index array), else indices."""
    if len(spans) == 1:
        return slice(*spans[0])
    return np.concatenate([np.arange(a, b, dtype=np.intp) for a, b in spans])


def _average_one(
    recording: Recording,
    label: int,
    take: NDArray[np.intp] | slice,
    tolerance_rad: float,
    require_angles: bool,
    with_gyro: bool,
) -> PositionAverage:
    first = take.start if isinstance(take, slice) else int(take[0])
    angles_deg = [
        float(recording.alpha_deg[first]),
        float(recording.beta_deg[first]),
        float(recording.psi_deg[first]),
    ]
    if not np.all(np.isfinite(angles_deg)) and require_angles:
        raise InputError(
            f"{recording.source or 'recording'}: position {label} has no angles "
            "(only scalar |f| = g methods apply)"
        )
    alpha, beta, psi = (float(x) for x in np.deg2rad(angles_deg))
    temps = np.asarray(recording.temp_c[take], dtype=np.float64)
    finite_temps = temps[np.isfinite(temps)]
    temp_c = float(np.mean(finite_temps)) if finite_temps.size else None
    try:
        return average_position(
            Pose(alpha, beta, psi, tolerance_rad),
            recording.accel[take],
            recording.gyro[take] if with_gyro else None,
            sample_rate_hz=recording.sample_rate_hz,
            temp_c=temp_c,
            lost=lost_samples(recording, take, with_gyro),
        )
    except ValueError as exc:
        raise InputError(f"{recording.source or 'recording'}: position {label}: {exc}") from exc


def lost_samples(
    recording: Recording, rows: NDArray[np.intp] | slice, with_gyro: bool | None = None
) -> int:
    """Count samples of ``rows`` (one position) with a PDO half missing, counter gaps included.

    ``rows`` are indices, or a slice (one run of rows); ``with_gyro``: whether the recording
    has gyro data (looked up when None).
    """
    half_missing = np.isnan(recording.accel[rows, 0])
    if with_gyro is None:
        with_gyro = bool(np.isfinite(recording.gyro).any())
    if with_gyro:
        half_missing |= np.isnan(recording.gyro[rows, 0])
    return int(half_missing.sum()) + _counter_gaps(recording.counter[rows], rows)


def _counter_gaps(counter: NDArray[np.float64], rows: NDArray[np.intp] | slice) -> int:
    """Count samples skipped between consecutive rows of one run (the counter wraps).

    A run ends where rows of another label (motion, another position) come in between: the
    samples there are not lost. A row with an empty counter is a sample present, not a gap.
    ``rows`` as a slice is a single run.
    """
    finite = np.isfinite(counter)
    if bool(finite.all()):  # every counter known: no row skipped between two known ones
        if counter.size < 2:
            return 0
        step = np.mod(np.diff(counter), COUNTER_MODULUS)
        if isinstance(rows, slice):
            return int(np.maximum(step - 1, 0).sum(dtype=np.float64))  # whole counts: exact
        same_run = np.diff(rows) == 1
        return int(np.where(same_run, np.maximum(step - 1, 0), 0).sum(dtype=np.float64))
    if isinstance(rows, slice):
        rows = np.arange(rows.start, rows.stop, dtype=np.intp)
    run = np.concatenate([[0], np.cumsum(np.diff(rows) > 1)])
    known = np.flatnonzero(finite)
    if known.size < 2:
        return 0
    step = np.mod(np.diff(counter[known]), COUNTER_MODULUS)
    skipped = np.diff(known) - 1  # rows present between them whose counter is empty
    same_run = np.diff(run[known]) == 0
    gaps = np.where(same_run, np.maximum(step - 1 - skipped, 0), 0)
    return int(gaps.sum())


TRIAL_GAP_S = 60.0
"""A step in ``t`` longer than this (and 100 sample periods) splits an unlabelled file into
trials, when every piece holds at least two labelled positions."""


def detect_trials(recording: Recording) -> tuple[Recording, str | None]:
    """Give a recording without a ``trial`` column its trials, when the file shows them.

    Two signs, either enough: the label sequence runs again (a new trial starts where a label
    comes back that the current trial has had already, and every trial runs the first one's
    labels in its order, the last one possibly cut short), or long pauses in ``t``
    (:data:`TRIAL_GAP_S`). Found only when there are at least two trials of two labelled
    positions each; then the recording comes back with its ``trial`` column and a one-line
    note saying why. Labels that recur otherwise (a position redone later) leave the
    recording as it is, with a note that they were averaged together. A file with the column,
    or showing neither sign, comes back as it is, with no note.
    """
    if recording.trial is not None:
        return recording, None
    labels, firsts, n_labelled = _labelled_runs(recording.position)
    if n_labelled < 4:
        return recording, None
    repeats, chunks = _label_chunks(labels)
    repeated = len(chunks) > 1 and all(
        len(c) >= 2
        and c == chunks[0][: len(c)]
        and (len(c) == len(chunks[0]) or k == len(chunks) - 1)
        for k, c in enumerate(chunks)
    )
    starts = {firsts[k] for k in repeats} if repeated else set()
    gap_starts = _pauses(recording.t)
    edges = sorted(starts | gap_starts)
    found = _trials_of(recording, edges)
    if found is None:
        if repeats:
            first = labels[repeats[0]]
            return recording, (
                f"position {first} recurs in time order, not as a repeated plan: its rows are "
                "averaged as one position (a trial column tells trials apart)"
            )
        return recording, None
    why = []
    if starts:
        why.append("the position labels recur in time order")
    if gap_starts - starts:
        why.append(f"t pauses over {TRIAL_GAP_S:g} s")
    note = (
        f"no trial column, but {' and '.join(why)}: treated as {int(found.max()) + 1} trials "
        "(one bias each, K shared; a trial column says so explicitly)"
    )
    return dataclasses.replace(recording, trial=found), note


def _labelled_runs(position: NDArray[np.int64]) -> tuple[list[int], list[int], int]:
    """Return the runs of the labelled rows' labels, rows without a label left out.

    Each run's label and first row (file order), and the number of labelled rows; two runs
    of one label with only unlabelled rows between are one run. From the label changes
    (:func:`label_runs`' comparison), never an index array of the labelled rows (issue 23).
    """
    n = position.shape[0]
    if n == 0:
        return [], [], 0
    change = np.flatnonzero(position[1:] != position[:-1]) + 1
    starts = np.concatenate([[0], change])
    stops = np.concatenate([change, [n]])
    run_labels = position[starts]
    keep = run_labels >= 0
    labels: list[int] = []
    firsts: list[int] = []
    for label, first in zip(run_labels[keep].tolist(), starts[keep].tolist(), strict=True):
        if not labels or labels[-1] != label:
            labels.append(int(label))
            firsts.append(int(first))
    return labels, firsts, int(np.sum(stops[keep] - starts[keep]))


def _label_chunks(labels: list[int]) -> tuple[list[int], list[list[int]]]:
    """Split the labels' run sequence where a label comes back.

    ``labels`` one a run (:func:`_labelled_runs`). Returns the split points (indices into
    ``labels``) and each chunk's labels in order.
    """
    splits: list[int] = []
    chunks: list[list[int]] = [[]]
    for k, label in enumerate(labels):
        if label in chunks[-1]:
            splits.append(k)
            chunks.append([])
        chunks[-1].append(label)
    return splits, chunks


PAUSE_CHUNK_ROWS = 1 << 20
"""Steps of ``t`` the pause search reads at once (no temporaries the size of the file)."""


def _pauses(t: NDArray[np.float64]) -> set[int]:
    """Rows after a step in ``t`` over :data:`TRIAL_GAP_S` and 100 typical steps.

    The typical step is the median of the finite positive steps. It moves the threshold only
    when 100 of it exceed :data:`TRIAL_GAP_S`; a first pass in chunks counts the steps that
    cannot (``100·dt ≤ TRIAL_GAP_S``): when more than half do, the median cannot either and
    the threshold is :data:`TRIAL_GAP_S`, with no array of the steps built (issue 23).
    Otherwise (steps of 0.6 s and more: short files) the median is taken as before.
    """
    if t.size < 2:
        return set()
    positive = short = 0
    for dt in _steps(t):
        ok = np.isfinite(dt) & (dt > 0)
        positive += int(np.count_nonzero(ok))
        short += int(np.count_nonzero(ok & (100.0 * dt <= TRIAL_GAP_S)))
    if positive == 0 or short >= positive // 2 + 1:
        threshold = TRIAL_GAP_S
    else:
        steps = np.diff(t)
        typical = float(np.median(steps[np.isfinite(steps) & (steps > 0)]))
        threshold = max(TRIAL_GAP_S, 100.0 * typical)
    found: set[int] = set()
    for start, dt in zip(range(0, t.size - 1, PAUSE_CHUNK_ROWS), _steps(t), strict=True):
        found.update((np.flatnonzero(dt > threshold) + start + 1).tolist())
    return found


def _steps(t: NDArray[np.float64]) -> Iterator[NDArray[np.float64]]:
    """Yield ``np.diff(t)`` in chunks of :data:`PAUSE_CHUNK_ROWS` steps, in order."""
    for start in range(0, t.size - 1, PAUSE_CHUNK_ROWS):
        yield np.diff(t[start : start + PAUSE_CHUNK_ROWS + 1])


def _trials_of(recording: Recording, edges: list[int]) -> NDArray[np.int64] | None:
    """Return the trial of every row split at ``edges``.

    None unless two or more pieces each hold two labelled positions or more.
    """
    if not edges:
        return None
    labelled = np.flatnonzero(recording.position >= 0)
    trial = np.searchsorted(np.array(edges), np.arange(recording.n_rows), side="right")
    pieces = [
        np.unique(recording.position[labelled][trial[labelled] == t]) for t in range(len(edges) + 1)
    ]
    if any(p.size < 2 for p in pieces):
        return None
    return trial.astype(np.int64)
