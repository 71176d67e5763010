"""The recording CSV (DESIGN §5): the parsed :class:`Recording` and its strict fast reader.

Layout: ``# key: value`` header lines (``schema: canimucal.recording/1`` required), the exact
column line ``t,counter,position,alpha_deg,beta_deg,psi_deg,ax,ay,az,gx,gy,gz,temp_c``, then
one row per sample. Empty cells mean "unknown": ``counter``/angles/``temp_c`` read as NaN,
``position`` as -1, a lost PDO half as three NaN columns.

Reading parses the numbers with numpy in one pass; when that fails, a slow line-by-line pass
finds the first bad line so the error names file, line and problem. The streaming and
whole-file writers live in :mod:`canimucal.io.recording_writer`.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from canimucal.errors import InputError
from canimucal.io.recording_format import (
    COLUMN_LINE,
    COLUMNS,
    SCHEMA,
    FloatArray,
    HeaderValue,
    check_table,
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
    "read_recording",
    "recording_from_columns",
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
    table = block_table(t, accel, gyro, counter, position, alpha_deg, beta_deg, psi_deg, temp_c)
    return _recording_from_table(normalise_header(header), table, first_line=1, source="")


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
