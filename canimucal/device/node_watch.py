"""What a node did while the tool wrote to it: restarts, heartbeat gaps, NMT state, EMCY.

docs/design.md §9 ("The store is the commit point"). A write transaction marks the node
before its first download and asks :meth:`NodeWatch.trouble` before each step and again
after the store. Evidence that the node restarted and lost what was written to its RAM:

- a boot-up frame (:attr:`NodeMonitor.boots` moved);
- no heartbeat for longer than three producer-heartbeat periods (0x1017), and at least
  :data:`HEARTBEAT_GAP_FLOOR_S` (a restart whose boot-up frame was lost); the time a store
  took to answer is excused, since a node erasing flash inside its SDO handler may hold its
  heartbeat meanwhile;
- heartbeats saying PRE-OPERATIONAL where the node was OPERATIONAL at the mark, with no NMT
  command for it on the bus since, this client's or another master's (a reset that lost its
  boot-up frame; a node another master starts or stops keeps its RAM).

An EMCY whose code interrupts (:attr:`EmergencyReceived.interrupts`) is reported too: a node
that signals a device fault while being written is not trusted to store.
"""

from __future__ import annotations

from dataclasses import dataclass

from canopen.nmt import NMT_STATES

from canimucal.device import od
from canimucal.device.client import ImuClient
from canimucal.errors import SdoAbort

OPERATIONAL, PRE_OPERATIONAL = 0x05, 0x7F
"""Heartbeat state codes (CiA 301)."""
HEARTBEAT_GAP_FLOOR_S = 0.3
"""Shortest heartbeat gap that counts as a restart, whatever 0x1017 says: frames relayed by a
loaded host arrive late by tens of milliseconds, and a gap shorter than this would raise
alarms that no restart caused."""


@dataclass
class NodeWatch:
    """A node's boot-ups, heartbeat gaps, NMT state and EMCY since :meth:`start`."""

    client: ImuClient
    period_s: float | None
    boots: int
    emergencies: int
    state_code: int | None
    nmt_commands: int = 0
    """This client's and other masters' NMT commands to the node at the mark."""
    excused_s: float = 0.0

    @classmethod
    def start(cls, client: ImuClient) -> NodeWatch:
        """Mark the node now; read its heartbeat period (0x1017, one SDO read)."""
        try:
            period_ms = int(client.read_value(od.HEARTBEAT, 0, "u16"))
        except SdoAbort:
            period_ms = 0  # no 0x1017: only boot-ups and the read-back tell
        monitor = client.heartbeat
        monitor.mark_gaps()
        return cls(
            client,
            period_ms / 1000.0 if period_ms else None,
            monitor.boots,
            monitor.interrupting_emergencies,
            monitor.state_code,
            client.nmt_commands + client.foreign_nmt_commands,
        )

    @property
    def gap_limit_s(self) -> float | None:
        """Longest heartbeat gap that is not a restart (None: no heartbeat to watch)."""
        if self.period_s is None or self.state_code is None:
            return None
        return max(3.0 * self.period_s, HEARTBEAT_GAP_FLOOR_S) + self.excused_s

    def excuse(self, seconds: float) -> None:
        """Allow a longer heartbeat gap by ``seconds`` (the time a store took to answer)."""
        self.excused_s += max(0.0, seconds)

    def restarted(self) -> str | None:
        """Say why the node seems to have restarted since the mark (None: no sign of it)."""
        monitor, node = self.client.heartbeat, self.client.node_id
        if monitor.boots != self.boots:
            return f"node {node} sent a boot-up (it restarted: what was written to RAM is gone)"
        limit, silence = self.gap_limit_s, monitor.silence_s()
        if limit is not None and silence is not None and silence > limit:
            assert self.period_s is not None
            return (
                f"no heartbeat from node {node} for {silence:.2f} s (its period is "
                f"{1000 * self.period_s:.0f} ms): it may have restarted without a boot-up frame"
            )
        reset = self.state_code == OPERATIONAL and monitor.state_code == PRE_OPERATIONAL
        commanded = self.client.nmt_commands + self.client.foreign_nmt_commands
        if reset and commanded == self.nmt_commands:
            return (
                f"node {node} went from {_state_name(OPERATIONAL)} to "
                f"{_state_name(PRE_OPERATIONAL)} with no NMT command on the bus (a reset?)"
            )
        return None

    def emergency(self) -> str | None:
        """Describe the interrupting EMCY the node sent since the mark (None: none)."""
        monitor = self.client.heartbeat
        if monitor.interrupting_emergencies == self.emergencies or monitor.last_emergency is None:
            return None
        return f"node {self.client.node_id} sent an emergency: {monitor.last_emergency.text}"


def _state_name(code: int) -> str:
    return str(NMT_STATES.get(code, f"state {code}"))
