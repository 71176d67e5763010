"""Rules of the recording CSV (DESIGN §5): header keys and types, row checks, number format.

Shared by the reader and the writers of :mod:`canimucal.io.recording`, so that whatever the
writers accept, the reader reads back.
"""

from __future__ import annotations

import io
import math
import re
from collections.abc import Callable, Mapping

import numpy as np
from numpy.typing import NDArray

from canimucal.errors import InputError

SCHEMA = "canimucal.recording/1"
"""The only recording schema this version reads and writes."""

COLUMNS: tuple[str, ...] = ("t", "counter", "position", "alpha_deg", "beta_deg", "psi_deg")
COLUMNS += ("ax", "ay", "az", "gx", "gy", "gz", "temp_c")
COLUMN_LINE = ",".join(COLUMNS)
"""The exact column line of a recording."""

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
}
"""Every header key DESIGN §5 allows, with the parser of its value; any other is refused."""


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
    if np.isnan(table[:, 0]).any():
        raise located_error(where, first(np.isnan(table[:, 0])), "t is empty")
    back = np.diff(table[:, 0]) < 0
    if back.any():
        raise located_error(where, first(back) + 1, "t goes backwards")
    for col, name in ((1, "counter"), (2, "position")):
        values = table[:, col]
        bad = ~np.isnan(values) & ((values < 0) | (values != np.floor(values)))
        if bad.any():
            raise located_error(where, first(bad), f"{name} is not a non-negative integer")
    for cols, what in ((slice(3, 6), "angles"), (slice(6, 9), "accel"), (slice(9, 12), "gyro")):
        empty = np.isnan(table[:, cols])
        partial = empty.any(axis=1) & ~empty.all(axis=1)
        if partial.any():
            raise located_error(
                where, first(partial), f"{what} cells partly empty (all three or none)"
            )
    no_data = np.isnan(table[:, 6]) & np.isnan(table[:, 9])
    if no_data.any():
        raise located_error(where, first(no_data), "row has neither accel nor gyro values")
    _check_angles_constant(table, first_line, where)


def _check_angles_constant(table: FloatArray, first_line: int, where: str) -> None:
    labelled = np.flatnonzero(~np.isnan(table[:, 2]))
    if labelled.size == 0:
        return
    labels = table[labelled, 2]
    angles = np.nan_to_num(table[labelled, 3:6], nan=np.inf)  # inf: a comparable "empty"
    order = np.argsort(labels, kind="stable")
    labels, angles, rows = labels[order], angles[order], labelled[order]
    same_label = labels[1:] == labels[:-1]
    changed = same_label & (angles[1:] != angles[:-1]).any(axis=1)
    if changed.any():
        k = int(np.argmax(changed)) + 1
        raise located_error(
            where, first_line + int(rows[k]), f"angles change within position {labels[k]:g}"
        )


# -------------------------------------------------------------------------------- parsing


def parse_rows(data: bytes, first_line: int, source: str) -> FloatArray:
    """Parse the data rows into an ``(n, 13)`` float table, NaN for empty cells."""
    if data.endswith(b"\n"):
        data = data[:-1]
    if not data:
        return np.empty((0, len(COLUMNS)))
    if data.translate(None, _NUMERIC_BYTES) or data.startswith(b"\n") or b"\n\n" in data:
        raise _diagnose(data, first_line, source, "unexpected characters")
    # Empty cells become "nan" (letters were refused above, so NaN only comes from here).
    filled = data.replace(b",,", b",nan,").replace(b",,", b",nan,").replace(b",\n", b",nan\n")
    text = filled.decode("ascii") + ("nan" if filled.endswith(b",") else "")
    try:
        table = np.loadtxt(io.StringIO(text), delimiter=",", comments=None, ndmin=2)
    except ValueError as exc:
        raise _diagnose(data, first_line, source, str(exc).splitlines()[0]) from None
    if table.shape[1] != len(COLUMNS):
        raise _diagnose(data, first_line, source, "wrong number of columns")
    return table


def _diagnose(data: bytes, first_line: int, source: str, fallback: str) -> InputError:
    """Slow pass over the rows: raise an :class:`InputError` for the first bad line.

    Returns an error carrying ``fallback`` if no line is found bad (not expected).
    """
    for offset, line_bytes in enumerate(data.split(b"\n")):
        line_no = first_line + offset
        try:
            line = line_bytes.decode("utf-8")
        except UnicodeDecodeError:
            raise located_error(source, line_no, "not UTF-8 text") from None
        if not line:
            raise located_error(source, line_no, "empty line")
        cells = line.split(",")
        if len(cells) != len(COLUMNS):
            raise located_error(source, line_no, f"expected {len(COLUMNS)} cells, got {len(cells)}")
        for name, cell in zip(COLUMNS, cells, strict=True):
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
    """CSV rows for an ``(n, 13)`` table (NaN → empty cell), ``t`` with ≥ 6 decimals."""
    if table.shape[0] == 0:
        return ""
    columns = [_format_time(table[:, 0])]
    for col in range(1, len(COLUMNS)):
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
    labelled = table[~np.isnan(table[:, 2])]
    labels, first = np.unique(labelled[:, 2], return_index=True)
    angles = np.nan_to_num(labelled[first, 3:6], nan=np.inf)  # inf: a comparable "empty"
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
