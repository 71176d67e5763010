"""The calibration JSON (DESIGN §5): a frozen record, a strict reader, an atomic writer.

:class:`CalibrationRecord` mirrors the file key for key; nothing else is allowed in it (a
solver's warnings travel beside the record, not inside it). Arrays are tuples whose elements
may be ``None`` (a ``null``: "not estimated: nominal"). A key that is absent and a key that
is ``null`` mean the same and both read as ``None``; the writer omits ``None`` fields.

Units as in the file: counts, counts per m/s² (K, G), counts per rad/s (S), degrees for the
base tilt, m/s² for ``fit.rms``. The ``covariance`` block keeps the order of the solver's
parameter vector; its rows and columns of ``base_tilt.*`` are in **degrees** (the vector the
solver works with is in radians):
:func:`~canimucal.io.calibration_estimates.covariance_si` converts back.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from canimucal import schema as cs
from canimucal.errors import InputError
from canimucal.io.atomic import write_text_atomic

SCHEMA = "canimucal.calibration/1"
"""The only calibration schema this version reads and writes."""

PLANS = ("two", "five", "recommended", "custom", "scalar")
"""Allowed values of ``plan``."""

Vector = tuple[float | None, ...]
Matrix = tuple[Vector, ...]


@dataclass(frozen=True, kw_only=True)
class Tool:
    """``tool``: name and version of the program that wrote the file."""

    name: str | None = field(default=None, metadata=cs.text())
    version: str | None = field(default=None, metadata=cs.text())


@dataclass(frozen=True, kw_only=True)
class Device:
    """``device``: identity of the calibrated unit (0x1018) and its node id."""

    node_id: int | None = field(default=None, metadata=cs.integer(1, 127))
    vendor_id: int | None = field(default=None, metadata=cs.integer(0, 0xFFFFFFFF))
    product_code: int | None = field(default=None, metadata=cs.integer(0, 0xFFFFFFFF))
    revision: int | None = field(default=None, metadata=cs.integer(0, 0xFFFFFFFF))
    serial: int = field(metadata=cs.integer(0, 0xFFFFFFFF))


@dataclass(frozen=True, kw_only=True)
class Conditions:
    """``conditions``: gravity and place the calibration was made at."""

    g: float | None = field(default=None, metadata=cs.number(low=0.0, open_low=True))
    latitude_deg: float | None = field(default=None, metadata=cs.number(-90.0, 90.0))
    height_m: float | None = field(default=None, metadata=cs.number())
    heading_deg: float | None = field(default=None, metadata=cs.number())
    temp_c: float | None = field(default=None, metadata=cs.number())


@dataclass(frozen=True, kw_only=True)
class AccelBlock:
    """``accel``: bias (counts) and K (counts per m/s²) with their 1σ."""

    bias: Vector = field(metadata=cs.array((3,)))
    bias_sigma: Vector | None = field(default=None, metadata=cs.array((3,)))
    K: Matrix = field(metadata=cs.array((3, 3)))
    K_sigma: Matrix | None = field(default=None, metadata=cs.array((3, 3)))


@dataclass(frozen=True, kw_only=True)
class GyroBlock:
    """``gyro``: bias (counts), S (counts per rad/s), G (counts per m/s²) with their 1σ."""

    bias: Vector | None = field(default=None, metadata=cs.array((3,)))
    bias_sigma: Vector | None = field(default=None, metadata=cs.array((3,)))
    S: Matrix | None = field(default=None, metadata=cs.array((3, 3)))
    S_sigma: Matrix | None = field(default=None, metadata=cs.array((3, 3)))
    G: Matrix | None = field(default=None, metadata=cs.array((3, 3)))
    G_sigma: Matrix | None = field(default=None, metadata=cs.array((3, 3)))


@dataclass(frozen=True, kw_only=True)
class BaseTilt:
    """``base_tilt_deg``: the constant tilt of the base, degrees, with 1σ of both."""

    alpha0: float | None = field(default=None, metadata=cs.number())
    beta0: float | None = field(default=None, metadata=cs.number())
    sigma: Vector | None = field(default=None, metadata=cs.array((2,)))


@dataclass(frozen=True, kw_only=True)
class Covariance:
    """``covariance``: parameter order and matrix (tilt rows/columns in degrees)."""

    order: tuple[str, ...] = field(metadata=cs.names())
    matrix: tuple[tuple[float, ...], ...] = field(metadata=cs.square())


@dataclass(frozen=True, kw_only=True)
class PositionSummary:
    """One entry of ``positions``: the pose (degrees) and what was measured there."""

    alpha_deg: float | None = field(default=None, metadata=cs.number())
    beta_deg: float | None = field(default=None, metadata=cs.number())
    psi_deg: float | None = field(default=None, metadata=cs.number())
    seconds: float | None = field(default=None, metadata=cs.number(low=0.0))
    n: int | None = field(default=None, metadata=cs.integer(0, None))
    lost: int | None = field(default=None, metadata=cs.integer(0, None))
    mean_accel: Vector | None = field(default=None, metadata=cs.array((3,)))
    mean_gyro: Vector | None = field(default=None, metadata=cs.array((3,)))
    std_accel: Vector | None = field(default=None, metadata=cs.array((3,)))
    std_gyro: Vector | None = field(default=None, metadata=cs.array((3,)))
    temp_c: float | None = field(default=None, metadata=cs.number())


@dataclass(frozen=True, kw_only=True)
class Fit:
    """``fit``: residual rms after correction (m/s²) and degrees of freedom."""

    rms: float | None = field(default=None, metadata=cs.number(low=0.0))
    dof: int | None = field(default=None, metadata=cs.integer(0, None))


@dataclass(frozen=True, kw_only=True)
class RecordingRef:
    """``recording``: the recording the calibration was solved from."""

    file: str | None = field(default=None, metadata=cs.text())
    sha256: str | None = field(default=None, metadata=cs.text(pattern=r"[0-9a-f]{64}"))


@dataclass(frozen=True, kw_only=True)
class Readback:
    """``readback`` (``demo --headless``; ``write-params`` ignores it): values read back."""

    accel_bias: Vector | None = field(default=None, metadata=cs.array((3,)))
    accel_correction: Matrix | None = field(default=None, metadata=cs.array((3, 3)))
    gyro_bias: Vector | None = field(default=None, metadata=cs.array((3,)))
    gyro_correction: Matrix | None = field(default=None, metadata=cs.array((3, 3)))
    gyro_g: Matrix | None = field(default=None, metadata=cs.array((3, 3)))
    base_tilt_rad: Vector | None = field(default=None, metadata=cs.array((2,)))
    valid: int | None = field(default=None, metadata=cs.integer(0, 1))
    crc_ok: bool | None = field(default=None, metadata=cs.boolean())


@dataclass(frozen=True, kw_only=True)
class CalibrationRecord:
    """The whole calibration JSON (see the module doc for ``None`` and units)."""

    schema: str = field(default=SCHEMA, metadata=cs.text(choices=(SCHEMA,)))
    created: str | None = field(default=None, metadata=cs.timestamp())
    plan: str | None = field(default=None, metadata=cs.text(choices=PLANS))
    tool: Tool | None = field(default=None, metadata=cs.block(Tool))
    device: Device = field(metadata=cs.block(Device))
    conditions: Conditions | None = field(default=None, metadata=cs.block(Conditions))
    accel: AccelBlock = field(metadata=cs.block(AccelBlock))
    gyro: GyroBlock | None = field(default=None, metadata=cs.block(GyroBlock))
    base_tilt_deg: BaseTilt | None = field(default=None, metadata=cs.block(BaseTilt))
    covariance: Covariance | None = field(default=None, metadata=cs.block(Covariance))
    positions: tuple[PositionSummary, ...] | None = field(
        default=None, metadata=cs.block_list(PositionSummary)
    )
    fit: Fit | None = field(default=None, metadata=cs.block(Fit))
    recording: RecordingRef | None = field(default=None, metadata=cs.block(RecordingRef))
    objects: dict[str, int | float] | None = field(default=None, metadata=cs.objects())
    readback: Readback | None = field(default=None, metadata=cs.block(Readback))


# --------------------------------------------------------------------------- read / write


def read_calibration(path_or_text: str | os.PathLike[str]) -> CalibrationRecord:
    """Read and validate a calibration JSON; every problem is an :class:`InputError`.

    A :class:`~pathlib.Path` is read as a file; a ``str`` is JSON text when it starts with
    ``{`` (after blanks), a file name otherwise.
    """
    source, text = cs.load_text(path_or_text, "calibration")
    document = cs.parse_json(text, source)
    if not isinstance(document, dict):
        raise InputError(f"{source}: top level is not a JSON object")
    if document.get("schema") != SCHEMA:
        found = document.get("schema")
        raise InputError(f"{source}: schema must be {SCHEMA!r}, got {found!r}")
    try:
        record = cs.build(CalibrationRecord, document, "")
    except cs.SchemaError as exc:
        raise InputError(f"{source}: {exc}") from None
    _check_covariance(record, source)
    return record


def _check_covariance(record: CalibrationRecord, source: str) -> None:
    cov = record.covariance
    if cov is None:
        return
    if len(cov.matrix) != len(cov.order):
        n, m = len(cov.order), len(cov.matrix)
        raise InputError(f"{source}: covariance.matrix is {m}x{m}, order names {n} parameters")
    if cov.matrix:
        matrix = np.array(cov.matrix)
        scale = max(float(np.max(np.abs(np.diag(matrix)))), 1e-300)
        if np.any(np.diag(matrix) < 0) or np.max(np.abs(matrix - matrix.T)) > 1e-9 * scale:
            raise InputError(f"{source}: covariance.matrix is not a covariance (symmetric, ≥ 0)")


def calibration_to_dict(record: CalibrationRecord) -> dict[str, Any]:
    """Return the JSON object of ``record`` (``None`` fields omitted, tuples as lists)."""
    return cs.to_plain(record)


def calibration_to_json(record: CalibrationRecord) -> str:
    """Return the JSON text of ``record``: indent 2, keys in the contract's order, final newline."""
    return json.dumps(calibration_to_dict(record), indent=2, allow_nan=False) + "\n"


def write_calibration(
    path: str | os.PathLike[str], record: CalibrationRecord, *, overwrite: bool
) -> Path:
    """Validate ``record`` like a reader would, then write it atomically."""
    try:
        text = calibration_to_json(record)
    except ValueError as exc:  # json refuses NaN/inf: name it like the reader would
        raise InputError(f"{path}: calibration holds a non-finite number ({exc})") from exc
    read_calibration(text)
    return write_text_atomic(path, text, overwrite=overwrite)


def sha256_of(path: str | os.PathLike[str]) -> str:
    """Hex SHA-256 of a file's bytes (for ``recording.sha256``)."""
    return cs.sha256_of(path)


def as_array(value: Vector | Matrix | None, shape: tuple[int, ...]) -> NDArray[np.float64]:
    """Return a record array as numpy, NaN for ``null`` entries (all NaN when ``value`` is None)."""
    if value is None:
        return np.full(shape, np.nan)
    out = np.array(value, dtype=float)  # None elements become NaN
    return out.reshape(shape)
