"""What the client saw the node do besides answering: boot-ups, heartbeats, EMCY, bus errors.

Receive callbacks (canopen's notifier thread) only record and enqueue; nothing here makes
an SDO call. The events are past-tense dataclasses on ``ImuClient.events``; the procedure
redoes or flags the position being averaged when one arrives.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from collections import deque
from dataclasses import dataclass

import can
from canopen.nmt import NMT_STATES

logger = logging.getLogger(__name__)

EMCY_BASE = 0x80
HEARTBEAT_BASE = 0x700
EMCY_KEPT = 8
"""The last EMCY frames a :class:`NodeMonitor` keeps (for a diagnosis such as a refused start)."""
EMCY_LOG_EVERY = 1000
"""A stream of EMCY frames is logged at its 1st, 10th and every 1000th frame (all counted)."""

EMCY_TEXT = {
    0x0000: "error reset or no error",
    0x1000: "generic error",
    0x2000: "current",
    0x3000: "voltage",
    0x4000: "temperature",
    0x5000: "device hardware",
    0x6000: "device software",
    0x8100: "communication",
    0x8110: "CAN overrun (objects lost)",
    0x8120: "CAN in error passive mode",
    0x8130: "life guard or heartbeat error",
    0x8140: "recovered from bus off",
    0x8210: "PDO not processed due to length error",
    0xFF00: "device specific",
}


def emcy_text(code: int) -> str:
    """Readable CiA 301 error-code class of an EMCY code (``0x5000 device hardware``)."""
    text = EMCY_TEXT.get(code) or EMCY_TEXT.get(code & 0xFFF0) or EMCY_TEXT.get(code & 0xFF00)
    return f"0x{code:04X} {text or 'unknown error code'}"


@dataclass(frozen=True)
class NodeRebooted:
    """A boot-up frame arrived: the node restarted (unsaved values are gone)."""

    node_id: int
    time_s: float


@dataclass(frozen=True)
class HeartbeatLost:
    """No heartbeat within ``timeout_s`` since the last one (CAN time ``last_seen_s``)."""

    node_id: int
    last_seen_s: float | None
    timeout_s: float


@dataclass(frozen=True)
class HeartbeatResumed:
    """A heartbeat arrived again after a :class:`HeartbeatLost`."""

    node_id: int
    time_s: float


@dataclass(frozen=True)
class EmergencyReceived:
    """An EMCY frame: error code, error register (0x1001) and the manufacturer bytes."""

    node_id: int
    code: int
    register: int
    data: bytes
    time_s: float

    @property
    def interrupts(self) -> bool:
        """Whether it interrupts the attempt in progress (docs/design.md §9).

        No for 0x0000 (error reset; CANopenNode also sends it for a CAN bus warning) and
        for 0x81xx/0x82xx (communication: overrun, error passive, heartbeat, protocol);
        yes for every other code.
        """
        return self.code != 0x0000 and self.code >> 8 not in (0x81, 0x82)

    @property
    def text(self) -> str:
        """``"0x5000 device hardware (error register 0x01)"``."""
        return f"{emcy_text(self.code)} (error register 0x{self.register:02X})"


@dataclass(frozen=True)
class SerialChanged:
    """The identity serial read now differs from the one read before (another unit)."""

    node_id: int
    old_serial: int
    new_serial: int


@dataclass(frozen=True)
class BusErrorReceived:
    """The interface reported a CAN error frame (bus errors, error passive, bus off)."""

    time_s: float
    can_id: int
    data: bytes


DeviceEvent = (
    NodeRebooted
    | HeartbeatLost
    | HeartbeatResumed
    | EmergencyReceived
    | SerialChanged
    | BusErrorReceived
)


class NodeMonitor(can.Listener):
    """Boot-up, heartbeat, EMCY and error frames of one node, as state and events.

    ``boots`` counts boot-up frames (the transaction compares it before and after each
    step); ``watch(timeout_s)`` starts a watchdog thread emitting :class:`HeartbeatLost`.
    :meth:`silence_s` gives the longest heartbeat gap since :meth:`mark_gaps`;
    ``interrupting_emergencies`` and ``last_emergency`` count the EMCY frames that interrupt
    (:attr:`EmergencyReceived.interrupts`).
    """

    def __init__(self, node_id: int, events: queue.SimpleQueue[DeviceEvent]) -> None:
        self.node_id = node_id
        self.events = events
        self.seen = threading.Event()
        self.booted = threading.Event()
        self.last_time_s: float | None = None
        self.state_code: int | None = None
        self.boots = 0
        self.emergencies = 0
        self.recent_emergencies: deque[EmergencyReceived] = deque(maxlen=EMCY_KEPT)
        """The last EMCY frames, oldest first."""
        self.interrupting_emergencies = 0
        self.last_emergency: EmergencyReceived | None = None
        self.bus_errors = 0
        self._last_mono = 0.0
        self._max_gap_s = 0.0
        self._lost = False
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    # -- receive callbacks (notifier thread: record and enqueue only) ----------------------

    def on_heartbeat(self, can_id: int, data: bytearray, timestamp: float) -> None:
        """Boot-up (state 0) or heartbeat frame."""
        if not data:
            return
        with self._lock:
            self.state_code = data[0] & 0x7F
            self.last_time_s = timestamp
            now = time.monotonic()
            if self._last_mono:
                self._max_gap_s = max(self._max_gap_s, now - self._last_mono)
            self._last_mono = now
            resumed, self._lost = self._lost, False
            if self.state_code == 0:
                self.boots += 1
        if self.state_code == 0:
            self.booted.set()
            logger.warning("node %d booted (boot-up frame)", self.node_id)
            self.events.put(NodeRebooted(self.node_id, timestamp))
        elif resumed:
            logger.warning("node %d heartbeat resumed", self.node_id)
            self.events.put(HeartbeatResumed(self.node_id, timestamp))
        self.seen.set()

    def on_emergency(self, can_id: int, data: bytearray, timestamp: float) -> None:
        """EMCY frame (0x80 + node id); an empty one is a SYNC-like frame and is ignored."""
        if len(data) < 3:
            return
        event = EmergencyReceived(
            self.node_id,
            int.from_bytes(bytes(data[:2]), "little"),
            data[2],
            bytes(data[3:]),
            timestamp,
        )
        self.emergencies += 1
        self.recent_emergencies.append(event)
        if event.interrupts:
            self.interrupting_emergencies += 1
            self.last_emergency = event
        n = self.emergencies
        if n in (1, 10) or n % EMCY_LOG_EVERY == 0:
            more = "" if n == 1 else f" ({n} so far)"
            logger.warning("node %d emergency: %s%s", self.node_id, event.text, more)
        self.events.put(event)

    def on_message_received(self, msg: can.Message) -> None:
        """python-can listener: count and report error frames (canopen ignores them)."""
        if msg.is_error_frame:
            self.bus_errors += 1
            logger.warning("CAN error frame 0x%X: %s", msg.arbitration_id, bytes(msg.data).hex())
            self.events.put(BusErrorReceived(msg.timestamp, msg.arbitration_id, bytes(msg.data)))

    # -- watchdog --------------------------------------------------------------------------

    @property
    def state(self) -> str | None:
        """NMT state name the node reported, or None before any heartbeat or boot-up.

        A boot-up frame (code 0) says the node has just entered PRE-OPERATIONAL from
        initialisation (CiA 301's boot-up protocol), so it reads as PRE-OPERATIONAL, not as
        the INITIALISING the bare code would name; ``state_code`` keeps the 0.
        """
        if self.state_code is None:
            return None
        if self.state_code == 0:
            return "PRE-OPERATIONAL"
        return NMT_STATES.get(self.state_code, f"UNKNOWN {self.state_code}")

    def recent_state(self, window_s: float) -> str | None:
        """State of a heartbeat (not a boot-up) within the last ``window_s``, waiting for one.

        Returns None when no heartbeat comes within ``window_s`` from now.
        """
        deadline = time.monotonic() + window_s
        while True:
            with self._lock:
                fresh = time.monotonic() - self._last_mono <= window_s
                code = self.state_code if self._last_mono else None
            if fresh and code not in (None, 0):
                return self.state
            if time.monotonic() >= deadline:
                return None
            time.sleep(0.01)

    def mark_gaps(self) -> None:
        """Start measuring heartbeat gaps afresh (see :meth:`silence_s`)."""
        with self._lock:
            self._max_gap_s = 0.0

    def silence_s(self) -> float | None:
        """Longest time without a heartbeat since :meth:`mark_gaps`, the current silence too.

        None before the first heartbeat or boot-up frame.
        """
        with self._lock:
            if not self._last_mono:
                return None
            return max(self._max_gap_s, time.monotonic() - self._last_mono)

    @property
    def lost(self) -> bool:
        """Whether the watchdog declared the heartbeat lost (and none came since)."""
        return self._lost

    def watch(self, timeout_s: float) -> None:
        """Start the watchdog: :class:`HeartbeatLost` after ``timeout_s`` without a heartbeat."""
        self.unwatch()
        self._stop.clear()
        with self._lock:
            if not self._last_mono:
                self._last_mono = time.monotonic()
        self._thread = threading.Thread(
            target=self._run, args=(timeout_s,), name="canimucal-heartbeat", daemon=True
        )
        self._thread.start()

    def stop(self) -> None:
        """Stop listening: the watchdog ends (python-can's Listener interface)."""
        self.unwatch()

    def unwatch(self) -> None:
        """Stop the watchdog thread."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None

    def _run(self, timeout_s: float) -> None:
        while not self._stop.wait(max(timeout_s / 4.0, 0.005)):
            with self._lock:
                silent_s = time.monotonic() - self._last_mono
                newly_lost = silent_s > timeout_s and not self._lost
                if newly_lost:
                    self._lost = True
            if newly_lost:
                logger.warning("node %d heartbeat lost (%.2f s silent)", self.node_id, silent_s)
                self.events.put(HeartbeatLost(self.node_id, self.last_time_s, timeout_s))
