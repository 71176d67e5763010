"""The recording CSV (docs/design.md §5): the parsed :class:`Recording` and its strict fast reader.

Layout: ``# key: value`` header lines (``schema: canimucal.recording/1`` required), the exact
column line ``t,counter,position,alpha_deg,beta_deg,psi_deg,ax,ay,az,gx,gy,gz,temp_c``, then
one row per sample. Empty cells mean "unknown": ``counter``/angles/``temp_c`` read as NaN,
``position`` as -1, a lost PDO half as three NaN columns.

Reading streams the file (issue 23): the header line by line, then the rows in blocks of
about :data:`CHUNK_BYTES`, each parsed with numpy and checked (row checks, ``t`` and the
angles of a position across blocks too) before its numbers go straight into typed columns
(float64 ``t``, int64 ``position``, the others float32 while their values fit it exactly, see
:class:`_Columns`); neither the whole text nor a whole ``(n, 13)`` table ever exists.
Recording arrays may therefore be float32: code summing samples converts to float64 first.
When a block fails to parse, a slow line-by-line pass over that block finds the first bad
line, so the error names file, line and problem. A file with several problems reports the
first block's first one. The streaming and
whole-file writers live in :mod:`canimucal.io.recording_writer`.
"""

from __future__ import annotations

import io
import logging
import math
import os
import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np
from numpy.typing import ArrayLike, NDArray

from canimucal.errors import InputError
from canimucal.io.decimal_fields import decimal_table
from canimucal.model.vocabulary.constants import OUTPUT_DATA_RATES_HZ

__all__ = [
    "COLUMNS",
    "COLUMN_LINE",
    "SCHEMA",
    "TRIAL_COLUMN_LINE",
    "HeaderValue",
    "KnownTurn",
    "Recording",
    "read_recording_csv",
    "recording_from_columns",
]

logger = logging.getLogger(__name__)


# ------------------------------------------------------------------------------- recording


@dataclass(frozen=True)
class KnownTurn:
    """A turn of known angle about a known body axis, rows ``start`` to ``stop`` (exclusive).

    The unit is still at both ends and the start and end attitudes are the same (imucal's
    ``*_rot`` sections: a full turn). ``axis`` is 0, 1, 2 for body x, y, z; ``angle_deg``
    is signed, right hand about the axis.
    """

    label: str
    start: int
    stop: int
    axis: int
    angle_deg: float


@dataclass(frozen=True, eq=False)
class Recording:
    """A parsed recording: typed header and one numpy array per column (see module doc).

    ``accel``/``gyro`` are ``(n, 3)`` counts; ``position`` is int with -1 for "no position".
    Read from a file, the columns but ``t`` and ``position`` are float32 when every value
    fits it exactly (module doc): convert to float64 before summing many samples.
    ``sample_rate_inferred`` is true when the header had no ``sample_rate_hz`` and the
    value in ``header`` is the median sample interval's inverse. ``turns`` are the known
    turns an importer found (gyro moves beside the labelled positions).
    """

    header: dict[str, HeaderValue]
    t: FloatArray
    counter: FloatArray
    position: NDArray[np.int64]
    alpha_deg: FloatArray
    beta_deg: FloatArray
    psi_deg: FloatArray
    accel: FloatArray
    gyro: FloatArray
    temp_c: FloatArray
    sample_rate_inferred: bool = False
    source: str = field(default="", compare=False)
    turns: tuple[KnownTurn, ...] = field(default=(), compare=False)
    duplicate_counters: int = field(default=0, compare=False)
    """Rows whose counter repeats one of the :data:`REPEAT_WINDOW_ROWS` rows before (a frame
    received twice, a block pasted again, two logs merged), adjacent or not."""
    duplicate_rows: int = field(default=0, compare=False)
    """Rows equal in every column but ``t`` to an earlier row with the same counter within
    :data:`REPEAT_WINDOW_ROWS` rows (the same sample written again: a copy-paste, a doubled
    log), adjacent or not; without a counter, rows equal to the row before in every column."""
    trial: NDArray[np.int64] | None = field(default=None, compare=False)
    """The optional ``trial`` column (docs/design.md §5): which mounting of the unit each row
    belongs to, -1 where empty; ``None`` when the file has no such column."""

    @property
    def n_rows(self) -> int:
        """Number of sample rows."""
        return int(self.t.shape[0])

    def take_rows(self, keep: NDArray[np.intp]) -> Recording:
        """Return the rows ``keep`` (increasing indices) of every per-row column, read-only.

        Known turns are re-indexed to the rows kept; the header and the counts of repeated
        rows are those of the whole recording.
        """

        def take(values: NDArray[Any]) -> NDArray[Any]:
            out = np.ascontiguousarray(values[keep])
            out.setflags(write=False)
            return out

        turns = tuple(
            replace(
                turn,
                start=int(np.searchsorted(keep, turn.start)),
                stop=int(np.searchsorted(keep, turn.stop)),
            )
            for turn in self.turns
        )
        rows: dict[str, Any] = {name: take(getattr(self, name)) for name in COLUMN_KEYS}
        trial = None if self.trial is None else take(self.trial)
        return replace(self, **rows, trial=trial, turns=turns)

    @property
    def sample_rate_hz(self) -> float:
        """The header's sample rate (Hz); InputError when the header has none."""
        rate = self.header.get("sample_rate_hz")
        if not isinstance(rate, float):
            raise InputError(f"{self.source or 'recording'}: no sample_rate_hz")
        return rate


def recording_from_columns(
    header: Mapping[str, HeaderValue],
    *,
    t: ArrayLike,
    accel: ArrayLike | None = None,
    gyro: ArrayLike | None = None,
    counter: ArrayLike | None = None,
    position: ArrayLike | None = None,
    alpha_deg: ArrayLike | None = None,
    beta_deg: ArrayLike | None = None,
    psi_deg: ArrayLike | None = None,
    temp_c: ArrayLike | None = None,
    trial: ArrayLike | None = None,
) -> Recording:
    """Build a :class:`Recording` from column arrays; ``None`` means an empty column.

    ``trial`` (one integer per row, < 0 for empty) gives the recording a ``trial`` column;
    ``None`` leaves it without one.
    """
    table = block_table(t, accel, gyro, counter, position, alpha_deg, beta_deg, psi_deg, temp_c)
    trials = None
    if trial is not None:
        trials = trial_column(np.asarray(trial, dtype=float), table.shape[0], "trial")
    return _recording_from_table(
        normalise_header(header), table, first_line=1, source="", trial=trials
    )


def trial_column(values: NDArray[np.float64], n: int, source: str) -> NDArray[np.int64]:
    """Check ``trial`` values (non-negative integers, NaN or < 0 empty) and type them."""
    values = values.reshape(-1)
    if values.shape != (n,):
        raise InputError(f"column trial has shape {values.shape}, expected ({n},)")
    empty = np.isnan(values) | (values < 0)
    bad = ~empty & ((values != np.floor(values)) | ~np.isfinite(values))
    if bad.any():
        raise InputError(f"{source}: trial {values[np.argmax(bad)]!r} is not an integer")
    return np.where(empty, -1, np.nan_to_num(values)).astype(np.int64)


def block_table(
    t: ArrayLike,
    accel: ArrayLike | None,
    gyro: ArrayLike | None,
    counter: ArrayLike | None,
    position: ArrayLike | None,
    alpha_deg: ArrayLike | None,
    beta_deg: ArrayLike | None,
    psi_deg: ArrayLike | None,
    temp_c: ArrayLike | None,
) -> FloatArray:
    """Stack column arrays into the ``(n, 13)`` float table of the file (NaN = empty)."""
    t_arr = np.asarray(t, dtype=float).reshape(-1)
    n = t_arr.shape[0]

    def column(values: ArrayLike | None, width: int, name: str) -> FloatArray:
        if values is None:
            return np.full((n, width), np.nan)
        arr = np.asarray(values, dtype=float)
        if name == "position":
            arr = np.where(arr < 0, np.nan, arr)
        shape = (n, width) if width > 1 else (n,)
        if arr.shape != shape:
            raise InputError(f"column {name} has shape {arr.shape}, expected {shape}")
        return arr.reshape(n, width)

    parts = [t_arr.reshape(n, 1), column(counter, 1, "counter"), column(position, 1, "position")]
    parts += [column(a, 1, name) for a, name in ((alpha_deg, "alpha_deg"), (beta_deg, "beta_deg"))]
    parts += [column(psi_deg, 1, "psi_deg"), column(accel, 3, "accel"), column(gyro, 3, "gyro")]
    parts.append(column(temp_c, 1, "temp_c"))
    return np.hstack(parts)


def _recording_from_table(
    header: dict[str, HeaderValue],
    table: FloatArray,
    *,
    first_line: int,
    source: str,
    trial: NDArray[np.int64] | None = None,
) -> Recording:
    check_table(table, first_line, source)
    columns = _Columns(table.shape[0], with_trial=trial is not None)
    columns.append(table, trial)
    return _recording_from_parts(header, columns, source)


class _Columns:
    """Typed columns filled block by block (capacity grows by half when a block overflows).

    ``t`` is float64 and ``position`` int64; every other column starts as float32 and stays
    so while each value read fits it exactly (sample counts, the 16-bit counter, whole or
    binary-fraction angles and temperatures: 4 bytes a cell instead of 8), and becomes
    float64 from the first block with a value that does not (:data:`COMPACT_COLUMNS`).
    Either way every value reads back exactly as the file wrote it.
    """

    def __init__(self, capacity: int, *, with_trial: bool = False) -> None:
        self.n = 0
        self.with_trial = with_trial
        self._capacity = capacity
        self._data: dict[str, NDArray[Any]] = {
            "t": np.empty(capacity, dtype=np.float64),
            "position": np.empty(capacity, dtype=np.int64),
        }
        for name, width in COMPACT_COLUMNS.items():
            shape = (capacity, width) if width > 1 else (capacity,)
            self._data[name] = np.empty(shape, dtype=np.float32)
        if with_trial:
            self._data["trial"] = np.empty(capacity, dtype=np.int64)

    def append(self, table: FloatArray, trial: NDArray[np.int64] | None = None) -> None:
        k = table.shape[0]
        if self.n + k > self._capacity:
            self._grow(max(self.n + k, int(self._capacity * 1.5) + 1024))
        rows = slice(self.n, self.n + k)
        data = self._data
        if self.with_trial:
            assert trial is not None and trial.shape == (k,)
            data["trial"][rows] = trial
        data["t"][rows] = table[:, 0]
        label = table[:, 2]
        data["position"][rows] = np.where(np.isnan(label), -1, label)
        narrow = [name for name in _TABLE_COLUMNS if data[name].dtype == np.float32]
        if narrow:
            fits = _fits_float32(table)
            for name in narrow:
                if not fits[_TABLE_COLUMNS[name]].all():
                    self._widen(name)
        for name, cols in _TABLE_COLUMNS.items():
            data[name][rows] = table[:, cols]
        self.n += k

    def _widen(self, name: str) -> None:
        """Make column ``name`` float64 (its filled rows converted exactly)."""
        old = self._data[name]
        new = np.empty(old.shape, dtype=np.float64)
        new[: self.n] = old[: self.n]
        self._data[name] = new

    def _grow(self, capacity: int) -> None:
        for name, old in self._data.items():
            new = np.empty((capacity, *old.shape[1:]), dtype=old.dtype)
            new[: self.n] = old[: self.n]
            self._data[name] = new
        self._capacity = capacity

    def arrays(self) -> dict[str, NDArray[np.float64] | NDArray[np.int64]]:
        """Return the filled rows, read-only (views: no column is copied)."""
        n = self.n
        out: dict[str, NDArray[Any]] = {name: arr[:n] for name, arr in self._data.items()}
        for arr in out.values():
            arr.setflags(write=False)
        return out


COMPACT_COLUMNS: dict[str, int] = {
    "counter": 1,
    "alpha_deg": 1,
    "beta_deg": 1,
    "psi_deg": 1,
    "accel": 3,
    "gyro": 3,
    "temp_c": 1,
}
"""The columns kept as float32 while their values fit it exactly, and their widths."""

_TABLE_COLUMNS: dict[str, int | slice] = {
    "counter": 1,
    "alpha_deg": 3,
    "beta_deg": 4,
    "psi_deg": 5,
    "accel": slice(6, 9),
    "gyro": slice(9, 12),
    "temp_c": 12,
}


def _fits_float32(table: FloatArray) -> NDArray[np.bool_]:
    """Whether each column's values are all NaN or exactly a float32 (one pass over the block).

    A value that does not fit differs from its float32 rounding (finite: the table checks
    refused inf); NaN differs from itself and is skipped.
    """
    with np.errstate(over="ignore"):
        narrow = table.astype(np.float32)
    return np.asarray(~((narrow != table) & ~np.isnan(table)).any(axis=0))


def _recording_from_parts(
    header: dict[str, HeaderValue], columns: _Columns, source: str
) -> Recording:
    """Finish a checked recording: whole-file checks, the rate, the repeats; build it."""
    parts = columns.arrays()
    t = parts["t"]
    check_time_advances(t, source)  # type: ignore[arg-type]
    inferred = False
    if "sample_rate_hz" not in header:
        header["sample_rate_hz"] = _infer_rate(t, source)  # type: ignore[arg-type]
        inferred = True
        logger.info("%s: sample_rate_hz inferred from t: %g", source, header["sample_rate_hz"])
    dup_counters, dup_rows = count_duplicates_columns(
        t,  # type: ignore[arg-type]
        parts["counter"],  # type: ignore[arg-type]
        [parts[k] for k in (*COLUMN_KEYS[2:], *(["trial"] if "trial" in parts else []))],
    )
    if dup_counters or dup_rows:
        logger.warning(
            "%s: %d rows repeat an earlier row's counter, %d rows are exact copies of an "
            "earlier row (kept; check how the file was made)",
            source or "recording",
            dup_counters,
            dup_rows,
        )
    return Recording(
        header,
        **parts,  # type: ignore[arg-type]
        sample_rate_inferred=inferred,
        source=source,
        duplicate_counters=dup_counters,
        duplicate_rows=dup_rows,
    )


COLUMN_KEYS: tuple[str, ...] = ("t", "counter", "position", "alpha_deg", "beta_deg", "psi_deg")
COLUMN_KEYS += ("accel", "gyro", "temp_c")
"""The :class:`Recording` fields of the file's columns, in file order."""


REPEAT_WINDOW_ROWS = 32_768
"""How far back a repeated counter is looked for: half the 16-bit counter's range, so a
counter that wrapped (65,536 samples later) is never taken for a repeat unless more samples
were lost than received in between. A node rebooting within this many rows of the file's
start restarts its counter and its first rows are counted too (a warning only)."""


def count_duplicates(table: FloatArray) -> tuple[int, int]:
    """:func:`count_duplicates_columns` of an ``(n, 13)`` table."""
    return count_duplicates_columns(table[:, 0], table[:, 1], [table[:, 2:]])


def count_duplicates_columns(
    t: FloatArray, counter: FloatArray, others: list[NDArray[np.float64] | NDArray[np.int64]]
) -> tuple[int, int]:
    """Count rows repeating an earlier row's counter, and rows equal to that earlier row.

    ``others`` are the columns compared besides the counter (every one but ``t``), arrays of
    ``n`` rows (1-D or 2-D); compared on the rows concerned only, no full-table temporary.

    A row counts when its counter equals that of one of the :data:`REPEAT_WINDOW_ROWS` rows
    before it, adjacent or not; it is also a copy when every column but ``t`` (the file's
    times never go back, so a sample written again later has a later ``t``) equals the
    nearest such row's (empty cells equal empty cells). Rows with an empty counter are
    compared with the row before only, in every column. Vectorised (a stable sort by
    counter), and done :data:`DUPLICATE_CHUNK_ROWS` rows at a time, each with the window
    before it, so ten million rows cost seconds and no temporary grows with the file.
    """
    n = counter.shape[0]
    if n < 2:
        return 0, 0
    repeats = copies = 0
    for start in range(0, n, DUPLICATE_CHUNK_ROWS):
        stop = min(n, start + DUPLICATE_CHUNK_ROWS)
        r, c = _duplicates_in(t, counter, others, start, stop)
        repeats += r
        copies += c
    return repeats, copies


DUPLICATE_CHUNK_ROWS = 1 << 20
"""Rows whose repeats :func:`count_duplicates_columns` looks for at a time."""


def _duplicates_in(
    t: FloatArray,
    counter: FloatArray,
    others: list[NDArray[np.float64] | NDArray[np.int64]],
    start: int,
    stop: int,
) -> tuple[int, int]:
    """:func:`count_duplicates_columns` for the rows ``start:stop`` (the window before read).

    The nearest earlier row with the same counter within the window is found among rows
    ``start - REPEAT_WINDOW_ROWS`` on, so the count is that of the whole file's sort.
    """
    low = max(0, start - REPEAT_WINDOW_ROWS)
    finite = np.flatnonzero(np.isfinite(counter[low:stop])) + low
    order = finite[np.argsort(counter[finite], kind="stable")]  # same counters: by row
    later, earlier = order[1:], order[:-1]
    same = (counter[later] == counter[earlier]) & (later - earlier <= REPEAT_WINDOW_ROWS)
    same &= later >= start
    later, earlier = later[same], earlier[same]
    copies = int(np.count_nonzero(_rows_equal(others, later, earlier)))
    first = max(start, 1)
    empty = np.flatnonzero(~np.isfinite(counter[first:stop])) + first  # the row before only
    same_counter = np.isnan(counter[empty]) & np.isnan(counter[empty - 1])
    same_t = t[empty] == t[empty - 1]
    copies += int(np.count_nonzero(_rows_equal(others, empty, empty - 1) & same_counter & same_t))
    return int(later.size), copies


def _rows_equal(
    columns: list[NDArray[np.float64] | NDArray[np.int64]],
    a_rows: NDArray[np.intp],
    b_rows: NDArray[np.intp],
) -> NDArray[np.bool_]:
    """Whether rows ``a_rows`` equal rows ``b_rows`` in every column (empty equals empty)."""
    equal = np.ones(a_rows.size, dtype=bool)
    if a_rows.size == 0:
        return equal
    for column in columns:
        a, b = column[a_rows], column[b_rows]
        same = (a == b) | (np.isnan(a) & np.isnan(b)) if a.dtype.kind == "f" else a == b
        equal &= same.reshape(a_rows.size, -1).all(axis=1)
    return equal


def check_time_advances(t: FloatArray, source: str) -> None:
    """Refuse a time column that stands still for most rows (InputError, exit 2).

    Every analysis takes the sample interval from the median step of ``t``; a constant
    column, or a file whose rows were each written twice, makes it zero. Said here, once,
    in words, rather than as a division by zero wherever ``t`` is used. With ``t``
    non-decreasing (every caller checked it) the median step is zero exactly when more than half
    of the steps are (the larger middle one for an even count), so the zero steps are
    counted block by block instead of sorting every step.
    """
    steps = t.shape[0] - 1
    if steps <= 0:
        return
    block = DUPLICATE_CHUNK_ROWS
    still = sum(
        int(np.count_nonzero(t[i + 1 : i + block + 1] == t[i : min(i + block, steps)]))
        for i in range(0, steps, block)
    )
    if still <= steps // 2:
        return
    raise InputError(
        f"{source or 'recording'}: t does not advance ({still} of {steps} steps are 0: "
        "a constant time column, or rows written twice); fix t or remove the repeated rows"
    )


def _infer_rate(t: FloatArray, source: str) -> float:
    """Inverse of the median sample interval, snapped to a device rate within 0.5 %.

    Unix times near 1.7e9 s carry about 0.2 µs of rounding, so a 5 ms interval is only
    known to ~1e-4; the output data rates of 0x2010:03 are the likely truth.
    """
    dt = np.diff(t)
    median = float(np.median(dt)) if dt.size else 0.0
    if median <= 0.0:
        where = source or "recording"
        raise InputError(f"{where}: no sample_rate_hz header and t does not give one")
    rate = 1.0 / median
    for device_rate in OUTPUT_DATA_RATES_HZ:
        if abs(rate - device_rate) <= 0.005 * device_rate:
            return float(device_rate)
    return rate


# ---------------------------------------------------------------------------------- reader


MEMORY_PER_FILE_BYTE = 14
"""Peak memory of reading a file whole, per byte of file (12.7 measured for a 40 MB,
1,000,000-row recording before issue 23: the text, numpy's parse and the table); the
importers still read whole files."""

STREAMED_MEMORY_PER_FILE_BYTE = 5
"""Peak memory of :func:`read_recording_csv` per byte of file: the typed columns (60 bytes a
row with float32-exact values, 104 without, about 1-2 per byte of a 56-byte row, up to 4 for
the shortest rows); the text is read in blocks of :data:`CHUNK_BYTES` and the repeats check
runs in chunks of :data:`DUPLICATE_CHUNK_ROWS`."""


def available_memory_bytes() -> int | None:
    """Memory this process can still take: ``MemAvailable``, capped by ``ulimit -v`` left.

    ``None`` when neither is known (not Linux, no limit).
    """
    limits: list[int] = []
    try:
        import resource

        soft, _ = resource.getrlimit(resource.RLIMIT_AS)
        if soft != resource.RLIM_INFINITY:
            limits.append(soft - _proc_kib("/proc/self/status", "VmSize:") * 1024)
    except (ImportError, OSError, ValueError):
        pass
    try:
        limits.append(_proc_kib("/proc/meminfo", "MemAvailable:") * 1024)
    except (OSError, ValueError):
        pass
    return max(0, min(limits)) if limits else None


def _proc_kib(path: str, key: str) -> int:
    """Return the ``kB`` value of ``key`` in a ``/proc`` file (ValueError when absent)."""
    with open(path, encoding="ascii") as lines:
        for line in lines:
            if line.startswith(key):
                return int(line.split()[1])
    raise ValueError(f"{key} not in {path}")


def require_memory(source: str, size_bytes: int, per_byte: float = MEMORY_PER_FILE_BYTE) -> None:
    """Refuse, before reading it, a file whose parsing would need more memory than is left.

    Raises :class:`InputError` naming the file's size, the memory needed and the memory
    available; does nothing when the available memory is unknown.
    """
    available = available_memory_bytes()
    needed = size_bytes * per_byte
    if available is not None and needed > available:
        raise InputError(
            f"{source}: not enough memory to read {size_bytes / 1e6:.0f} MB (needs about "
            f"{needed / 1e6:.0f} MB, {available / 1e6:.0f} MB available); split the file "
            "or record shorter stretches"
        )


def read_recording_csv(path: str | os.PathLike[str]) -> Recording:
    """Read and validate a recording CSV; every problem is an :class:`InputError`.

    A file too large for the memory left is refused before it is read
    (:func:`require_memory`); a MemoryError while parsing gives the same message.
    """
    source = str(path)
    size = 0
    try:
        size = Path(path).stat().st_size
        require_memory(source, size, STREAMED_MEMORY_PER_FILE_BYTE)
        with open(path, "rb") as handle:
            return _read_stream(handle, source, size)
    except OSError as exc:
        raise InputError(f"cannot read {source}: {exc.strerror or exc}") from exc
    except MemoryError:
        raise InputError(
            f"{source}: not enough memory to read {size / 1e6:.0f} MB; split the file "
            "or record shorter stretches"
        ) from None


def parse_recording(raw: bytes, source: str) -> Recording:
    """Parse and validate the bytes of a recording CSV read from ``source``.

    A UTF-8 byte-order mark (written by some spreadsheet programs) is skipped.
    """
    return _read_stream(io.BytesIO(raw), source, len(raw))


CHUNK_BYTES = 4 * 2**20
"""Bytes of rows parsed at a time (a block ends at the last complete line in it)."""

MAX_HEAD_LINE_BYTES = 2**16
"""The longest header or column line looked at (a longer one is wrong anyway)."""


def _read_stream(handle: BinaryIO, source: str, size: int) -> Recording:
    """Read a recording from a binary stream of ``size`` bytes (module doc)."""
    head = bytearray()
    while True:
        line = handle.readline(MAX_HEAD_LINE_BYTES)
        if not head:
            line = line.removeprefix(b"\xef\xbb\xbf")
        head += line
        if not line.startswith(b"#") or not line.endswith(b"\n"):
            break
    raw_head = bytes(head).replace(b"\r\n", b"\n")
    header, with_trial, line_no = _read_head(raw_head, source)
    width = len(COLUMNS) + with_trial
    columns: _Columns | None = None
    carry = b""
    last_t = -math.inf
    angles: dict[int, tuple[float, ...]] = {}
    ahead = handle.read(CHUNK_BYTES)
    while True:
        block, ahead = ahead, handle.read(CHUNK_BYTES) if ahead else b""
        final = not ahead
        data = carry + block
        if not final:
            cut = data.rfind(b"\n") + 1
            data, carry = data[:cut], data[cut:]
            if not data:
                continue
        if b"\r" in data:
            data = data.replace(b"\r\n", b"\n")
        if not final and (data.startswith(b"\n") or data.endswith(b"\n\n")):
            raise _diagnose(data[:-1], line_no, source, "empty line", width)  # rows follow
        table = parse_rows(data, line_no, source, width)
        trial = None
        if with_trial:
            table, trial = table[:, : len(COLUMNS)], _checked_trials(table[:, -1], line_no, source)
        check_table(table, line_no, source)
        if table.shape[0]:
            if table[0, 0] < last_t:
                raise located_error(source or "recording", line_no, "t goes backwards")
            _check_angles_across_blocks(table, angles, line_no, source)
            last_t = float(table[-1, 0])
        if columns is None:
            rows_per_byte = table.shape[0] / max(len(data), 1)
            capacity = int(size * rows_per_byte * 1.02) + table.shape[0] + 16
            columns = _Columns(capacity, with_trial=with_trial)
        columns.append(table, trial)
        line_no += int(np.count_nonzero(np.frombuffer(data, dtype=np.uint8) == 10))
        if final:
            break
    assert columns is not None
    return _recording_from_parts(header, columns, source)


def _check_angles_across_blocks(
    table: FloatArray, seen: dict[int, tuple[float, ...]], first_line: int, source: str
) -> None:
    """Refuse a position whose angles differ from an earlier block's; remember new ones."""
    changed = [
        label
        for label, value in angles_by_position(table).items()
        if seen.setdefault(label, value) != value
    ]
    if changed:
        rows = [int(np.argmax(table[:, 2] == label)) for label in changed]
        k = int(np.argmin(rows))
        raise located_error(
            source or "recording",
            first_line + rows[k],
            f"angles change within position {changed[k]:g}",
        )


def _checked_trials(values: FloatArray, first_line: int, source: str) -> NDArray[np.int64]:
    """Type a block's ``trial`` cells: empty (-1) or a non-negative integer, else an error."""
    bad = ~np.isnan(values) & ((values < 0) | (values != np.floor(values)))
    if bad.any():
        raise located_error(
            source or "recording",
            first_line + int(np.argmax(bad)),
            "trial is not a non-negative integer",
        )
    return np.where(np.isnan(values), -1, values).astype(np.int64)


def _read_head(raw: bytes, source: str) -> tuple[dict[str, HeaderValue], bool, int]:
    """Parse header and column line.

    Returns the header, whether the column line ends in the optional ``trial`` column, and
    the line number of the first row.
    """
    header: dict[str, HeaderValue] = {}
    pos, number = 0, 1
    while True:
        end = raw.find(b"\n", pos)
        end = len(raw) if end < 0 else end
        try:
            line = raw[pos:end].decode("utf-8")
        except UnicodeDecodeError:
            raise located_error(source, number, "not UTF-8 text") from None
        if not line.startswith("#"):
            break
        key, value = parse_header_line(line, f"{source}:{number}")
        if key in header:
            raise located_error(source, number, f"duplicate header key {key!r}")
        header[key] = value
        pos, number = end + 1, number + 1
    if "schema" not in header:
        raise located_error(source, number, f"missing header line '# schema: {SCHEMA}'")
    if pos >= len(raw):
        raise located_error(source, number, "missing column line")
    if line not in (COLUMN_LINE, TRIAL_COLUMN_LINE):
        raise located_error(source, number, _column_problem(line))
    return header, line == TRIAL_COLUMN_LINE, number + 1


def _column_problem(line: str) -> str:
    names = line.split(",")
    missing = [c for c in COLUMNS if c not in names]
    if missing:
        return f"missing columns {', '.join(missing)} (column line must be '{COLUMN_LINE}')"
    return f"column line must be exactly '{COLUMN_LINE}' (optionally followed by ',trial')"


SCHEMA = "canimucal.recording/1"
"""The only recording schema this version reads and writes."""

COLUMNS: tuple[str, ...] = ("t", "counter", "position", "alpha_deg", "beta_deg", "psi_deg")
COLUMNS += ("ax", "ay", "az", "gx", "gy", "gz", "temp_c")
COLUMN_LINE = ",".join(COLUMNS)
"""The exact column line of a recording."""

TRIAL_COLUMN_LINE = COLUMN_LINE + ",trial"
"""The column line of a recording with the optional ``trial`` column (docs/design.md §5):
several mountings of one unit in one file, each row naming its trial (empty: unknown)."""

HeaderValue = str | float | bool
"""A typed header value (``node_id`` and ``device_serial`` are ints)."""

FloatArray = NDArray[np.float64]

_NUMERIC_BYTES = b"0123456789eE.+-,\n"
NUMBER = re.compile(r"[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?")


# ---------------------------------------------------------------------------------- header


def _text(raw: str) -> str:
    if not raw:
        raise ValueError("empty value")
    return raw


def _finite(raw: str) -> float:
    if not NUMBER.fullmatch(raw):
        raise ValueError("not a number")
    number = float(raw)
    if not math.isfinite(number):
        raise ValueError("not a finite number")
    return number


def _positive(raw: str) -> float:
    number = _finite(raw)
    if number <= 0.0:
        raise ValueError("must be > 0")
    return number


def _non_negative(raw: str) -> float:
    number = _finite(raw)
    if number < 0.0:
        raise ValueError("must be >= 0")
    return number


def _nonzero(raw: str) -> float:
    number = _finite(raw)
    if number == 0.0:
        raise ValueError("must not be 0")
    return number


def _latitude(raw: str) -> float:
    number = _finite(raw)
    if abs(number) > 90.0:
        raise ValueError("must be within ±90")
    return number


def _integer(raw: str) -> int:
    if not raw.isascii() or not raw.isdigit():
        raise ValueError("not a non-negative integer")
    return int(raw)


def _node_id(raw: str) -> int:
    number = _integer(raw)
    if not 1 <= number <= 127:
        raise ValueError("must be 1..127")
    return number


def _serial(raw: str) -> int:
    number = _integer(raw)
    if not 0 <= number <= 0xFFFFFFFF:
        raise ValueError("must be 0..4294967295")
    return number


def _bool(raw: str) -> bool:
    if raw not in ("true", "false"):
        raise ValueError("must be true or false")
    return raw == "true"


def _choice(*allowed: str) -> Callable[[str], str]:
    def parse(raw: str) -> str:
        if raw not in allowed:
            raise ValueError(f"must be one of {', '.join(allowed)}")
        return raw

    return parse


def _plan_name(raw: str) -> str:
    if not re.fullmatch(r"[a-z][a-z0-9_-]{0,31}", raw):
        raise ValueError("not a plan name")
    return raw


def _matrix9(raw: str) -> str:
    """Nine finite numbers separated by spaces (a 3×3 matrix, row-major), kept as text."""
    parts = raw.split()
    if len(parts) != 9:
        raise ValueError("expected 9 numbers (a 3×3 matrix, row-major)")
    for part in parts:
        _finite(part)
    return " ".join(parts)


def header_matrix(value: HeaderValue) -> NDArray[np.float64]:
    """Return the 3×3 matrix of a ``prior_k`` header value."""
    return np.array([float(v) for v in str(value).split()], dtype=float).reshape(3, 3)


def matrix_header(matrix: NDArray[np.float64]) -> str:
    """Return the ``prior_k`` header value of a 3×3 matrix (exact: ``repr`` of each float)."""
    return " ".join(repr(float(v)) for v in np.asarray(matrix, dtype=float).reshape(9))


HEADER_PARSERS: Mapping[str, Callable[[str], HeaderValue]] = {
    "schema": _text,
    "sample_rate_hz": _positive,
    "node_id": _node_id,
    "device_serial": _serial,
    "g": _positive,
    "latitude_deg": _latitude,
    "height_m": _finite,
    "heading_deg": _finite,
    "accel_lsb": _nonzero,
    "gyro_lsb": _nonzero,
    "accel_units": _text,
    "gyro_units": _text,
    "offset_binary": _bool,
    "plan": _plan_name,
    "model": _choice("diag", "full"),
    "tilt": _choice("rigid", "additive", "none"),
    "gyro": _choice("none", "mems", "moves", "nav"),
    "tolerance_deg": _non_negative,
    "prior_k": _matrix9,
    "prior_k_sigma": _positive,
    "prior_k_source": _text,
    "prior_k_sigma_source": _text,
    "gyro_g": _bool,
}
"""Every header key (docs/design.md §5, §9, docs/recording-header.md), with its value's parser;
any other is refused.

``plan``, ``model``, ``tilt``, ``gyro``, ``tolerance_deg`` (the plan's angle-setting 1σ) and
``gyro_g`` (G estimated) are written by the tool's own sessions: the model the session solved,
for ``solve``. So are ``prior_k`` (the mean of the prior on K the session held, counts per
m/s², row-major), ``prior_k_sigma`` (its relative 1σ) and where each came from."""


def parse_header_line(line: str, where: str) -> tuple[str, HeaderValue]:
    """Split and type one ``# key: value`` line; ``where`` (``FILE:LINE``) leads messages."""
    key, sep, raw = line[1:].partition(":")
    key, raw = key.strip(), raw.strip()
    if not sep or not key:
        raise InputError(f"{where}: header line is not '# key: value'")
    parser = HEADER_PARSERS.get(key)
    if parser is None:
        raise InputError(f"{where}: unknown header key {key!r}")
    try:
        value = parser(raw)
    except ValueError as exc:
        raise InputError(f"{where}: bad value {raw!r} for header key {key!r} ({exc})") from None
    if key == "schema" and value != SCHEMA:
        raise InputError(f"{where}: unknown schema {raw!r} (this version reads {SCHEMA})")
    return key, value


def normalise_header(header: Mapping[str, HeaderValue]) -> dict[str, HeaderValue]:
    """Validate and type ``header`` as a reader would (``schema`` added when absent).

    ``{"sample_rate_hz": 200}`` becomes ``{"schema": ..., "sample_rate_hz": 200.0}``.
    """
    items = {"schema": SCHEMA, **header}
    out: dict[str, HeaderValue] = {}
    for key in ["schema", *sorted(k for k in items if k != "schema")]:
        value = items[key]
        raw = ("true" if value else "false") if isinstance(value, bool) else str(value)
        if "\n" in raw or "\r" in raw:
            raise InputError(f"header value of {key!r} spans lines")
        out[key] = parse_header_line(f"# {key}: {raw}", "header")[1]
    return out


def format_header(header: Mapping[str, HeaderValue]) -> str:
    """Return the header lines of ``header`` (``schema`` first), validated."""
    lines = []
    for key, value in normalise_header(header).items():
        raw = ("true" if value else "false") if isinstance(value, bool) else str(value)
        lines.append(f"# {key}: {raw}\n")
    return "".join(lines)


# ---------------------------------------------------------------------------- table checks


def located_error(source: str, line: int, problem: str) -> InputError:
    """Build the one-line error ``FILE:LINE: problem``."""
    return InputError(f"{source}:{line}: {problem}")


def check_table(table: FloatArray, first_line: int, source: str) -> None:
    """Semantic checks of a parsed ``(n, 13)`` table; row ``i`` is line ``first_line + i``."""
    where = source or "recording"

    def first(mask: NDArray[np.bool_] | np.bool_) -> int:
        return first_line + int(np.argmax(mask))

    if np.isinf(table).any():
        raise located_error(where, first(np.isinf(table).any(axis=1)), "number out of range")
    nan = np.isnan(table).T  # one pass over the table; nan[c] is column c
    if nan[0].any():
        raise located_error(where, first(nan[0]), "t is empty")
    back = np.diff(table[:, 0]) < 0
    if back.any():
        raise located_error(where, first(back) + 1, "t goes backwards")
    for col, name in ((1, "counter"), (2, "position")):
        values = table[:, col]
        bad = ~nan[col] & ((values < 0) | (values != np.floor(values)))
        if bad.any():
            raise located_error(where, first(bad), f"{name} is not a non-negative integer")
    for col, what in ((3, "angles"), (6, "accel"), (9, "gyro")):
        partial = (nan[col] != nan[col + 1]) | (nan[col + 1] != nan[col + 2])
        if partial.any():
            raise located_error(
                where, first(partial), f"{what} cells partly empty (all three or none)"
            )
    no_data = nan[6] & nan[9]
    if no_data.any():
        raise located_error(where, first(no_data), "row has neither accel nor gyro values")
    _check_angles_constant(table, first_line, where)


def _check_angles_constant(table: FloatArray, first_line: int, where: str) -> None:
    """Refuse a position whose rows' angles differ (empty equals empty).

    Read from the runs of equal labels: each row against the one before in its run, each
    run's first row against the last row of the label's previous run. Reports the smallest
    label with a change, at its first changed row (as a stable sort by label would).
    """
    label = table[:, 2]
    if np.isnan(label).all():
        return
    angles = np.nan_to_num(table[:, 3:6], nan=np.inf)  # inf: a comparable "empty"
    first_change: dict[float, int] = {}
    same_label = label[1:] == label[:-1]  # NaN never equals: unlabelled rows are skipped
    inside = np.flatnonzero(same_label & (angles[1:] != angles[:-1]).any(axis=1)) + 1
    if inside.size:
        labels, first = np.unique(label[inside], return_index=True)
        first_change = dict(zip(labels.tolist(), inside[first].tolist(), strict=True))
    last_row: dict[float, int] = {}
    starts = np.concatenate([[0], np.flatnonzero(~same_label) + 1])
    stops = np.concatenate([starts[1:], [label.shape[0]]])
    for a, b in zip(starts.tolist(), stops.tolist(), strict=True):
        value = float(label[a])
        if value != value:  # NaN: no position
            continue
        before = last_row.get(value)
        if before is not None and bool((angles[a] != angles[before]).any()):
            first_change[value] = min(first_change.get(value, a), a)
        last_row[value] = b - 1
    if first_change:
        worst = min(first_change)
        raise located_error(
            where, first_line + first_change[worst], f"angles change within position {worst:g}"
        )


# -------------------------------------------------------------------------------- parsing


def parse_rows(data: bytes, first_line: int, source: str, width: int = len(COLUMNS)) -> FloatArray:
    """Parse the data rows into an ``(n, width)`` float table, NaN for empty cells.

    ``width`` is 13, or 14 with the ``trial`` column.
    """
    if data.endswith(b"\n"):
        data = data[:-1]
    if not data:
        return np.empty((0, width))
    table = decimal_table(data, width)  # plain decimals: exact, 2-3x faster than loadtxt
    if table is not None:
        return table
    blank_line, empty_cells = _blanks(data)
    if data.translate(None, _NUMERIC_BYTES) or data.startswith(b"\n") or blank_line:
        raise _diagnose(data, first_line, source, "unexpected characters", width)
    # Empty cells become "nan" (letters were refused above, so NaN only comes from here),
    # inserted where each one starts: one pass, however many there are.
    if empty_cells.size:
        nan = np.tile(np.frombuffer(b"nan", dtype=np.uint8), empty_cells.size)
        at = np.repeat(empty_cells, 3)
        text = np.insert(np.frombuffer(data, dtype=np.uint8), at, nan).tobytes().decode("ascii")
    else:
        text = data.decode("ascii")
    try:
        table = np.loadtxt(io.StringIO(text), delimiter=",", comments=None, ndmin=2)
    except ValueError as exc:
        raise _diagnose(data, first_line, source, str(exc).splitlines()[0], width) from None
    if table.shape[1] != width:
        raise _diagnose(data, first_line, source, "wrong number of columns", width)
    return table


def _blanks(data: bytes) -> tuple[bool, NDArray[np.intp]]:
    """Find the empty lines and empty cells of ``data`` (rows without their final newline).

    Returns whether there is an empty line, and where each empty cell starts (after a comma
    followed by a comma, a newline or the end). Looked for with numpy: 8x faster than
    ``bytes`` searches for a two-byte pattern.
    """
    u = np.frombuffer(data, dtype=np.uint8)
    newline, comma = u == ord("\n"), u == ord(",")
    blank_line = bool((newline[:-1] & newline[1:]).any())
    empty = np.flatnonzero(comma[:-1] & (comma[1:] | newline[1:])) + 1
    if data.endswith(b","):
        empty = np.append(empty, len(data))
    return blank_line, empty


def _diagnose(
    data: bytes, first_line: int, source: str, fallback: str, width: int = len(COLUMNS)
) -> InputError:
    """Slow pass over the rows: raise an :class:`InputError` for the first bad line.

    Returns an error carrying ``fallback`` if no line is found bad (not expected).
    """
    names = COLUMNS + (("trial",) if width > len(COLUMNS) else ())
    for offset, line_bytes in enumerate(data.split(b"\n")):
        line_no = first_line + offset
        try:
            line = line_bytes.decode("utf-8")
        except UnicodeDecodeError:
            raise located_error(source, line_no, "not UTF-8 text") from None
        if not line:
            raise located_error(source, line_no, "empty line")
        cells = line.split(",")
        if len(cells) != len(names):
            raise located_error(source, line_no, f"expected {len(names)} cells, got {len(cells)}")
        for name, cell in zip(names, cells, strict=True):
            if cell and not NUMBER.fullmatch(cell):
                lowered = cell.strip().lower().lstrip("+-")
                if lowered in ("nan", "inf", "infinity"):
                    problem = f"{cell!r} in column {name}: leave unknown values empty"
                else:
                    problem = f"non-numeric cell {cell[:20]!r} in column {name}"
                raise located_error(source, line_no, problem)
            if not cell and name == "t":
                raise located_error(source, line_no, "t is empty")
    return located_error(source, first_line, fallback)


# ---------------------------------------------------------------------------------- writer


def format_table(table: FloatArray) -> str:
    """CSV rows for an ``(n, 13)`` table, or 14 with ``trial`` (NaN → empty cell).

    ``t`` is written with at least 6 decimals.
    """
    if table.shape[0] == 0:
        return ""
    columns = [_format_time(table[:, 0])]
    for col in range(1, table.shape[1]):
        columns.append(_format_numbers(table[:, col]))
    return "\n".join(map(",".join, zip(*columns, strict=True))) + "\n"


def _format_time(t: FloatArray) -> list[str]:
    """Six decimals, or the shortest exact form with at least six when six lose bits."""
    text = [f"{x:.6f}" for x in t.tolist()]
    exact = np.array(list(map(float, text))) == t
    for i in np.flatnonzero(~exact):
        text[i] = np.format_float_positional(t[i], unique=True, min_digits=6)
    return text


def _format_numbers(values: FloatArray) -> list[str]:
    """Integers without a decimal point, other numbers as their shortest exact repr."""
    empty = np.isnan(values)
    if empty.all():
        return [""] * values.shape[0]
    finite = values[~empty]
    if np.all(finite == np.round(finite)) and np.all(np.abs(finite) < 2**53):
        text = list(map(str, np.where(empty, 0, values).astype(np.int64).tolist()))
    else:
        text = list(map(repr, values.tolist()))
    for i in np.flatnonzero(empty).tolist():
        text[i] = ""
    return text


def angles_by_position(table: FloatArray) -> dict[int, tuple[float, ...]]:
    """Angles of each labelled position (first row; the table was checked to agree)."""
    label = table[:, 2]
    if label.shape[0] == 0:
        return {}
    starts = np.concatenate([[0], np.flatnonzero(label[1:] != label[:-1]) + 1])
    starts = starts[~np.isnan(label[starts])]
    labels, first = np.unique(label[starts], return_index=True)
    rows = starts[first]
    angles = np.nan_to_num(table[rows, 3:6], nan=np.inf)  # inf: a comparable "empty"
    return {int(k): tuple(a) for k, a in zip(labels.tolist(), angles.tolist(), strict=True)}


def check_same_origin(
    old: Mapping[str, HeaderValue], new: Mapping[str, HeaderValue], old_rate_inferred: bool
) -> None:
    """Refuse to append data of another schema, sample rate or device serial."""
    for key in ("schema", "sample_rate_hz", "device_serial"):
        old_value, new_value = old.get(key), new.get(key)
        inferred = key == "sample_rate_hz" and old_rate_inferred
        if inferred and isinstance(new_value, float) and isinstance(old_value, float):
            if abs(old_value - new_value) <= 0.01 * new_value:  # inferred: 1 % agreement
                continue
        if old_value != new_value:
            raise InputError(
                f"cannot append: header {key!r} is {old_value!r} in the file, {new_value!r} now"
            )
