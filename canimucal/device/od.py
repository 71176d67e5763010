"""The IMU node's object dictionary (docs/design.md §4): names, encodings, CRC, ranges, firmware.

Pure data and numerics: nothing here talks to a bus, so the client, the simulated node, the
file layer and the tests share one definition of what each object holds and how it is
checked, and one definition of the value ranges: the simulated node refuses an out-of-range
SDO write with them, the client checks a whole block with them before writing. Units: biases in
counts, M in m/s² per count, N in rad/s per count, G in counts per m/s², base tilt in
radians, calibration temperature in °C, fit rms in m/s².
"""

from __future__ import annotations

import math
import struct
import zlib
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from canimucal.errors import InputError

DEVICE_TYPE = 0x1000
ERROR_REGISTER = 0x1001
DEVICE_NAME = 0x1008
HARDWARE_VERSION = 0x1009
SOFTWARE_VERSION = 0x100A
STORE = 0x1010
RESTORE = 0x1011
HEARTBEAT = 0x1017
IDENTITY = 0x1018
TPDO_COMM = (0x1800, 0x1801, 0x1802)
TPDO_MAP = (0x1A00, 0x1A01, 0x1A02)

ACCEL_RAW = 0x2000
GYRO_RAW = 0x2001
SAMPLE_INFO = 0x2002  # sub 1 temperature (0.01 °C), 2 counter, 3 status
NOMINAL = 0x2010  # sub 1 accel LSB, 2 gyro LSB (REAL32, signed), 3 output data rate Hz

ACCEL_BIAS = 0x2100
ACCEL_CORRECTION = 0x2101
GYRO_BIAS = 0x2110
GYRO_CORRECTION = 0x2111
GYRO_G = 0x2112
BASE_TILT = 0x2120
CAL_INFO = 0x2121  # subs: 1 time, 2 plan code, 3 temp °C, 4 rms, 5 valid, 6 crc

CAL_TIME_SUB = 1
CAL_PLAN_SUB = 2
CAL_TEMP_SUB = 3
CAL_RMS_SUB = 4
CAL_VALID_SUB = 5
CAL_CRC_SUB = 6

STORE_ALL_SUB = 1
STORE_COMM_SUB = 2
STORE_APP_SUB = 3
STORE_CALIBRATION_SUB = 4

SAVE_SIGNATURE = 0x65766173  # 'save' as little-endian U32 (CiA 301 0x1010)
LOAD_SIGNATURE = 0x64616F6C  # 'load' as little-endian U32 (CiA 301 0x1011)

PLAN_CODES = {"two": 1, "five": 2, "recommended": 3, "custom": 4, "scalar": 5, "vehicle": 6}
ODR_CHOICES_HZ = (50, 100, 200, 250, 500, 1000)

STATUS_SATURATED = 0x01  # 0x2002:03 bit 0: a sample of the last period saturated
STATUS_MOVING = 0x02  # 0x2002:03 bit 1: the unit is moving between poses
STATUS_CAL_ACTIVE = 0x04  # 0x2002:03 bit 2: valid = 1 and the CRC matches

_FORMATS = {"f32": "<f", "u32": "<I", "u16": "<H", "u8": "<B", "i16": "<h", "i32": "<i"}


def _matrix_subs(index: int) -> tuple[tuple[int, int, str], ...]:
    return tuple((index, sub, "f32") for sub in range(1, 10))


def _vector_subs(index: int, count: int) -> tuple[tuple[int, int, str], ...]:
    return tuple((index, sub, "f32") for sub in range(1, count + 1))


CRC_ORDER: tuple[tuple[int, int, str], ...] = (
    _vector_subs(ACCEL_BIAS, 3)
    + _matrix_subs(ACCEL_CORRECTION)
    + _vector_subs(GYRO_BIAS, 3)
    + _matrix_subs(GYRO_CORRECTION)
    + _matrix_subs(GYRO_G)
    + _vector_subs(BASE_TILT, 2)
    + (
        (CAL_INFO, CAL_TIME_SUB, "u32"),
        (CAL_INFO, CAL_PLAN_SUB, "u8"),
        (CAL_INFO, CAL_TEMP_SUB, "f32"),
        (CAL_INFO, CAL_RMS_SUB, "f32"),
    )
)
"""The objects the CRC covers, in CRC order, with their encoding code (docs/design.md §4)."""

CALIBRATION_OBJECTS: tuple[tuple[int, int, str], ...] = CRC_ORDER + (
    (CAL_INFO, CAL_VALID_SUB, "u8"),
    (CAL_INFO, CAL_CRC_SUB, "u32"),
)
"""Everything a backup holds: the CRC set plus the valid flag and the CRC itself."""

OBJECT_CODES: dict[tuple[int, int], str] = {(i, s): c for i, s, c in CALIBRATION_OBJECTS}
"""Encoding code of each calibration object, keyed by ``(index, sub)``."""

ABORT_VALUE_RANGE = 0x06090030
ABORT_READ_ONLY = 0x06010002
ABORT_NO_OBJECT = 0x06020000
ABORT_NO_SUBINDEX = 0x06090011
ABORT_CANNOT_STORE = 0x08000020
ABORT_TIMEOUT = 0x05040000


def eds_path() -> Path:
    """Path of ``canimucal_imu.eds``: packaged data if installed so, else ``<repo>/eds``."""
    package_root = Path(__file__).resolve().parent.parent
    packaged = package_root / "data" / "canimucal_imu.eds"
    if packaged.is_file():
        return packaged
    return package_root.parent / "eds" / "canimucal_imu.eds"


def format_key(index: int, sub: int) -> str:
    """``"0x2100:01"``: the key of one object in a backup's ``objects`` map."""
    return f"0x{index:04X}:{sub:02X}"


def parse_key(key: str) -> tuple[int, int]:
    """Inverse of :func:`format_key` (case-insensitive, hex sub-index)."""
    try:
        index_text, sub_text = key.split(":")
        return int(index_text, 16), int(sub_text, 16)
    except ValueError as exc:
        raise InputError(f"bad object key {key!r}, expected like '0x2100:01'") from exc


def encode(code: str, value: float | int) -> bytes:
    """Little-endian SDO encoding of ``value`` as ``code`` (``f32``, ``u32``, ``u8``, ...)."""
    fmt = _format_of(code)
    if code == "f32":
        return struct.pack(fmt, float(value))
    try:
        return struct.pack(fmt, int(value))
    except struct.error as exc:
        raise InputError(f"value {value!r} does not fit {code}") from exc


def decode(code: str, data: bytes) -> float | int:
    """Inverse of :func:`encode`; REAL32 decodes to a Python float, integers to int."""
    fmt = _format_of(code)
    if len(data) != struct.calcsize(fmt):
        raise InputError(f"{code} needs {struct.calcsize(fmt)} bytes, got {len(data)}")
    value = struct.unpack(fmt, data)[0]
    return float(value) if code == "f32" else int(value)


def _format_of(code: str) -> str:
    try:
        return _FORMATS[code]
    except KeyError:
        raise InputError(f"unknown encoding code {code!r}") from None


def to_float32(value: float) -> float:
    """``value`` rounded to the nearest REAL32, as a Python float."""
    return float(np.float32(value))


def block_crc(values: Mapping[tuple[int, int], float | int]) -> int:
    """CRC-32/ISO-HDLC (``zlib.crc32``, start 0) over the encodings of CRC_ORDER (§4)."""
    crc = 0
    for index, sub, code in CRC_ORDER:
        if (index, sub) not in values:
            raise InputError(f"object {format_key(index, sub)} missing for the CRC")
        crc = zlib.crc32(encode(code, values[(index, sub)]), crc)
    return crc & 0xFFFFFFFF


@dataclass(frozen=True)
class CalibrationBlock:
    """Everything 0x2100–0x2121:04 holds, in device units (see the module docstring).

    ``accel_correction`` is M = K⁻¹ and ``gyro_correction`` N = S⁻¹ (both row-major on the
    device); ``plan_code`` is one of :data:`PLAN_CODES` (0 = none, factory).
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

    def to_objects(self) -> dict[tuple[int, int], float | int]:
        """Return the CRC_ORDER entries, REAL32 values rounded to float32."""
        floats = np.concatenate(
            [
                np.asarray(self.accel_bias, float).reshape(3),
                np.asarray(self.accel_correction, float).reshape(9),
                np.asarray(self.gyro_bias, float).reshape(3),
                np.asarray(self.gyro_correction, float).reshape(9),
                np.asarray(self.gyro_g, float).reshape(9),
                np.asarray(self.base_tilt_rad, float).reshape(2),
                [self.temp_c, self.rms_ms2],
            ]
        )
        f32_keys = [(i, s) for i, s, c in CRC_ORDER if c == "f32"]
        objects: dict[tuple[int, int], float | int] = {
            key: to_float32(v) for key, v in zip(f32_keys, floats, strict=True)
        }
        objects[(CAL_INFO, CAL_TIME_SUB)] = int(self.time_unix_s)
        objects[(CAL_INFO, CAL_PLAN_SUB)] = int(self.plan_code)
        return {(i, s): objects[(i, s)] for i, s, _ in CRC_ORDER}

    @classmethod
    def from_objects(cls, objects: Mapping[tuple[int, int], float | int]) -> CalibrationBlock:
        """Build a block from ``(index, sub) -> value`` (at least the CRC_ORDER entries)."""
        missing = [format_key(i, s) for i, s, _ in CRC_ORDER if (i, s) not in objects]
        if missing:
            raise InputError(f"calibration objects missing: {', '.join(missing)}")

        def vec(index: int, count: int) -> NDArray[np.float64]:
            return np.array([float(objects[(index, s)]) for s in range(1, count + 1)])

        return cls(
            accel_bias=vec(ACCEL_BIAS, 3),
            accel_correction=vec(ACCEL_CORRECTION, 9).reshape(3, 3),
            gyro_bias=vec(GYRO_BIAS, 3),
            gyro_correction=vec(GYRO_CORRECTION, 9).reshape(3, 3),
            gyro_g=vec(GYRO_G, 9).reshape(3, 3),
            base_tilt_rad=vec(BASE_TILT, 2),
            time_unix_s=int(objects[(CAL_INFO, CAL_TIME_SUB)]),
            plan_code=int(objects[(CAL_INFO, CAL_PLAN_SUB)]),
            temp_c=float(objects[(CAL_INFO, CAL_TEMP_SUB)]),
            rms_ms2=float(objects[(CAL_INFO, CAL_RMS_SUB)]),
        )


def factory_block(accel_lsb: float, gyro_lsb: float) -> CalibrationBlock:
    """Return the factory defaults (§4): zero biases, M and N = diag(LSB), G = 0."""
    return CalibrationBlock(
        accel_bias=np.zeros(3),
        accel_correction=np.eye(3) * accel_lsb,
        gyro_bias=np.zeros(3),
        gyro_correction=np.eye(3) * gyro_lsb,
        gyro_g=np.zeros((3, 3)),
        base_tilt_rad=np.zeros(2),
    )


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

    With valid = 1 and a matching CRC: ``a = M (U − b)``, ``w = N (V − B − G a)``;
    otherwise the nominal values ``lsb · counts``. Accepts ``(3,)`` or ``(n, 3)`` counts.
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
    return accel, gyro


BIAS_LIMIT_COUNTS = 65536.0
DIAGONAL_TOLERANCE = 0.5  # |diagonal| within ±50 % of the nominal |LSB|
OFF_DIAGONAL_RATIO = 0.2  # |off-diagonal| ≤ 0.2 |row diagonal|
G_LIMIT = 1000.0  # counts per m/s²
TILT_LIMIT_RAD = 0.2


def is_diagonal_sub(sub: int) -> bool:
    """Tell whether ``sub`` is a diagonal (1, 5, 9) of a row-major 3×3 matrix object."""
    return sub in (1, 5, 9)


def row_diagonal_sub(sub: int) -> int:
    """Sub-index of the diagonal element in the row of matrix sub-index ``sub`` (1..9)."""
    row = (sub - 1) // 3
    return 1 + 4 * row


def range_problems(
    index: int,
    sub: int,
    value: float,
    accel_lsb: float,
    gyro_lsb: float,
    row_diagonal: float | None = None,
) -> str | None:
    """Check one object's value against docs/design.md §4's ranges; None if fine, else the reason.

    ``row_diagonal`` is the current diagonal of the row an off-diagonal M/N entry belongs
    to; without it the nominal |LSB| stands in.
    """
    name = format_key(index, sub)
    number = float(value)
    if not math.isfinite(number):
        return f"{name} must be finite, got {value!r}"
    if index in (ACCEL_CORRECTION, GYRO_CORRECTION):
        lsb = accel_lsb if index == ACCEL_CORRECTION else gyro_lsb
        return _matrix_problem(name, sub, number, lsb, row_diagonal)
    return _scalar_problem(index, sub, name, number)


def _matrix_problem(
    name: str, sub: int, value: float, lsb: float, row_diagonal: float | None
) -> str | None:
    if is_diagonal_sub(sub):
        low, high = (1 - DIAGONAL_TOLERANCE) * abs(lsb), (1 + DIAGONAL_TOLERANCE) * abs(lsb)
        if not low <= abs(value) <= high:
            return f"{name} = {value:.6g}: |diagonal| must lie in [{low:.6g}, {high:.6g}]"
        return None
    diagonal = abs(lsb) if row_diagonal is None else abs(float(row_diagonal))
    limit = OFF_DIAGONAL_RATIO * diagonal
    if abs(value) > limit:
        return f"{name} = {value:.6g}: |off-diagonal| must be ≤ {limit:.6g} (0.2 × diagonal)"
    return None


def _scalar_problem(index: int, sub: int, name: str, value: float) -> str | None:
    limits: dict[int, tuple[float, str]] = {
        ACCEL_BIAS: (BIAS_LIMIT_COUNTS, "counts"),
        GYRO_BIAS: (BIAS_LIMIT_COUNTS, "counts"),
        GYRO_G: (G_LIMIT, "counts per m/s²"),
        BASE_TILT: (TILT_LIMIT_RAD, "rad"),
    }
    if index in limits:
        limit, unit = limits[index]
        if abs(value) > limit:
            return f"{name} = {value:.6g}: |value| must be ≤ {limit:g} {unit}"
        return None
    if index == CAL_INFO:
        return _cal_info_problem(sub, name, value)
    if index == NOMINAL and sub == 3 and int(value) not in ODR_CHOICES_HZ:
        return f"{name} = {value:g}: output data rate must be one of {ODR_CHOICES_HZ} Hz"
    return None


def _cal_info_problem(sub: int, name: str, value: float) -> str | None:
    integral = value == int(value)
    if sub in (CAL_TIME_SUB, CAL_CRC_SUB) and not (integral and 0 <= value <= 0xFFFFFFFF):
        return f"{name} = {value:g}: must be an unsigned 32-bit integer"
    if sub == CAL_PLAN_SUB and not (integral and 0 <= value <= max(PLAN_CODES.values())):
        return f"{name} = {value:g}: plan code must be 0..{max(PLAN_CODES.values())}"
    if sub == CAL_RMS_SUB and value < 0:
        return f"{name} = {value:g}: fit rms must not be negative"
    if sub == CAL_VALID_SUB and value not in (0, 1):
        return f"{name} = {value:g}: valid flag must be 0 or 1"
    return None


def block_range_problems(block: CalibrationBlock, accel_lsb: float, gyro_lsb: float) -> list[str]:
    """Every range problem of a whole block (off-diagonals against the block's diagonals)."""
    objects = block.to_objects()
    problems = []
    for index, sub, _ in CRC_ORDER:
        row_diagonal = None
        if index in (ACCEL_CORRECTION, GYRO_CORRECTION) and not is_diagonal_sub(sub):
            row_diagonal = float(objects[(index, row_diagonal_sub(sub))])
        problem = range_problems(
            index, sub, objects[(index, sub)], accel_lsb, gyro_lsb, row_diagonal
        )
        if problem is not None:
            problems.append(problem)
    return problems
