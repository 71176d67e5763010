"""Why a node sends no sample after NMT start: it stays PRE-OPERATIONAL (docs/design.md §9).

CANopenNode's stock NMT control sends a node back to PRE-OPERATIONAL after every NMT start
while a masked bit of its error register is set; a blank storage at first boot (EMCY 0x5000,
generic error bit) is enough (issue 24, case 2). The heartbeat then says 0x7F the whole time
and the node looks silent. :func:`refused_start` turns that into one line with what the node
showed: its state from the heartbeat, its error register (0x1001, read by SDO) and the EMCY
frames seen since the tool connected.
"""

from __future__ import annotations

import time

from canimucal.device import od
from canimucal.device.client import ImuClient
from canimucal.device.events import emcy_text
from canimucal.errors import DeviceError

ERROR_REGISTER_BITS = (
    (0x01, "generic"),
    (0x02, "current"),
    (0x04, "voltage"),
    (0x08, "temperature"),
    (0x10, "communication"),
    (0x20, "device profile"),
    (0x80, "manufacturer"),
)
"""CiA 301 error register (0x1001) bits."""
EMCY_LISTED = 3
"""The latest EMCY frames named in the message."""
HEARTBEAT_WINDOW_S = 2.0
"""How long to wait for a new heartbeat: one arriving now says the node is alive, and where."""
POLL_S = 0.02


def refused_start(client: ImuClient) -> str | None:
    """One line for a node its heartbeat shows PRE-OPERATIONAL after start; None otherwise.

    ``"node 16 stays pre-operational after start: error register 0x01 (generic), EMCY
    0x5000 'device hardware' at 12:00:01: the node refuses to start ..."``.
    """
    if _next_heartbeat_state(client) != "PRE-OPERATIONAL":
        return None  # running, silent (stopped, unplugged) or without a heartbeat
    seen = [_register(client)]
    emergencies = list(client.heartbeat.recent_emergencies)[-EMCY_LISTED:]
    if emergencies:
        seen += [_emcy(e.code, e.time_s) for e in emergencies]
    else:
        seen.append("no EMCY since the tool connected (a node sends one when the error arises)")
    return (
        f"node {client.node_id} stays pre-operational after start: {', '.join(seen)}: the node "
        "refuses to start (CANopenNode returns to PRE-OPERATIONAL while its error register is "
        "set; docs/firmware.md §5)"
    )


def _next_heartbeat_state(client: ImuClient) -> str | None:
    """Wait for the next heartbeat (:data:`HEARTBEAT_WINDOW_S`); return its state, else None.

    A boot-up frame is passed over: the state the restarted node settles in comes with the
    heartbeat after it.
    """
    before = client.heartbeat.last_time_s
    deadline = time.monotonic() + HEARTBEAT_WINDOW_S
    while time.monotonic() < deadline:
        now = client.heartbeat.last_time_s
        if now != before:
            if client.heartbeat.state_code != 0:
                return client.heartbeat.state
            before = now
        time.sleep(POLL_S)
    return None


def _register(client: ImuClient) -> str:
    try:
        value = int(client.read_value(od.ERROR_REGISTER, 0, "u8"))
    except DeviceError as exc:
        return f"error register unreadable ({exc})"
    names = [name for bit, name in ERROR_REGISTER_BITS if value & bit]
    return f"error register 0x{value:02X}" + (f" ({', '.join(names)})" if names else "")


def _emcy(code: int, time_s: float) -> str:
    text = emcy_text(code).split(" ", 1)[1]  # "0x5000 device hardware" -> "device hardware"
    when = time.strftime("%H:%M:%S", time.localtime(time_s))
    return f"EMCY 0x{code:04X} '{text}' at {when}"
