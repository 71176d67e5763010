"""The IMU node's objects (docs/design.md §4), one table: :data:`OBJECTS`.

Each :class:`DeviceObject` is one ``index:sub`` with its EDS entry (parameter name, data
type, access, default, PDO mapping), its unit, the rule its written values must meet, whether
the calibration CRC covers it (in the table's order) and which field of
:class:`~canimucal.device.od.CalibrationBlock` holds it. The client's checks before a write,
the simulated node's refusals, the CRC, the calibration block and the EDS test all read this
table; an object is added by adding a row, and a row cannot be written without its rule
(:data:`TYPE_RANGE` says "any value its type holds" out loud).

``eds/canimucal_imu.eds`` and its packaged copy hold the same objects
(``tests/device/test_eds.py`` checks every one both ways).
"""

from __future__ import annotations

import math
import struct
import zlib
from collections.abc import Callable, Collection, Mapping
from dataclasses import dataclass
from typing import Literal

from canimucal.errors import InputError
from canimucal.model.vocabulary.constants import COUNTER_MODULUS, INT16_SPAN, OUTPUT_DATA_RATES_HZ
from canimucal.model.vocabulary.plans import PLANS

DataType = Literal["u8", "u16", "u32", "i16", "f32", "vstr"]
Access = Literal["ro", "rw", "const"]

EDS_DATA_TYPES: Mapping[str, int] = {"i16": 0x3, "u8": 0x5, "u16": 0x6, "u32": 0x7, "f32": 0x8}
"""CiA 301 data type codes of the EDS ``DataType`` key (VISIBLE_STRING is 0x9)."""
EDS_DATA_TYPES = {**EDS_DATA_TYPES, "vstr": 0x9}

_INTEGER_SPAN: Mapping[str, tuple[int, int]] = {
    "u8": (0, 0xFF),
    "u16": (0, 0xFFFF),
    "u32": (0, 0xFFFFFFFF),
    "i16": (-0x8000, 0x7FFF),
}

DEVICE_TYPE = 0x1000
ERROR_REGISTER = 0x1001
SYNC_COB_ID = 0x1005
COMM_CYCLE_PERIOD = 0x1006
DEVICE_NAME = 0x1008
HARDWARE_VERSION = 0x1009
SOFTWARE_VERSION = 0x100A
STORE = 0x1010
RESTORE = 0x1011
EMCY_COB_ID = 0x1014
HEARTBEAT = 0x1017
IDENTITY = 0x1018
TPDO_COMM = (0x1800, 0x1801, 0x1802)
TPDO_MAP = (0x1A00, 0x1A01, 0x1A02)

ACCEL_RAW = 0x2000
GYRO_RAW = 0x2001
SAMPLE_INFO = 0x2002  # sub 1 temperature (0.01 °C), 2 counter, 3 status
NOMINAL = 0x2010  # sub 1 accel LSB, 2 gyro LSB (REAL32, signed), 3 output data rate Hz
CALIBRATION_STORE_SUB = 0x2011  # the 0x1010/0x1011 sub-index that saves the calibration block

ACCEL_BIAS = 0x2100
ACCEL_CORRECTION = 0x2101
GYRO_BIAS = 0x2110
GYRO_CORRECTION = 0x2111
GYRO_G = 0x2112
BASE_TILT = 0x2120
CAL_INFO = 0x2121  # subs: 1 time, 2 plan code, 3 temp °C, 4 rms, 5 valid, 6 crc
MOUNTING_TRIM = 0x2122  # subs 1–3: alpha, beta, psi (rad); absent on a 39-object firmware

CAL_TIME_SUB = 1
CAL_PLAN_SUB = 2
CAL_TEMP_SUB = 3
CAL_RMS_SUB = 4
CAL_VALID_SUB = 5
CAL_CRC_SUB = 6


@dataclass(frozen=True)
class Nominal:
    """What a rule or a default may depend on: the node's nominal LSBs (0x2010:01/02)."""

    accel_lsb: float
    gyro_lsb: float


@dataclass(frozen=True)
class RangeContext(Nominal):
    """A rule's inputs: the nominal LSBs and, for an off-diagonal M/N entry, its row's diagonal.

    ``row_diagonal`` None: the nominal |LSB| stands in.
    """

    row_diagonal: float | None = None


class RangeRule:
    """What a written value must meet beyond its data type; :meth:`problem` says why not."""

    def problem(self, value: float, ctx: RangeContext) -> str | None:
        """Return None when ``value`` is fine, else the reason (without the object's key)."""
        return None


class TypeRange(RangeRule):
    """Any value the object's data type holds (and, for REAL32, finite)."""


TYPE_RANGE = TypeRange()
"""The rule of an object whose every value (of its type) is valid."""


@dataclass(frozen=True)
class Magnitude(RangeRule):
    """``|value| ≤ limit`` (in ``unit``)."""

    limit: float
    unit: str

    def problem(self, value: float, ctx: RangeContext) -> str | None:
        """Refuse a magnitude above the limit."""
        if abs(value) > self.limit:
            return f"|value| must be ≤ {self.limit:g} {self.unit}"
        return None


@dataclass(frozen=True)
class NotNegative(RangeRule):
    """``value ≥ 0``."""

    what: str

    def problem(self, value: float, ctx: RangeContext) -> str | None:
        """Refuse a negative value."""
        return f"{self.what} must not be negative" if value < 0 else None


@dataclass(frozen=True)
class OneOf(RangeRule):
    """One of the values ``choices()`` gives when the value is checked (``shown`` in words)."""

    what: str
    choices: Callable[[], Collection[float]]
    shown: str = ""

    def problem(self, value: float, ctx: RangeContext) -> str | None:
        """Refuse a value not among the choices."""
        allowed = sorted(self.choices())
        if value not in allowed:
            listed = self.shown or ", ".join(f"{c:g}" for c in allowed)
            return f"{self.what} must be one of {listed}"
        return None


DIAGONAL_TOLERANCE = 0.5
"""|diagonal| of M or N within ±50 % of the nominal |LSB|."""
OFF_DIAGONAL_RATIO = 0.2
"""|off-diagonal| of M or N at most 0.2 × |its row's diagonal|."""


@dataclass(frozen=True)
class Correction(RangeRule):
    """An entry of the correction matrix M (``accel``) or N (``gyro``), row-major subs 1–9."""

    sensor: Literal["accel", "gyro"]
    diagonal: bool

    def problem(self, value: float, ctx: RangeContext) -> str | None:
        """Diagonal: near the nominal |LSB|; off-diagonal: small against its row's diagonal."""
        lsb = abs(ctx.accel_lsb if self.sensor == "accel" else ctx.gyro_lsb)
        if self.diagonal:
            low, high = (1 - DIAGONAL_TOLERANCE) * lsb, (1 + DIAGONAL_TOLERANCE) * lsb
            if not low <= abs(value) <= high:
                return f"|diagonal| must lie in [{low:.6g}, {high:.6g}]"
            return None
        diagonal = lsb if ctx.row_diagonal is None else abs(float(ctx.row_diagonal))
        limit = OFF_DIAGONAL_RATIO * diagonal
        if abs(value) > limit:
            return f"|off-diagonal| must be ≤ {limit:.6g} ({OFF_DIAGONAL_RATIO:g} × diagonal)"
        return None


Default = int | float | str | Callable[[Nominal], float]
"""An EDS default: a value, ``$NODEID+0x180``-style text, or a function of the nominal LSBs."""


@dataclass(frozen=True)
class DeviceObject:
    """One ``index:sub`` of the node (module doc); ``sub`` 0 for a plain variable.

    ``name`` is the EDS ``ParameterName``; ``block_field`` the
    :class:`~canimucal.device.od.CalibrationBlock` field whose flattened elements the
    objects naming it hold, in table order.
    """

    index: int
    sub: int
    name: str
    data_type: DataType
    access: Access
    default: Default
    valid: RangeRule
    unit: str = ""
    pdo: bool = False
    crc: bool = False
    block_field: str | None = None

    @property
    def key(self) -> tuple[int, int]:
        """``(index, sub)``."""
        return (self.index, self.sub)

    def default_value(self, nominal: Nominal) -> int | float | str:
        """Return the default for these nominal LSBs (``$NODEID`` text is the EDS reader's)."""
        return self.default(nominal) if callable(self.default) else self.default

    def problem(self, value: float, ctx: RangeContext) -> str | None:
        """Check ``value`` against the data type and then the rule; None when fine."""
        if self.data_type == "vstr":
            return None
        number = float(value)
        if not math.isfinite(number):
            return f"must be finite, got {value!r}"
        span = _INTEGER_SPAN.get(self.data_type)
        if span is not None and not (number == int(number) and span[0] <= number <= span[1]):
            return f"must be an integer in {span[0]}..{span[1]} ({self.data_type}), got {value!r}"
        return self.valid.problem(number, ctx)


@dataclass(frozen=True)
class ObjectGroup:
    """An ARRAY or RECORD of the EDS: its index, parameter name and object type."""

    index: int
    name: str
    kind: Literal["array", "record"]


def _nominal_diagonal(sensor: str, sub: int) -> Callable[[Nominal], float]:
    def default(nominal: Nominal) -> float:
        if sub not in (1, 5, 9):
            return 0.0
        return nominal.accel_lsb if sensor == "accel" else nominal.gyro_lsb

    return default


def _xyz(index: int, what: str, data_type: DataType, unit: str) -> list[DeviceObject]:
    return [
        DeviceObject(
            index, s, f"{what} {a} ({unit})", data_type, "ro", 0, TYPE_RANGE, unit, pdo=True
        )
        for s, a in zip((1, 2, 3), "xyz", strict=True)
    ]


def _calibration_vector(
    index: int, what: str, axes: tuple[str, ...], unit: str, field: str, rule: RangeRule
) -> list[DeviceObject]:
    return [
        DeviceObject(
            index, s, f"{what} {a} ({unit})", "f32", "rw", 0.0, rule, unit, crc=True,
            block_field=field,
        )
        for s, a in enumerate(axes, start=1)
    ]  # fmt: skip


def _calibration_matrix(
    index: int, what: str, unit: str, field: str, correction: Literal["accel", "gyro"] | None
) -> list[DeviceObject]:
    out = []
    for s in range(1, 10):
        row, col = divmod(s - 1, 3)
        rule: RangeRule = G_RULE
        default: Default = 0.0
        if correction is not None:
            rule = Correction(correction, s in (1, 5, 9))
            default = _nominal_diagonal(correction, s)
        name = f"{what} {row + 1}{col + 1} ({unit})"
        out.append(
            DeviceObject(index, s, name, "f32", "rw", default, rule, unit, crc=True,
                         block_field=field)
        )  # fmt: skip
    return out


BIAS_LIMIT_COUNTS = float(INT16_SPAN)
"""|bias| a calibration may hold: the INT16 span."""
G_LIMIT = 1000.0
"""|G| a calibration may hold, counts per m/s²."""
TILT_LIMIT_RAD = 0.2
"""|base tilt| a calibration may hold."""
TRIM_LIMIT_RAD = 0.2
"""|mounting trim| angle a calibration may hold (11.5°: more is a wrong mounting map)."""
G_RULE = Magnitude(G_LIMIT, "counts per m/s²")


def _plan_codes() -> Collection[float]:
    return {0, *(entry.device_code for entry in PLANS.values())}


TRANSMISSION_TYPES = OneOf(
    "transmission type", lambda: {*range(241), 252, 253, 254, 255}, "0–240, 252–255"
)
"""CiA 301 TPDO transmission types: synchronous 0–240, RTR-only 252/253, event-driven 254/255."""


def _communication() -> list[DeviceObject]:
    rw: Access = "rw"
    ro: Access = "ro"
    u32: DataType = "u32"
    u16: DataType = "u16"
    u8: DataType = "u8"
    out = [
        DeviceObject(DEVICE_TYPE, 0, "Device type", u32, ro, 0, TYPE_RANGE),
        DeviceObject(ERROR_REGISTER, 0, "Error register", u8, ro, 0, TYPE_RANGE, pdo=True),
        DeviceObject(SYNC_COB_ID, 0, "COB-ID SYNC message", u32, rw, 0x80, TYPE_RANGE),
        DeviceObject(COMM_CYCLE_PERIOD, 0, "Communication cycle period (us)", u32, rw, 0,
                     TYPE_RANGE, "µs"),
        DeviceObject(DEVICE_NAME, 0, "Manufacturer device name", "vstr", "const",
                     "canimucal IMU", TYPE_RANGE),
        DeviceObject(HARDWARE_VERSION, 0, "Manufacturer hardware version", "vstr", "const",
                     "sim 1", TYPE_RANGE),
        DeviceObject(SOFTWARE_VERSION, 0, "Manufacturer software version", "vstr", "const",
                     "sim 1", TYPE_RANGE),
    ]  # fmt: skip
    for index, verb, what in ((STORE, "Save", "parameters"), (RESTORE, "Restore", "default")):
        parts = ("all", "communication", "application", "calibration")
        for s, part in enumerate(parts, start=1):
            name = f"{verb} {part} {what}" + (" parameters" if verb == "Restore" else "")
            out.append(DeviceObject(index, s, name, u32, rw, 1, TYPE_RANGE))
    out.append(DeviceObject(EMCY_COB_ID, 0, "COB-ID EMCY", u32, ro, "$NODEID+0x80", TYPE_RANGE))
    out.append(
        DeviceObject(HEARTBEAT, 0, "Producer heartbeat time (ms)", u16, rw, 1000, TYPE_RANGE, "ms")
    )
    identity = ("Vendor-ID", "Product code", "Revision number", "Serial number")
    for s, (name, default) in enumerate(zip(identity, (0, 0, 0x10000, 0), strict=True), start=1):
        out.append(DeviceObject(IDENTITY, s, name, u32, ro, default, TYPE_RANGE))
    for n, (index, timer_ms) in enumerate(zip(TPDO_COMM, (0, 0, 100), strict=True)):
        out += [
            DeviceObject(index, 1, "COB-ID used by TPDO", u32, rw,
                         f"$NODEID+0x{0x180 + 0x100 * n:X}", TYPE_RANGE),
            DeviceObject(index, 2, "Transmission type", u8, rw, 0xFE, TRANSMISSION_TYPES),
            DeviceObject(index, 3, "Inhibit time (100 us)", u16, rw, 0, TYPE_RANGE, "100 µs"),
            DeviceObject(index, 5, "Event timer (ms)", u16, rw, timer_ms, TYPE_RANGE, "ms"),
            DeviceObject(index, 6, "SYNC start value", u8, rw, 0, TYPE_RANGE),
        ]  # fmt: skip
    for index, mapped in zip(TPDO_MAP, _TPDO_MAPPING, strict=True):
        out.append(DeviceObject(index, 0, "Number of mapped objects", u8, rw, len(mapped),
                                TYPE_RANGE))  # fmt: skip
        for s in range(1, 9):
            default = mapped[s - 1] if s <= len(mapped) else 0
            out.append(DeviceObject(index, s, f"Mapped object {s}", u32, rw, default, TYPE_RANGE))
    return out


_TPDO_MAPPING = (
    (0x20000110, 0x20000210, 0x20000310, 0x20020210),
    (0x20010110, 0x20010210, 0x20010310, 0x20020210),
    (0x20020110, 0x20020210, 0x20020308),
)
"""Default TPDO maps: accel x/y/z + counter, gyro x/y/z + counter, temperature/counter/status."""


def _application() -> list[DeviceObject]:
    rates = " ".join(str(r) for r in OUTPUT_DATA_RATES_HZ)
    out = _xyz(ACCEL_RAW, "Accel raw", "i16", "counts") + _xyz(
        GYRO_RAW, "Gyro raw", "i16", "counts"
    )
    out += [
        DeviceObject(SAMPLE_INFO, 1, "Temperature (0.01 degC)", "i16", "ro", 2500, TYPE_RANGE,
                     "0.01 °C", pdo=True),
        DeviceObject(SAMPLE_INFO, 2, f"Sample counter (wraps at {COUNTER_MODULUS})", "u16", "ro",
                     0, TYPE_RANGE, pdo=True),
        DeviceObject(SAMPLE_INFO, 3,
                     "Status (bit0 saturated, bit1 moving, bit2 calibration active)", "u8",
                     "ro", 0, TYPE_RANGE, pdo=True),
        DeviceObject(NOMINAL, 1, "Nominal accel LSB (m/s2 per count, signed)", "f32", "ro",
                     lambda n: n.accel_lsb, TYPE_RANGE, "m/s² per count"),
        DeviceObject(NOMINAL, 2, "Nominal gyro LSB (rad/s per count, signed)", "f32", "ro",
                     lambda n: n.gyro_lsb, TYPE_RANGE, "rad/s per count"),
        DeviceObject(NOMINAL, 3, f"Output data rate (Hz: {rates})", "u16", "rw", 200,
                     OneOf("output data rate (Hz)", lambda: OUTPUT_DATA_RATES_HZ), "Hz"),
        DeviceObject(CALIBRATION_STORE_SUB, 0, "Calibration store sub-index (0x1010 and 0x1011)",
                     "u8", "ro", 4, TYPE_RANGE),
    ]  # fmt: skip
    bias = Magnitude(BIAS_LIMIT_COUNTS, "counts")
    tilt = Magnitude(TILT_LIMIT_RAD, "rad")
    out += _calibration_vector(ACCEL_BIAS, "Accel bias", ("x", "y", "z"), "counts",
                               "accel_bias", bias)  # fmt: skip
    out += _calibration_matrix(ACCEL_CORRECTION, "Accel correction M (K^-1)", "m/s2 per count",
                               "accel_correction", "accel")  # fmt: skip
    out += _calibration_vector(GYRO_BIAS, "Gyro bias", ("x", "y", "z"), "counts",
                               "gyro_bias", bias)  # fmt: skip
    out += _calibration_matrix(GYRO_CORRECTION, "Gyro correction N (S^-1)", "rad/s per count",
                               "gyro_correction", "gyro")  # fmt: skip
    out += _calibration_matrix(GYRO_G, "Gyro g-sensitivity G", "counts per m/s2", "gyro_g", None)
    out += _calibration_vector(BASE_TILT, "Base tilt", ("alpha0", "beta0"), "rad",
                               "base_tilt_rad", tilt)  # fmt: skip
    out += [
        DeviceObject(CAL_INFO, CAL_TIME_SUB, "Calibration time (Unix s)", "u32", "rw", 0,
                     TYPE_RANGE, "s", crc=True, block_field="time_unix_s"),
        DeviceObject(CAL_INFO, CAL_PLAN_SUB, "Plan code (0 none; docs/design.md section 3)",
                     "u8", "rw", 0, OneOf("plan code", _plan_codes), crc=True,
                     block_field="plan_code"),
        DeviceObject(CAL_INFO, CAL_TEMP_SUB, "Temperature at calibration (degC)", "f32", "rw",
                     0.0, TYPE_RANGE, "°C", crc=True, block_field="temp_c"),
        DeviceObject(CAL_INFO, CAL_RMS_SUB, "Fit residual rms (m/s2)", "f32", "rw", 0.0,
                     NotNegative("fit rms"), "m/s²", crc=True, block_field="rms_ms2"),
        DeviceObject(CAL_INFO, CAL_VALID_SUB, "Valid flag (0/1)", "u8", "rw", 0,
                     OneOf("valid flag", lambda: (0, 1))),
        DeviceObject(CAL_INFO, CAL_CRC_SUB, "CRC-32 of the calibration block", "u32", "rw",
                     lambda n: _factory_crc(n), TYPE_RANGE),
    ]  # fmt: skip
    out += _calibration_vector(MOUNTING_TRIM, "Mounting trim", ("alpha", "beta", "psi"), "rad",
                               "mounting_trim_rad", Magnitude(TRIM_LIMIT_RAD, "rad"))  # fmt: skip
    return out


def _factory_crc(nominal: Nominal) -> int:
    return block_crc({o.key: o.default_value(nominal) for o in OBJECTS if o.crc})  # type: ignore[misc]


def _legacy_factory_crc(nominal: Nominal) -> int:
    """Return the factory CRC of a node without 0x2122 (the 39-object layout)."""
    return block_crc(
        {o.key: o.default_value(nominal) for o in LEGACY_CRC_OBJECTS}  # type: ignore[misc]
    )


OBJECTS: tuple[DeviceObject, ...] = tuple(_communication() + _application())
"""Every object of the node in index order (module doc)."""

GROUPS: tuple[ObjectGroup, ...] = (
    ObjectGroup(STORE, "Store parameters", "array"),
    ObjectGroup(RESTORE, "Restore default parameters", "array"),
    ObjectGroup(IDENTITY, "Identity object", "record"),
    *(ObjectGroup(i, f"TPDO{n} communication parameter", "record")
      for n, i in enumerate(TPDO_COMM, start=1)),
    *(ObjectGroup(i, f"TPDO{n} mapping parameter", "record")
      for n, i in enumerate(TPDO_MAP, start=1)),
    ObjectGroup(ACCEL_RAW, "Accelerometer raw (counts)", "array"),
    ObjectGroup(GYRO_RAW, "Gyro raw (counts)", "array"),
    ObjectGroup(SAMPLE_INFO, "Sample info", "record"),
    ObjectGroup(NOMINAL, "Nominal scaling", "record"),
    ObjectGroup(ACCEL_BIAS, "Accel bias b (counts)", "array"),
    ObjectGroup(ACCEL_CORRECTION, "Accel correction M (K^-1) (m/s2 per count), row-major",
                "array"),
    ObjectGroup(GYRO_BIAS, "Gyro bias B (counts)", "array"),
    ObjectGroup(GYRO_CORRECTION, "Gyro correction N (S^-1) (rad/s per count), row-major",
                "array"),
    ObjectGroup(GYRO_G, "Gyro g-sensitivity G (counts per m/s2), row-major", "array"),
    ObjectGroup(BASE_TILT, "Base tilt (rad)", "array"),
    ObjectGroup(CAL_INFO, "Calibration info", "record"),
    ObjectGroup(MOUNTING_TRIM, "Mounting trim (rad)", "array"),
)  # fmt: skip
"""The EDS's ARRAY and RECORD objects; every other index is a plain variable (sub 0)."""

BY_KEY: Mapping[tuple[int, int], DeviceObject] = {o.key: o for o in OBJECTS}
"""Each object by ``(index, sub)``."""


CRC_OBJECTS: tuple[DeviceObject, ...] = tuple(o for o in OBJECTS if o.crc)
"""The objects the calibration CRC covers, in CRC order (the table's): 42 objects, 165 bytes."""

TRIM_KEYS: tuple[tuple[int, int], ...] = tuple(
    o.key for o in CRC_OBJECTS if o.index == MOUNTING_TRIM
)
"""The mounting trim's objects (0x2122:01–03), the last three the CRC covers."""

LEGACY_CRC_OBJECTS: tuple[DeviceObject, ...] = tuple(
    o for o in CRC_OBJECTS if o.key not in TRIM_KEYS
)
"""What the CRC covers on a node without 0x2122 (a firmware before it): 39 objects, 153
bytes, 0x2100:01 … 0x2121:04. The 42-object layout continues that CRC over the trim's 12
bytes, so its first 39 objects are these in the same order (docs/design.md §4)."""


def crc_objects(trim: bool) -> tuple[DeviceObject, ...]:
    """Return the CRC layout of a node with the mounting-trim object (``trim``) or without."""
    return CRC_OBJECTS if trim else LEGACY_CRC_OBJECTS


def has_trim(values: Collection[tuple[int, int]]) -> bool:
    """Tell whether ``values`` (keys of calibration objects) are of the 42-object layout.

    All three trim keys, or none (the 39-object layout); InputError for one or two of them.
    """
    present = [key in values for key in TRIM_KEYS]
    if any(present) and not all(present):
        missing = [format_key(*k) for k, p in zip(TRIM_KEYS, present, strict=True) if not p]
        raise InputError(f"mounting trim incomplete: {', '.join(missing)} missing")
    return all(present)


def object_at(index: int, sub: int) -> DeviceObject | None:
    """Return the object at ``index:sub``, None when the node has none there."""
    return BY_KEY.get((index, sub))


BACKUP_EXTRAS: tuple[tuple[int, int], ...] = ((CAL_INFO, CAL_VALID_SUB), (CAL_INFO, CAL_CRC_SUB))
"""What a backup holds beside the CRC objects: the valid flag and the CRC itself."""


def row_diagonal_sub(sub: int) -> int:
    """Sub-index of the diagonal element in the row of matrix sub-index ``sub`` (1..9)."""
    row = (sub - 1) // 3
    return 1 + 4 * row


def row_diagonal_key(obj: DeviceObject) -> tuple[int, int] | None:
    """Return the diagonal's key an off-diagonal M/N entry is checked against; else None."""
    rule = obj.valid
    if isinstance(rule, Correction) and not rule.diagonal:
        return (obj.index, row_diagonal_sub(obj.sub))
    return None


def format_key(index: int, sub: int) -> str:
    """``"0x2100:01"``: the key of one object in a backup's ``objects`` map."""
    return f"0x{index:04X}:{sub:02X}"


_FORMATS: Mapping[str, str] = {
    "f32": "<f", "u32": "<I", "u16": "<H", "u8": "<B", "i16": "<h", "i32": "<i",
}  # fmt: skip


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


def block_crc(values: Mapping[tuple[int, int], float | int], trim: bool | None = None) -> int:
    """CRC-32/ISO-HDLC (``zlib.crc32``, start 0) over the encodings of the CRC objects (§4).

    ``trim``: the 42-object layout (with 0x2122) or the 39-object one; None reads it from
    the keys of ``values`` (:func:`has_trim`).
    """
    crc = 0
    for obj in crc_objects(has_trim(values) if trim is None else trim):
        if obj.key not in values:
            raise InputError(f"object {format_key(*obj.key)} missing for the CRC")
        crc = zlib.crc32(encode(obj.data_type, values[obj.key]), crc)
    return crc & 0xFFFFFFFF
