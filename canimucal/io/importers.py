"""Importers of other tools' recordings into :class:`Recording` objects (docs/design.md §5, §6).

- **imu_tk**: two ASCII files (accelerometer, gyro) of whitespace columns ``t x y z``; raw
  counts of a 16-bit offset-binary sensor (about 32768 at zero). The header says so with
  ``offset_binary: true`` and ``accel_units``/``gyro_units: counts``; the offset stays in
  the data (it is part of the bias). Rows of the two files are paired by index; the times
  must agree.
- **imucal**: one CSV ``n_samples,gyr_x,gyr_y,gyr_z,acc_x,acc_y,acc_z`` (gyro deg/s, accel
  m/s², the sensor's nominal units) and a section JSON ``{name: {"start", "end"}}`` of
  sample indices. The values are kept in their units, which become the "counts" of the
  recording: ``accel_lsb: 1`` (m/s² per unit) and ``gyro_lsb: π/180`` (rad/s per deg/s).
  Sections whose name ends in ``_rot`` are left unlabelled and become known turns
  (:class:`KnownTurn`): −360° about the body axis their name starts with (imucal's own
  default, ``expected_angle = −360``: the operator turns clockwise); the static ones become
  positions 0, 1, … in file order. The six Ferraris poses carry their angles
  (:data:`FERRARIS_POSES`: ``x_p`` = +x up, ``x_a`` = +x down, …); other static sections
  have none. The CSV has no time column: ``sample_rate_hz`` must be given.

:func:`detect_format` tells the three formats apart by content, not by name. The one
dispatcher over every input format, bus logs included, is
:func:`canimucal.runtime.inputs.read_recording`.
"""

from __future__ import annotations

import dataclasses
import logging
import os
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from canimucal.errors import InputError
from canimucal.io.recording import (
    HeaderValue,
    KnownTurn,
    Recording,
    recording_from_columns,
    require_memory,
)
from canimucal.schema import parse_json, read_text

log = logging.getLogger(__name__)

Format = Literal["recording", "imutk", "imucal"]
FORMATS: tuple[Format, ...] = ("recording", "imutk", "imucal")

IMUCAL_COLUMNS = ("n_samples", "gyr_x", "gyr_y", "gyr_z", "acc_x", "acc_y", "acc_z")
"""The columns of imucal's example session CSV, in order."""

FERRARIS_POSES = {
    "x_p": (-90.0, 0.0, 0.0),
    "x_a": (90.0, 0.0, 0.0),
    "y_p": (180.0, 0.0, 0.0),
    "y_a": (0.0, 0.0, 0.0),
    "z_p": (0.0, 90.0, 0.0),
    "z_a": (0.0, -90.0, 0.0),
}
"""(alpha, beta, psi) degrees of imucal's six static poses in docs/design.md §2's convention: at
rest f = C f_L with f_L = [0, −g, 0], so +x up (``x_p``, f = [+g, 0, 0]) is alpha = −90°,
+y up (f = [0, +g, 0]) alpha = 180°, +z up (f = [0, 0, +g]) beta = +90°."""

_PathLike = str | os.PathLike[str]

UTF8_BOM = b"\xef\xbb\xbf"
"""The byte-order mark some Windows programs put before UTF-8 text: skipped in every format."""


def _head(path: _PathLike, size: int = 4096) -> str:
    """Return the first ``size`` bytes of ``path`` as text, a leading BOM skipped."""
    try:
        with open(path, "rb") as handle:
            raw = handle.read(size)
    except OSError as exc:
        raise InputError(f"{path}: cannot read ({exc.strerror})") from None
    return raw.removeprefix(UTF8_BOM).decode("utf-8", errors="replace")


def detect_format(path: _PathLike) -> Format:
    """Tell the format of ``path`` from its first lines (InputError when none fits)."""
    lines = [ln.strip() for ln in _head(path).splitlines() if ln.strip()]
    if not lines:
        raise InputError(f"{path}: empty file")
    if lines[0].startswith("#") and "canimucal.recording" in lines[0]:
        return "recording"
    if lines[0].startswith("#"):
        return "recording"  # a header without schema: the reader says what is wrong
    names = [c.strip() for c in lines[0].split(",")]
    if "gyr_x" in names and "acc_x" in names:
        return "imucal"
    fields = lines[0].split()
    if len(fields) == 4 and all(_is_number(f) for f in fields):
        return "imutk"
    raise InputError(
        f"{path}: unknown format (not a canimucal recording, an imu_tk 't x y z' file, an "
        "imucal CSV or a CAN bus log); name it with format=",
        options=("format=",),
    )


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _load_columns(path: _PathLike, columns: int) -> NDArray[np.float64]:
    try:
        require_memory(str(path), os.stat(path).st_size)
        data = np.loadtxt(path, dtype=float, ndmin=2, encoding="utf-8-sig")
    except (OSError, ValueError) as exc:
        raise InputError(f"{path}: not a table of numbers ({exc})") from None
    except MemoryError:
        raise InputError(
            f"{path}: not enough memory to read it; split the file or record shorter stretches"
        ) from None
    if data.shape[1] != columns or data.shape[0] < 2:
        raise InputError(f"{path}: expected {columns} columns, got shape {data.shape}")
    if not np.all(np.isfinite(data)):
        raise InputError(f"{path}: NaN or infinite values")
    return data


def read_imutk(accel_path: _PathLike, gyro_path: _PathLike | None = None) -> Recording:
    """Read imu_tk's accelerometer file and, optionally, its gyro file (module doc)."""
    acc = _load_columns(accel_path, 4)
    gyro = None
    if gyro_path is not None:
        gyr = _load_columns(gyro_path, 4)
        if gyr.shape[0] != acc.shape[0]:
            raise InputError(
                f"{gyro_path}: {gyr.shape[0]} rows but the accelerometer file has {acc.shape[0]}"
            )
        if not np.allclose(gyr[:, 0], acc[:, 0], atol=1e-4):
            raise InputError(f"{gyro_path}: its times differ from the accelerometer file's")
        gyro = gyr[:, 1:]
    if np.any(np.diff(acc[:, 0]) <= 0):
        raise InputError(f"{accel_path}: times must increase")
    rate = _snap_rate(1.0 / float(np.median(np.diff(acc[:, 0]))))
    header: dict[str, HeaderValue] = {
        "sample_rate_hz": rate,
        "accel_units": "counts",
        "gyro_units": "counts",
        "offset_binary": True,
    }
    log.info("imu_tk: %d samples at %.3f Hz", acc.shape[0], rate)
    return recording_from_columns(header, t=acc[:, 0], accel=acc[:, 1:], gyro=gyro)


def _snap_rate(rate: float) -> float:
    """Round an inferred rate to 0.1 Hz (100.0 from a median interval of 9.98 ms)."""
    return float(np.round(rate, 1))


def read_imucal(
    csv_path: _PathLike, sections_path: _PathLike | None, sample_rate_hz: float | None
) -> Recording:
    """Read imucal's session CSV and section JSON (module doc)."""
    if sample_rate_hz is None or not np.isfinite(sample_rate_hz) or sample_rate_hz <= 0:
        raise InputError(
            f"{csv_path}: an imucal CSV has no time column; give sample_rate_hz",
            options=("sample_rate_hz",),
        )
    first = _head(csv_path, 1024).splitlines()[0] if _head(csv_path, 1024) else ""
    names = tuple(c.strip() for c in first.split(","))
    if names != IMUCAL_COLUMNS:
        raise InputError(f"{csv_path}: expected columns {','.join(IMUCAL_COLUMNS)}")
    require_memory(str(csv_path), os.stat(csv_path).st_size)
    try:
        data = np.loadtxt(
            csv_path, delimiter=",", skiprows=1, dtype=float, ndmin=2, encoding="utf-8-sig"
        )
    except ValueError as exc:
        raise InputError(f"{csv_path}: not a table of numbers ({exc})") from None
    except MemoryError:
        raise InputError(
            f"{csv_path}: not enough memory to read it; split the file or record shorter stretches"
        ) from None
    n = data[:, 0].astype(np.int64)
    position = np.full(n.size, -1, dtype=np.int64)
    angles = np.full((n.size, 3), np.nan)
    sections = _sections(sections_path) if sections_path is not None else []
    static = [sec for sec in sections if not sec[0].endswith("_rot")]
    for label, (name, start, end) in enumerate(static):
        rows = (n >= start) & (n < end)
        position[rows] = label
        angles[rows] = FERRARIS_POSES.get(name, (np.nan, np.nan, np.nan))
    turns = tuple(
        turn for sec in sections if sec[0].endswith("_rot") if (turn := _turn(sec, n)) is not None
    )
    header: dict[str, HeaderValue] = {
        "sample_rate_hz": float(sample_rate_hz),
        "accel_units": "m/s^2",
        "gyro_units": "deg/s",
        "accel_lsb": 1.0,
        "gyro_lsb": float(np.pi / 180.0),
    }
    recording = recording_from_columns(
        header,
        t=n / float(sample_rate_hz),
        accel=data[:, 4:7],
        gyro=data[:, 1:4],
        position=position,
        alpha_deg=angles[:, 0],
        beta_deg=angles[:, 1],
        psi_deg=angles[:, 2],
    )
    return dataclasses.replace(recording, turns=turns)


IMUCAL_TURN_DEG = -360.0
"""The angle of imucal's ``*_rot`` sections (its ``expected_angle`` default)."""


def _turn(section: tuple[str, int, int], n: NDArray[np.int64]) -> KnownTurn | None:
    """Return the known turn of an ``x_rot``/``y_rot``/``z_rot`` section (rows by index)."""
    name, start, end = section
    axis = "xyz".find(name[:1])
    rows = np.flatnonzero((n >= start) & (n < end))
    if axis < 0 or name != f"{name[:1]}_rot" or rows.size < 2:
        log.warning("imucal: section %r is not a turn about x, y or z; ignored", name)
        return None
    return KnownTurn(name, int(rows[0]), int(rows[-1]) + 1, axis, IMUCAL_TURN_DEG)


def _sections(path: _PathLike) -> list[tuple[str, int, int]]:
    """``(name, start, end)`` of each section of an imucal section JSON, in file order."""
    doc = parse_json(read_text(path), f"{path}: imucal section list")
    if not isinstance(doc, dict):
        raise InputError(f"{path}: expected an object of sections")
    out = []
    for name, sec in doc.items():
        if not (isinstance(sec, dict) and isinstance(sec.get("start"), int)):
            raise InputError(f"{path}: section {name!r} needs integer 'start' and 'end'")
        if not isinstance(sec.get("end"), int) or sec["end"] <= sec["start"]:
            raise InputError(f"{path}: section {name!r} needs an integer 'end' after 'start'")
        out.append((str(name), int(sec["start"]), int(sec["end"])))
    return out
