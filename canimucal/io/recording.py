"""The recording CSV (DESIGN §5): a strict fast reader, a streaming writer, a whole-file writer.

Layout: ``# key: value`` header lines (``schema: canimucal.recording/1`` required), the exact
column line ``t,counter,position,alpha_deg,beta_deg,psi_deg,ax,ay,az,gx,gy,gz,temp_c``, then
one row per sample. Empty cells mean "unknown": ``counter``/angles/``temp_c`` read as NaN,
``position`` as -1, a lost PDO half as three NaN columns.

Reading parses the numbers with numpy in one pass; when that fails, a slow line-by-line pass
finds the first bad line so the error names file, line and problem.

Writing: :class:`RecordingWriter` streams into ``OUT.csv.partial`` (flushed per block) and
renames it to ``OUT.csv`` on :meth:`RecordingWriter.close`, which the context manager calls
on any exit, Ctrl-C included. A process killed outright leaves ``OUT.csv.partial`` with every
block written so far; the target name only ever holds a complete file.
"""

from __future__ import annotations

import logging
import math
import os
import shutil
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType
from typing import TextIO

import numpy as np
from numpy.typing import ArrayLike, NDArray

from canimucal.errors import InputError
from canimucal.io.atomic import move_into_place, refuse_existing, write_text_atomic
from canimucal.io.recording_format import (
    COLUMN_LINE,
    COLUMNS,
    SCHEMA,
    FloatArray,
    HeaderValue,
    angles_by_position,
    check_same_origin,
    check_table,
    format_header,
    format_table,
    located_error,
    normalise_header,
    parse_header_line,
    parse_rows,
)

__all__ = [
    "COLUMNS",
    "COLUMN_LINE",
    "SCHEMA",
    "HeaderValue",
    "Recording",
    "RecordingWriter",
    "read_recording",
    "recording_from_columns",
    "write_recording",
]

logger = logging.getLogger(__name__)

DEVICE_RATES_HZ = (50, 100, 200, 250, 500, 1000)
"""Output data rates the IMU offers (0x2010:03); an inferred rate near one snaps to it."""

# ------------------------------------------------------------------------------- recording


@dataclass(frozen=True, eq=False)
class Recording:
    """A parsed recording: typed header and one numpy array per column (see module doc).

    ``accel``/``gyro`` are ``(n, 3)`` counts; ``position`` is int with -1 for "no position".
    ``sample_rate_inferred`` is true when the header had no ``sample_rate_hz`` and the
    value in ``header`` is the median sample interval's inverse.
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

    @property
    def n_rows(self) -> int:
        """Number of sample rows."""
        return int(self.t.shape[0])

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
) -> Recording:
    """Build a :class:`Recording` from column arrays; ``None`` means an empty column."""
    table = _block_table(t, accel, gyro, counter, position, alpha_deg, beta_deg, psi_deg, temp_c)
    return _recording_from_table(normalise_header(header), table, first_line=1, source="")


def _block_table(
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
    header: dict[str, HeaderValue], table: FloatArray, *, first_line: int, source: str
) -> Recording:
    check_table(table, first_line, source)
    inferred = False
    if "sample_rate_hz" not in header:
        header["sample_rate_hz"] = _infer_rate(table[:, 0], source)
        inferred = True
        logger.info("%s: sample_rate_hz inferred from t: %g", source, header["sample_rate_hz"])
    position = np.where(np.isnan(table[:, 2]), -1, table[:, 2]).astype(np.int64)
    arrays = [np.ascontiguousarray(table[:, i]) for i in (0, 1, 3, 4, 5, 12)]
    accel, gyro = np.ascontiguousarray(table[:, 6:9]), np.ascontiguousarray(table[:, 9:12])
    for arr in (*arrays, accel, gyro, position):
        arr.setflags(write=False)
    t, counter, alpha, beta, psi, temp = arrays
    return Recording(
        header, t, counter, position, alpha, beta, psi, accel, gyro, temp, inferred, source
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
    for device_rate in DEVICE_RATES_HZ:
        if abs(rate - device_rate) <= 0.005 * device_rate:
            return float(device_rate)
    return rate


# ---------------------------------------------------------------------------------- reader


def read_recording(path: str | os.PathLike[str]) -> Recording:
    """Read and validate a recording CSV; every problem is an :class:`InputError`."""
    source = str(path)
    try:
        raw = Path(path).read_bytes()
    except OSError as exc:
        raise InputError(f"cannot read {source}: {exc.strerror or exc}") from exc
    if b"\r" in raw:
        raw = raw.replace(b"\r\n", b"\n")
    header, data_start, first_line = _read_head(raw, source)
    table = parse_rows(raw[data_start:], first_line, source)
    return _recording_from_table(header, table, first_line=first_line, source=source)


def _read_head(raw: bytes, source: str) -> tuple[dict[str, HeaderValue], int, int]:
    """Parse header and column line; return header, offset of the data and its line number."""
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
    if line != COLUMN_LINE:
        raise located_error(source, number, _column_problem(line))
    return header, end + 1, number + 1


def _column_problem(line: str) -> str:
    names = line.split(",")
    missing = [c for c in COLUMNS if c not in names]
    if missing:
        return f"missing columns {', '.join(missing)} (column line must be '{COLUMN_LINE}')"
    return f"column line must be exactly '{COLUMN_LINE}'"


# ---------------------------------------------------------------------------------- writer


def write_recording(path: str | os.PathLike[str], recording: Recording, *, overwrite: bool) -> Path:
    """Write a whole :class:`Recording` atomically (header, column line, rows)."""
    table = _recording_table(recording)
    check_table(table, 1, str(path))  # a Recording built by hand gets the reader's checks
    text = format_header(recording.header) + COLUMN_LINE + "\n" + format_table(table)
    return write_text_atomic(path, text, overwrite=overwrite)


def _recording_table(rec: Recording) -> FloatArray:
    position = np.where(rec.position < 0, np.nan, rec.position.astype(float))
    cols = [rec.t, rec.counter, position, rec.alpha_deg, rec.beta_deg, rec.psi_deg]
    return np.column_stack([*cols, rec.accel, rec.gyro, rec.temp_c])


class RecordingWriter:
    """Streaming writer for the recorder (see the module doc for the ``.partial`` design).

    Use :meth:`open` (or ``with RecordingWriter.open(...) as writer``), then
    :meth:`write_rows` per block, then :meth:`close`.
    """

    def __init__(self, path: Path, handle: TextIO, *, overwrite: bool) -> None:
        self.path = path
        self.partial_path = _partial(path)
        self._handle: TextIO | None = handle
        self._overwrite = overwrite
        self._last_t = -math.inf
        self._angles: dict[int, tuple[float, ...]] = {}
        self.rows_written = 0

    @classmethod
    def open(
        cls,
        path: str | os.PathLike[str],
        header: Mapping[str, HeaderValue],
        *,
        overwrite: bool = False,
        append: bool = False,
    ) -> RecordingWriter:
        """Start ``path.partial``; with ``append`` it starts as a copy of ``path``.

        Raises :class:`InputError` when ``path`` exists (without ``overwrite``/``append``),
        when ``path.partial`` exists (an interrupted recording: keep or remove it), or when
        appending to a file whose schema, sample rate or device serial differ.
        """
        target = Path(path)
        partial = _partial(target)
        if os.path.lexists(partial) and not overwrite:
            raise InputError(f"{partial} exists (an interrupted recording?); move it away")
        if append:
            return cls._open_append(target, partial, header)
        refuse_existing(target, overwrite=overwrite)
        head = format_header(header) + COLUMN_LINE + "\n"
        writer = cls(target, _open_text(partial, append=False), overwrite=overwrite)
        writer._write(head)
        return writer

    @classmethod
    def _open_append(
        cls, target: Path, partial: Path, header: Mapping[str, HeaderValue]
    ) -> RecordingWriter:
        if not target.exists():
            raise InputError(f"cannot append: {target} does not exist")
        old = read_recording(target)
        check_same_origin(old.header, normalise_header(header), old.sample_rate_inferred)
        try:
            shutil.copyfile(target, partial)
        except OSError as exc:
            raise InputError(f"cannot write {partial}: {exc.strerror or exc}") from exc
        writer = cls(target, _open_text(partial, append=True), overwrite=True)
        if not _ends_with_newline(target):
            writer._write("\n")
        writer._last_t = float(old.t[-1]) if old.n_rows else -math.inf
        writer._remember_angles(_recording_table(old))
        return writer

    def write_rows(
        self,
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
    ) -> int:
        """Append one block of rows (``None`` = empty column; position < 0 = empty).

        The block is validated as a reader would (t non-decreasing across blocks, angles
        constant per position) before anything is written. Returns the rows written.
        """
        table = _block_table(
            t, accel, gyro, counter, position, alpha_deg, beta_deg, psi_deg, temp_c
        )
        if table.shape[0] == 0:
            return 0
        check_table(table, self.rows_written + 1, f"{self.path} (block)")
        if table[0, 0] < self._last_t:
            raise InputError(f"{self.path}: t goes backwards between blocks")
        self._check_angles_against_earlier(table)
        self._write(format_table(table))
        self._last_t = float(table[-1, 0])
        self._remember_angles(table)
        self.rows_written += table.shape[0]
        return int(table.shape[0])

    def _check_angles_against_earlier(self, table: FloatArray) -> None:
        for label, angles in angles_by_position(table).items():
            known = self._angles.get(label)
            if known is not None and known != angles:
                raise InputError(f"{self.path}: angles change within position {label}")

    def _remember_angles(self, table: FloatArray) -> None:
        self._angles.update(angles_by_position(table))

    def _write(self, text: str) -> None:
        if self._handle is None:
            raise InputError(f"{self.path}: writer is closed")
        self._handle.write(text)
        self._handle.flush()

    def close(self) -> Path:
        """Flush, fsync and rename ``path.partial`` to ``path``; idempotent."""
        handle, self._handle = self._handle, None
        if handle is None:
            return self.path
        try:
            os.fsync(handle.fileno())
        finally:
            handle.close()
        try:
            move_into_place(self.partial_path, self.path, overwrite=self._overwrite)
        except OSError as exc:
            raise InputError(f"cannot write {self.path}: {exc.strerror or exc}") from exc
        logger.info("wrote %s (%d new rows)", self.path, self.rows_written)
        return self.path

    def __enter__(self) -> RecordingWriter:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()


def _ends_with_newline(path: Path) -> bool:
    with open(path, "rb") as handle:
        handle.seek(0, os.SEEK_END)
        if handle.tell() == 0:
            return True
        handle.seek(-1, os.SEEK_END)
        return handle.read(1) == b"\n"


def _partial(path: Path) -> Path:
    return path.with_name(path.name + ".partial")


def _open_text(path: Path, *, append: bool) -> TextIO:
    try:
        if append:
            return open(path, "a", encoding="utf-8", newline="\n")
        return open(path, "w", encoding="utf-8", newline="\n")
    except OSError as exc:
        raise InputError(f"cannot write {path}: {exc.strerror or exc}") from exc
