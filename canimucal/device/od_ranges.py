"""The value ranges of DESIGN §4 that writes to the object dictionary must satisfy.

One definition for both sides: the simulated node refuses an out-of-range SDO write with it,
the client checks a whole calibration block with it before writing. Kept apart from
:mod:`canimucal.device.od`, which names the objects and encodes them.
"""

from __future__ import annotations

import math

from canimucal.device.od import (
    ACCEL_BIAS,
    ACCEL_CORRECTION,
    BASE_TILT,
    CAL_CRC_SUB,
    CAL_INFO,
    CAL_PLAN_SUB,
    CAL_RMS_SUB,
    CAL_TIME_SUB,
    CAL_VALID_SUB,
    CRC_ORDER,
    GYRO_BIAS,
    GYRO_CORRECTION,
    GYRO_G,
    NOMINAL,
    ODR_CHOICES_HZ,
    PLAN_CODES,
    CalibrationBlock,
    format_key,
)

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
    """Check one object's value against DESIGN §4's ranges; None if fine, else the reason.

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
