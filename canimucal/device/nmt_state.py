"""The NMT state a node was found in, so the tool can leave it as found (docs/design.md §9).

Inferred, in this order: a heartbeat within 1.5 producer periods (0x1017) gives the state;
else TPDOs arriving mean OPERATIONAL; else SDO answers without TPDOs mean PRE-OPERATIONAL
(reported as inferred). A node whose valid TPDOs are all SYNC-driven (transmission type
0..240) and that sends no heartbeat cannot be told apart: the state is unknown, and then no
NMT command is sent at all (a SYNC-driven node may be OPERATIONAL on a bus whose SYNC
producer is simply quiet).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

from canimucal.device import od
from canimucal.errors import SdoAbort

HEARTBEAT_PERIODS = 1.5
TPDO_WINDOW_PERIODS = 3.0
MIN_TPDO_WINDOW_S = 0.3
MAX_TPDO_WINDOW_S = 2.0
NMT_COMMAND = {"OPERATIONAL": 0x01, "STOPPED": 0x02, "PRE-OPERATIONAL": 0x80}
"""The NMT command that puts a node back into each state."""

ReadU = Callable[[int, int, str], float | int]
Subscribe = Callable[[int, Callable[[int, bytearray, float], None]], None]


@dataclass(frozen=True)
class NmtFound:
    """The state a node was found in (None: unknown) and how that was known.

    ``source``: ``"heartbeat"`` (reported by the node), ``"tpdo"`` (TPDOs seen: inferred
    OPERATIONAL), ``"sdo"`` (SDO answers, no TPDOs: inferred PRE-OPERATIONAL) or
    ``"unknown"`` (SYNC-only TPDOs, no heartbeat: no NMT will be sent).
    """

    state: str | None
    source: str

    @property
    def command(self) -> int | None:
        """NMT command restoring this state (None: send nothing)."""
        return None if self.state is None else NMT_COMMAND.get(self.state)

    def describe(self) -> str:
        """``"OPERATIONAL (heartbeat)"``, ``"PRE-OPERATIONAL (inferred: ...)"``."""
        if self.state is None:
            return "unknown (TPDOs on SYNC only, no heartbeat): no NMT sent"
        how = {
            "heartbeat": "heartbeat",
            "tpdo": "inferred: TPDOs arriving",
            "sdo": "inferred: SDO answers, no TPDOs",
        }[self.source]
        return f"{self.state} ({how})"


@dataclass(frozen=True)
class _Tpdo:
    cob_id: int
    trans_type: int
    event_timer_ms: int


def infer_nmt_state(
    read: ReadU,
    heartbeat: Callable[[float], str | None],
    subscribe: Subscribe,
    unsubscribe: Subscribe,
) -> NmtFound:
    """Infer the node's NMT state (module doc).

    ``read(index, sub, code)`` is an SDO read; ``heartbeat(window_s)`` returns the state a
    heartbeat reported within the last ``window_s`` (waiting up to that long for one), or
    None; ``subscribe``/``unsubscribe`` attach a receive callback to a COB-ID.
    """
    period_ms = _read_or(read, od.HEARTBEAT, 0, "u16", 0)
    if period_ms > 0:
        state = heartbeat(HEARTBEAT_PERIODS * period_ms / 1000.0)
        if state in NMT_COMMAND:
            return NmtFound(state, "heartbeat")
    tpdos = _valid_tpdos(read)
    if not tpdos:
        return NmtFound("PRE-OPERATIONAL", "sdo")
    timers = [t.event_timer_ms for t in tpdos if t.trans_type >= 254 and t.event_timer_ms]
    window = TPDO_WINDOW_PERIODS * max(timers, default=0) / 1000.0
    window = min(max(window, MIN_TPDO_WINDOW_S), MAX_TPDO_WINDOW_S)
    if _tpdo_seen(tpdos, window, subscribe, unsubscribe):
        return NmtFound("OPERATIONAL", "tpdo")
    if any(t.trans_type >= 254 for t in tpdos):
        return NmtFound("PRE-OPERATIONAL", "sdo")
    return NmtFound(None, "unknown")


def _read_or(read: ReadU, index: int, sub: int, code: str, default: int) -> int:
    try:
        return int(read(index, sub, code))
    except SdoAbort:
        return default


def _valid_tpdos(read: ReadU) -> list[_Tpdo]:
    out = []
    for comm in od.TPDO_COMM:
        cob = _read_or(read, comm, 1, "u32", 0x8000_0000)
        if cob & 0x8000_0000:
            continue
        cob_id = cob & (0x1FFF_FFFF if cob & 0x2000_0000 else 0x7FF)
        trans_type = _read_or(read, comm, 2, "u8", 254)
        timer = _read_or(read, comm, 5, "u16", 0)
        out.append(_Tpdo(cob_id, trans_type, timer))
    return out


def _tpdo_seen(
    tpdos: list[_Tpdo], window_s: float, subscribe: Subscribe, unsubscribe: Subscribe
) -> bool:
    seen = threading.Event()

    def on_frame(can_id: int, data: bytearray, timestamp: float) -> None:
        seen.set()

    for tpdo in tpdos:
        subscribe(tpdo.cob_id, on_frame)
    try:
        deadline = time.monotonic() + window_s
        return seen.wait(max(deadline - time.monotonic(), 0.0))
    finally:
        for tpdo in tpdos:
            unsubscribe(tpdo.cob_id, on_frame)
