"""The IMU node's object dictionary (docs/design.md §4): calibration block, CRC, ranges, firmware.

Derived from the object table, :mod:`canimucal.device.objects` (every object's type, range
rule, unit, default and CRC order are defined there). Pure data and numerics: nothing here
talks to a bus, so the client, the simulated node and the tests share one definition of what
each object holds and how it is checked: the simulated node refuses an out-of-range SDO
write with it, the client checks a whole block with it before writing. Units: biases in
counts, M in m/s² per count, N in rad/s per count, G in counts per m/s², base tilt and
mounting trim in radians, calibration temperature in °C, fit rms in m/s². A node without the
mounting-trim object 0x2122 (a firmware before it) has the 39-object CRC layout; its block
holds no trim (``mounting_trim_rad`` None).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from canimucal.device.objects import (  # noqa: F401  (the indices, as od.X for every user)
    ACCEL_BIAS,
    ACCEL_CORRECTION,
    ACCEL_RAW,
    BACKUP_EXTRAS,
    BASE_TILT,
    CAL_CRC_SUB,
    CAL_INFO,
    CAL_PLAN_SUB,
    CAL_RMS_SUB,
    CAL_TEMP_SUB,
    CAL_TIME_SUB,
    CAL_VALID_SUB,
    CALIBRATION_STORE_SUB,
    COMM_CYCLE_PERIOD,
    CRC_OBJECTS,
    DEVICE_NAME,
    DEVICE_TYPE,
    ERROR_REGISTER,
    GYRO_BIAS,
    GYRO_CORRECTION,
    GYRO_G,
    GYRO_RAW,
    HARDWARE_VERSION,
    HEARTBEAT,
    IDENTITY,
    LEGACY_CRC_OBJECTS,
    MOUNTING_TRIM,
    NOMINAL,
    OBJECTS,
    RESTORE,
    SAMPLE_INFO,
    SOFTWARE_VERSION,
    STORE,
    TPDO_COMM,
    TPDO_MAP,
    TRIM_KEYS,
    Nominal,
    RangeContext,
    block_crc,
    crc_objects,
    decode,
    encode,
    format_key,
    has_trim,
    object_at,
    row_diagonal_key,
    row_diagonal_sub,
)
from canimucal.errors import InputError
from canimucal.model.frames import trim_dcm

STORE_ALL_SUB = 1
STORE_COMM_SUB = 2
STORE_APP_SUB = 3
STORE_CALIBRATION_SUB = 4

SAVE_SIGNATURE = 0x65766173  # 'save' as little-endian U32 (CiA 301 0x1010)
LOAD_SIGNATURE = 0x64616F6C  # 'load' as little-endian U32 (CiA 301 0x1011)

STATUS_SATURATED = 0x01  # 0x2002:03 bit 0: a sample of the last period saturated
STATUS_MOVING = 0x02  # 0x2002:03 bit 1: the unit is moving between poses
STATUS_CAL_ACTIVE = 0x04  # 0x2002:03 bit 2: valid = 1 and the CRC matches

CRC_ORDER: tuple[tuple[int, int, str], ...] = tuple(
    (o.index, o.sub, o.data_type) for o in CRC_OBJECTS
)
"""The objects the CRC covers, in CRC order, with their encoding code (docs/design.md §4)."""

CALIBRATION_OBJECTS: tuple[tuple[int, int, str], ...] = CRC_ORDER + tuple(
    (o.index, o.sub, o.data_type) for o in OBJECTS if o.key in BACKUP_EXTRAS
)
"""Everything a backup holds: the CRC set plus the valid flag and the CRC itself (a node
without 0x2122 holds all but the trim's three)."""


def crc_order(trim: bool) -> tuple[tuple[int, int, str], ...]:
    """:data:`CRC_ORDER` of the 42-object layout (``trim``) or of the 39-object one."""
    return tuple((o.index, o.sub, o.data_type) for o in crc_objects(trim))


def calibration_objects(trim: bool) -> tuple[tuple[int, int, str], ...]:
    """:data:`CALIBRATION_OBJECTS` of a node with the mounting trim (``trim``) or without."""
    return tuple(entry for entry in CALIBRATION_OBJECTS if trim or entry[:2] not in TRIM_KEYS)


OBJECT_CODES: dict[tuple[int, int], str] = {(i, s): c for i, s, c in CALIBRATION_OBJECTS}
"""Encoding code of each calibration object, keyed by ``(index, sub)``."""

ABORT_VALUE_RANGE = 0x06090030
ABORT_NO_OBJECT = 0x06020000
ABORT_NO_SUBINDEX = 0x06090011
ABORT_CANNOT_STORE = 0x08000020


def eds_path() -> Path:
    """Path of ``canimucal_imu.eds``: packaged data if installed so, else ``<repo>/eds``."""
    package_root = Path(__file__).resolve().parent.parent
    packaged = package_root / "data" / "canimucal_imu.eds"
    if packaged.is_file():
        return packaged
    return package_root.parent / "eds" / "canimucal_imu.eds"


def parse_key(key: str) -> tuple[int, int]:
    """Inverse of :func:`format_key` (case-insensitive, hex sub-index)."""
    try:
        index_text, sub_text = key.split(":")
        return int(index_text, 16), int(sub_text, 16)
    except ValueError as exc:
        raise InputError(f"bad object key {key!r}, expected like '0x2100:01'") from exc


def to_float32(value: float) -> float:
    """``value`` rounded to the nearest REAL32, as a Python float."""
    return float(np.float32(value))


@dataclass(frozen=True)
class CalibrationBlock:
    """Everything 0x2100–0x2122 holds, in device units (see the module docstring).

    ``accel_correction`` is M = K⁻¹ and ``gyro_correction`` N = S⁻¹ (both row-major on the
    device); ``plan_code`` is a plan's device code in the plan registry (0 = none, factory);
    ``mounting_trim_rad`` the alignment rotation's ``(alpha, beta, psi)``, None on a node
    without 0x2122 (the 39-object CRC layout).
    """

    accel_bias: NDArray[np.float64]
    accel_correction: NDArray[np.float64]
    gyro_bias: NDArray[np.float64]
    gyro_correction: NDArray[np.float64]
    gyro_g: NDArray[np.float64]
    base_tilt_rad: NDArray[np.float64]
    time_unix_s: int = 0
    plan_code: int = 0
    temp_c: float = 0.0
    rms_ms2: float = 0.0
    mounting_trim_rad: NDArray[np.float64] | None = field(default_factory=lambda: np.zeros(3))

    @property
    def trim(self) -> bool:
        """Whether the block is of the 42-object layout (it holds the mounting trim)."""
        return self.mounting_trim_rad is not None

    def to_objects(self) -> dict[tuple[int, int], float | int]:
        """Return the CRC objects' values in CRC order, REAL32 values rounded to float32."""
        objects = crc_objects(self.trim)
        flat = {
            name: np.asarray(getattr(self, name), dtype=float).reshape(-1)
            for name in dict.fromkeys(o.block_field for o in objects if o.block_field)
        }
        used = dict.fromkeys(flat, 0)
        out: dict[tuple[int, int], float | int] = {}
        for obj in objects:
            name = str(obj.block_field)
            value = float(flat[name][used[name]])
            used[name] += 1
            out[obj.key] = to_float32(value) if obj.data_type == "f32" else int(value)
        return out

    @classmethod
    def from_objects(cls, objects: Mapping[tuple[int, int], float | int]) -> CalibrationBlock:
        """Build a block from ``(index, sub) -> value`` (at least the CRC objects).

        Without the trim's three objects: a block of the 39-object layout.
        """
        layout = crc_objects(has_trim(objects))
        missing = [format_key(*o.key) for o in layout if o.key not in objects]
        if missing:
            raise InputError(f"calibration objects missing: {', '.join(missing)}")
        fields: dict[str, list[float | int]] = {}
        for obj in layout:
            value = objects[obj.key]
            fields.setdefault(str(obj.block_field), []).append(
                float(value) if obj.data_type == "f32" else int(value)
            )
        shaped = {name: _shaped(values) for name, values in fields.items()}
        return cls(**shaped) if layout is CRC_OBJECTS else cls(**shaped, mounting_trim_rad=None)


def _shaped(values: list[float | int]) -> Any:
    """One value as itself, nine as a 3×3 matrix, others as a vector."""
    if len(values) == 1:
        return values[0]
    array = np.array(values, dtype=float)
    return array.reshape(3, 3) if array.size == 9 else array


def factory_block(accel_lsb: float, gyro_lsb: float, trim: bool = True) -> CalibrationBlock:
    """Return the factory defaults (§4): the objects' defaults for these nominal LSBs.

    ``trim`` False: the block of a node without 0x2122 (the 39-object layout).
    """
    nominal = Nominal(accel_lsb, gyro_lsb)
    defaults = {o.key: o.default_value(nominal) for o in crc_objects(trim)}
    return CalibrationBlock.from_objects(defaults)  # type: ignore[arg-type]


def apply_firmware(
    block: CalibrationBlock,
    valid: bool,
    crc_ok: bool,
    accel_counts: ArrayLike,
    gyro_counts: ArrayLike,
    accel_lsb: float,
    gyro_lsb: float,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Corrected outputs (m/s², rad/s) as the firmware computes them (docs/design.md §4).

    With valid = 1 and a matching CRC: ``a = M (U − b)``, ``w = N (V − B − G a)``, then,
    on a node with the mounting trim, both turned into the vehicle frame by the alignment
    rotation, ``a_v = R_mᵀ a`` and ``w_v = R_mᵀ w`` (``R_m`` unit ← vehicle, docs/method.md
    §3 eq. T1); otherwise the nominal values ``lsb · counts``. Accepts ``(3,)`` or ``(n, 3)``
    counts.
    """
    u = np.asarray(accel_counts, dtype=float)
    v = np.asarray(gyro_counts, dtype=float)
    if not (valid and crc_ok):
        return u * accel_lsb, v * gyro_lsb
    m = np.asarray(block.accel_correction, float)
    n = np.asarray(block.gyro_correction, float)
    g = np.asarray(block.gyro_g, float)
    accel = (u - block.accel_bias) @ m.T
    gyro = (v - block.gyro_bias - accel @ g.T) @ n.T
    if block.mounting_trim_rad is not None:  # R_mᵀ x as rows: x @ R_m
        align = trim_dcm(block.mounting_trim_rad)
        return accel @ align, gyro @ align
    return accel, gyro


def range_problems(
    index: int,
    sub: int,
    value: float,
    accel_lsb: float,
    gyro_lsb: float,
    row_diagonal: float | None = None,
) -> str | None:
    """Check one object's value against its rule in the object table; None if fine.

    ``row_diagonal`` is the current diagonal of the row an off-diagonal M/N entry belongs
    to; without it the nominal |LSB| stands in. An ``index:sub`` the table does not hold
    is a problem too: nothing is written unchecked.
    """
    name = format_key(index, sub)
    obj = object_at(index, sub)
    if obj is None:
        return f"{name} is not an object of the node"
    problem = obj.problem(value, RangeContext(accel_lsb, gyro_lsb, row_diagonal))
    return None if problem is None else f"{name} = {_shown(value)}: {problem}"


def _shown(value: float) -> str:
    try:
        return f"{float(value):.6g}"
    except (TypeError, ValueError):
        return repr(value)


def block_range_problems(block: CalibrationBlock, accel_lsb: float, gyro_lsb: float) -> list[str]:
    """Every range problem of a whole block (off-diagonals against the block's diagonals)."""
    objects = block.to_objects()
    problems = []
    for obj in crc_objects(block.trim):
        diagonal_key = row_diagonal_key(obj)
        row_diagonal = None if diagonal_key is None else float(objects[diagonal_key])
        problem = range_problems(*obj.key, objects[obj.key], accel_lsb, gyro_lsb, row_diagonal)
        if problem is not None:
            problems.append(problem)
    return problems
