"""Fault hooks of :class:`~canimucal.simnode.node.SimulatedImuNode`.

The node routes SDO requests and responses, TPDO frames and its simulated clock through
its :class:`~canimucal.simnode.faults.FaultInjector` (``node.faults``). :class:`FaultActions`,
a collaborator the node owns, holds the glue: serve / ignore / mute / abort / reboot an SDO
request, run timed faults (reboot, EMCY, error frames, heartbeat loss) from the producer
thread.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable

import can
import canopen

from canimucal.device import od
from canimucal.device.events import EMCY_LOG_EVERY
from canimucal.simnode.faults import EMCY_BASE, Emergency, FaultInjector, emcy_frame
from canimucal.simnode.producer import SampleProducer

log = logging.getLogger(__name__)

SdoHandler = Callable[[int, bytearray, float], None]


class FaultActions:
    """What the node does with the faults its injector decides.

    ``reboot()`` power-cycles the node; ``heartbeat_ms()`` reads 0x1017 (to resume a lost
    heartbeat). Call :meth:`wrap_sdo_server` before the node joins the network.
    """

    def __init__(
        self,
        node_id: int,
        faults: FaultInjector,
        lock: threading.RLock,
        local_node: canopen.LocalNode,
        network: canopen.Network,
        producer: SampleProducer,
        *,
        reboot: Callable[[], None],
        heartbeat_ms: Callable[[], int],
    ) -> None:
        self.node_id = node_id
        self.faults = faults
        self._lock = lock
        self._node = local_node
        self._network = network
        self._producer = producer
        self._reboot = reboot
        self._heartbeat_ms = heartbeat_ms
        self._serve_sdo: SdoHandler | None = None
        self._send_sdo: Callable[[bytes], None] | None = None
        self._mute_sdo = False

    def send_emergency(self, code: int, register: int = 0x01) -> None:
        """Send an EMCY frame (0x80 + node id) and set the error register 0x1001."""
        with self._lock:
            self._producer.error_register = register & 0xFF
            self._producer.live[(od.ERROR_REGISTER, 0)] = register & 0xFF
        self.faults.stats.emergencies += 1
        n = self.faults.stats.emergencies
        if n in (1, 10) or n % EMCY_LOG_EVERY == 0:  # as the client logs them: not 8000 lines
            log.warning("simulated EMCY 0x%04X (error register 0x%02X; %d sent)", code, register, n)
        self._network.send_message(EMCY_BASE + self.node_id, emcy_frame(code, register))

    def send_error_frame(self) -> None:
        """Put a CAN error frame on the bus (as a controller reporting a bus error does)."""
        self.faults.stats.error_frames += 1
        msg = can.Message(is_error_frame=True, arbitration_id=0x20000004, data=bytes(8))
        if self._network.bus is not None:
            self._network.bus.send(msg)

    def wrap_sdo_server(self) -> None:
        """Route SDO requests through the fault injector (before the network subscribes)."""
        sdo = self._node.sdo
        self._serve_sdo = sdo.on_request
        self._send_sdo = sdo.send_response
        self._mute_sdo = False
        sdo.on_request = self._on_sdo_request  # type: ignore[method-assign]
        sdo.send_response = self._on_sdo_response  # type: ignore[method-assign]

    def _on_sdo_request(self, can_id: int, data: bytearray, timestamp: float) -> None:
        assert self._serve_sdo is not None and self._send_sdo is not None
        fate = self.faults.on_sdo_request(bytes(data))
        if fate == "serve":
            self._serve_sdo(can_id, data, timestamp)
        elif fate == "mute":
            self._mute_sdo = True
            try:
                self._serve_sdo(can_id, data, timestamp)
            finally:
                self._mute_sdo = False
        elif fate == "reboot":
            log.warning("simulated power cycle while serving an SDO request")
            self._reboot()
        elif fate == "reboot+serve":
            log.warning("simulated power cycle just before serving an SDO request")
            self._reboot()
            self._serve_sdo(can_id, data, timestamp)
        elif fate.startswith("abort:"):
            code = int(fate.split(":")[1])
            head = bytes([0x80]) + bytes(data[1:4])
            self._send_sdo(head + code.to_bytes(4, "little"))

    def _on_sdo_response(self, response: bytes | bytearray) -> None:
        assert self._send_sdo is not None
        if not self._mute_sdo:
            self._send_sdo(bytes(response))

    def on_sim_time(self, t_s: float) -> None:
        """Run the timed faults due at simulated time ``t_s`` (producer thread)."""
        for kind, arg in self.faults.due(t_s):
            if kind == "reboot":
                self.faults.stats.reboots += 1
                log.warning("simulated power cycle at t = %.3f s", t_s)
                self._reboot()
            elif kind == "emergency" and isinstance(arg, Emergency):
                self.send_emergency(arg.code, arg.register)
            elif kind == "error_frame":
                self.send_error_frame()
            elif kind == "heartbeat":
                self._set_heartbeat(bool(arg))

    def _set_heartbeat(self, on: bool) -> None:
        nmt = self._node.nmt
        if on:
            nmt.start_heartbeat(self._heartbeat_ms())
            log.warning("simulated heartbeat resumed")
        else:
            nmt.stop_heartbeat()
            log.warning("simulated heartbeat loss")
