"""Schema of the truth JSON's ``faults`` block (the table is in :mod:`.faults`).

Each bad key raises one :class:`~canimucal.errors.SchemaError` naming it
(``truth: faults.sdo_aborts[0].object: ...``), so ``demo --truth FILE`` exits 2 with one line.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from canimucal.device import od
from canimucal.errors import InputError, SchemaError
from canimucal.schema import fail, read_integer, read_list, read_number, read_object

DEFAULT_ABORT_CODE = 0x08000020  # data cannot be transferred or stored
_FRACTIONS = (
    "tpdo_drop_fraction",
    "duplicate_fraction",
    "delay_fraction",
    "wrong_length_fraction",
)
_COUNTS = (
    "sdo_silent_after",
    "reboot_at_sdo_request",
    "abort_at_sdo_request",
    "serial_after_reboot",
    "delay_frames",
    "reboot_before_sdo_request",
    "twin_serial",
)
_KEYS = {"seed", "burst_loss", "sdo_aborts", "sdo_silent_mode", "reboot_at_s", "emergency"}
_KEYS |= {"heartbeat_loss", "error_frames_at_s", *_FRACTIONS, *_COUNTS}
_FROM_ZERO = ("sdo_silent_after", "twin_serial", "serial_after_reboot")
_ABORT_KEYS = {"object", "code", "access", "after_writes", "at_access"}


def _integer(value: Any, key: str, low: int = 0) -> int:
    """Read an integer ≥ ``low``; a string such as ``"0x08000020"`` in its own base."""
    if isinstance(value, str):
        try:
            value = int(value, 0)
        except ValueError:
            fail(key, f"must be an integer, got {value[:40]!r}")
    return read_integer(value, key, low)


@dataclass(frozen=True)
class AbortRule:
    """Abort transfers of one object (see the module table, ``sdo_aborts``)."""

    index: int
    sub: int
    code: int = DEFAULT_ABORT_CODE
    access: str = "write"
    after_writes: int = 0
    at_access: int | None = None

    @classmethod
    def parse(cls, value: Any, key: str) -> AbortRule:
        """Validate one ``sdo_aborts`` entry."""
        d = read_object(value, key, _ABORT_KEYS)
        if "object" not in d:
            fail(f"{key}.object", "is required")
        try:
            index, sub = od.parse_key(str(d["object"]))
        except (ValueError, InputError):
            fail(f"{key}.object", f"must look like 0x2101:05, got {d['object']!r}")
        access = d.get("access", "write")
        if access not in ("write", "read", "any"):
            fail(f"{key}.access", f"must be write, read or any, got {access!r}")
        at = d.get("at_access")
        return cls(
            index,
            sub,
            _integer(d.get("code", DEFAULT_ABORT_CODE), f"{key}.code"),
            access,
            _integer(d.get("after_writes", 0), f"{key}.after_writes"),
            None if at is None else _integer(at, f"{key}.at_access", 1),
        )


@dataclass(frozen=True)
class Emergency:
    """One EMCY frame to send at simulated time ``at_s``."""

    at_s: float
    code: int
    register: int

    @classmethod
    def parse(cls, value: Any, key: str) -> Emergency:
        """Validate one ``emergency`` entry."""
        d = read_object(value, key, {"at_s", "code", "register"})
        code = _integer(d.get("code", 0x1000), f"{key}.code")
        register = _integer(d.get("register", 0x01), f"{key}.register")
        if code > 0xFFFF or register > 0xFF:
            fail(key, "code must fit 16 bits and register 8 bits")
        return cls(read_number(d.get("at_s", 0.0), f"{key}.at_s", 0.0), code, register)


@dataclass(frozen=True)
class FaultConfig:
    """The validated ``faults`` block (see the module table)."""

    seed: int = 0
    tpdo_drop_fraction: float = 0.0
    burst_probability: float = 0.0
    burst_frames: int = 0
    duplicate_fraction: float = 0.0
    delay_fraction: float = 0.0
    delay_frames: int = 3
    wrong_length_fraction: float = 0.0
    sdo_aborts: tuple[AbortRule, ...] = ()
    sdo_silent_after: int | None = None
    sdo_silent_mode: str = "request"
    reboot_at_sdo_request: int | None = None
    reboot_before_sdo_request: int | None = None
    abort_at_sdo_request: int | None = None
    reboot_at_s: float | None = None
    emergency: tuple[Emergency, ...] = ()
    heartbeat_loss: tuple[float, float] | None = None
    serial_after_reboot: int | None = None
    error_frames_at_s: tuple[float, ...] = ()
    twin_serial: int | None = None

    @property
    def touches_tpdos(self) -> bool:
        """Whether any TPDO fault is active (the fast path skips the filter otherwise)."""
        return any(
            (self.tpdo_drop_fraction, self.burst_probability, self.duplicate_fraction)
            + (self.delay_fraction, self.wrong_length_fraction)
        )


def parse_faults(doc: Any) -> FaultConfig:
    """Validate a ``faults`` block; :class:`SchemaError` names the first bad key."""
    try:
        return _parse({} if doc is None else doc)
    except SchemaError as exc:
        problem = str(exc)
        where = "faults" if problem.startswith("top level:") else "faults."
        raise SchemaError(f"truth: {where}{problem.removeprefix('top level')}") from None


def _parse(doc: Any) -> FaultConfig:
    d = read_object(doc, "", _KEYS)
    kw: dict[str, Any] = {}
    for key in _FRACTIONS:
        if key in d:
            kw[key] = read_number(d[key], key, 0.0, 1.0)
    for key in _COUNTS:
        if d.get(key) is not None:
            kw[key] = _integer(d[key], key, 0 if key in _FROM_ZERO else 1)
    if "seed" in d:
        kw["seed"] = _integer(d["seed"], "seed")
    if "burst_loss" in d:
        b = read_object(d["burst_loss"], "burst_loss", {"probability", "frames"})
        kw["burst_probability"] = read_number(
            b.get("probability", 0.0), "burst_loss.probability", 0.0, 1.0
        )
        kw["burst_frames"] = _integer(b.get("frames", 1), "burst_loss.frames", 1)
    mode = d.get("sdo_silent_mode", "request")
    if mode not in ("request", "response"):
        fail("sdo_silent_mode", f"must be request or response, got {mode!r}")
    kw["sdo_silent_mode"] = mode
    rules = read_list(d.get("sdo_aborts", []), "sdo_aborts")
    kw["sdo_aborts"] = tuple(AbortRule.parse(r, f"sdo_aborts[{i}]") for i, r in enumerate(rules))
    if d.get("reboot_at_s") is not None:
        kw["reboot_at_s"] = read_number(d["reboot_at_s"], "reboot_at_s", 0.0)
    emcy = read_list(d.get("emergency", []), "emergency")
    kw["emergency"] = tuple(Emergency.parse(e, f"emergency[{i}]") for i, e in enumerate(emcy))
    if d.get("heartbeat_loss") is not None:
        h = read_object(d["heartbeat_loss"], "heartbeat_loss", {"from_s", "until_s"})
        start = read_number(h.get("from_s", 0.0), "heartbeat_loss.from_s", 0.0)
        until = h.get("until_s")
        end = math.inf if until is None else read_number(until, "heartbeat_loss.until_s", start)
        kw["heartbeat_loss"] = (start, end)
    times = read_list(d.get("error_frames_at_s", []), "error_frames_at_s")
    kw["error_frames_at_s"] = tuple(
        read_number(t, f"error_frames_at_s[{i}]", 0.0) for i, t in enumerate(times)
    )
    return FaultConfig(**kw)
