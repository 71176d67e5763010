"""TPDO layouts and frame packing for the simulated node, read from its object dictionary.

canopen's ``LocalNode`` knows the mapping objects but sends nothing by itself; the node's
producer packs frames with :class:`TpdoLayout`, built from the *current* values of
0x1800–0x1802 and 0x1A00–0x1A02, so a client that remaps or reconfigures a TPDO sees the
node follow.
"""

from __future__ import annotations

import struct
from collections.abc import Callable, Mapping
from dataclasses import dataclass

from canimucal.device import od

ReadRaw = Callable[[int, int], bytes]

COB_ID_INVALID = 0x80000000  # bit 31 of 0x180x:01: the PDO does not exist / is disabled
TRANS_EVENT = (254, 255)  # event-driven: sent on the event timer
TRANS_SYNC_MAX = 240  # 1..240: sent every n-th SYNC (0: acyclic, on every SYNC here)

_BIT_FORMATS = {8: "B", 16: "H", 32: "I"}


@dataclass(frozen=True)
class TpdoLayout:
    """One TPDO as configured: COB-ID, transmission type, event timer and packing."""

    number: int
    cob_id: int
    enabled: bool
    trans_type: int
    event_timer_ms: int
    keys: tuple[tuple[int, int], ...]
    fmt: str

    @property
    def length(self) -> int:
        """Frame length in bytes."""
        return struct.calcsize(self.fmt)

    @property
    def on_sync(self) -> bool:
        """True when the TPDO is sent on SYNC (transmission type 0..240)."""
        return self.trans_type <= TRANS_SYNC_MAX

    @property
    def on_event(self) -> bool:
        """True when the TPDO is sent on its event timer (transmission type 254/255)."""
        return self.trans_type in TRANS_EVENT

    def pack(self, values: Mapping[tuple[int, int], int]) -> bytes:
        """Frame data for the current object values (unknown objects send 0)."""
        return struct.pack(
            self.fmt, *(_wrapped(k, values.get(k, 0), self.fmt, i) for i, k in enumerate(self.keys))
        )


def _wrapped(key: tuple[int, int], value: int, fmt: str, position: int) -> int:
    code = fmt[1 + position]
    bits = {"B": 8, "b": 8, "H": 16, "h": 16, "I": 32, "i": 32}[code]
    if code.islower():
        low, high = -(1 << (bits - 1)), (1 << (bits - 1)) - 1
        return max(low, min(high, int(value)))
    return int(value) & ((1 << bits) - 1)


def read_layout(
    number: int, read_raw: ReadRaw, is_signed: Callable[[tuple[int, int]], bool]
) -> TpdoLayout:
    """Build TPDO ``number`` (1..3) from the communication and mapping objects.

    ``is_signed(key)`` tells whether a mapped object is a signed integer (packed saturating;
    unsigned ones wrap, like the sample counter).
    """
    comm, mapping = od.TPDO_COMM[number - 1], od.TPDO_MAP[number - 1]
    cob_raw = struct.unpack("<I", read_raw(comm, 1))[0]
    trans_type = read_raw(comm, 2)[0]
    timer_ms = struct.unpack("<H", read_raw(comm, 5))[0]
    count = read_raw(mapping, 0)[0]
    keys: list[tuple[int, int]] = []
    fmt = "<"
    for sub in range(1, count + 1):
        entry = struct.unpack("<I", read_raw(mapping, sub))[0]
        key = (entry >> 16, (entry >> 8) & 0xFF)
        code = _BIT_FORMATS.get(entry & 0xFF, "")
        if not code:
            continue
        keys.append(key)
        fmt += code.lower() if is_signed(key) else code
    return TpdoLayout(
        number=number,
        cob_id=cob_raw & 0x1FFFFFFF,
        enabled=not cob_raw & COB_ID_INVALID and bool(keys),
        trans_type=trans_type,
        event_timer_ms=timer_ms,
        keys=tuple(keys),
        fmt=fmt,
    )


class EventTimer:
    """Decides, in simulated time, when an event-driven TPDO is due.

    Due times are ``anchor + k·period`` (multiplied, not summed: summing 0.001 s a few
    million times drifted by more than the tolerance and skipped one sample an hour at
    1 kHz, a loss no fault injected).
    """

    def __init__(self) -> None:
        self.anchor_s: float | None = None
        self.count = 0

    @property
    def next_due_s(self) -> float | None:
        """Simulated time the TPDO is next due (None before the first)."""
        return None if self.anchor_s is None else self.anchor_s + self.count * self._period_s

    _period_s = 0.0

    def due(self, t_s: float, period_s: float) -> bool:
        """Tell whether a TPDO with event timer ``period_s`` (0: every sample) is due at ``t_s``."""
        if period_s <= 0.0:
            return True
        if self.anchor_s is None or period_s != self._period_s:
            return self._restart(t_s, period_s)
        next_due = self.anchor_s + self.count * period_s
        if t_s - next_due > period_s:  # late by more than a period: a new schedule from now
            return self._restart(t_s, period_s)
        if t_s + 1e-9 >= next_due:
            self.count += 1
            return True
        return False

    def ticks(self, t_s: float, period_s: float, sample_period_s: float) -> list[float]:
        """Offsets after ``t_s`` of the ticks before the next sample, for a timer on its own clock.

        A timer whose period is not the sample period (``timer_skew_ppm``) ticks on its own:
        each tick in ``[t_s, t_s + sample_period_s)`` sends the sample of ``t_s`` (the newest
        one then), so a slow timer has no tick for some samples (their counters are skipped)
        and a fast one two ticks for some (the counter sent twice). Due times are
        ``anchor + k·period`` as in :meth:`due`; a timer late by more than a period starts
        again from ``t_s``.
        """
        if period_s <= 0.0:
            return [0.0]
        anchor = self.anchor_s
        offsets: list[float] = []
        late = anchor is not None and t_s - (anchor + self.count * period_s) > period_s
        if anchor is None or period_s != self._period_s or late:
            anchor = t_s
            self._restart(t_s, period_s)
            offsets.append(0.0)
        end = t_s + sample_period_s - 1e-9  # a tick on the next sample is that sample's
        while (due_s := anchor + self.count * period_s) < end:
            offsets.append(max(0.0, due_s - t_s))
            self.count += 1
        return offsets

    def _restart(self, t_s: float, period_s: float) -> bool:
        self.anchor_s, self.count, self._period_s = t_s, 1, period_s
        return True

    def reset(self) -> None:
        """Forget the schedule: the next sample is sent and starts a new one."""
        self.anchor_s = None
