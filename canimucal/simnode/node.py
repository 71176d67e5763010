"""``SimulatedImuNode``: a real canopen ``LocalNode`` built from the EDS, driven by the simulator.

What canopen's ``LocalNode`` lacks and this class adds (STYLE.md, docs/design.md §4): TPDOs on their
event timer or on SYNC, only while OPERATIONAL; storing on 0x1010 and restoring defaults on
0x1011 (effective at the next reset); NMT reset node / reset communication with a new
boot-up; range checks on writes; live values for SDO reads of 0x2000–0x2002 (the SDO
read/write side: :mod:`canimucal.simnode.od_access`). Calibration objects stay raw on the
bus: the firmware semantics are exposed as :meth:`corrected_sample`.
"""

from __future__ import annotations

import logging
import math
import threading
from pathlib import Path
from types import TracebackType
from typing import Any

import can
import canopen
import numpy as np
from numpy.typing import NDArray

from canimucal.device import od
from canimucal.device.client import NOTIFIER_CYCLE_S
from canimucal.errors import InputError, NoDeviceError
from canimucal.model.positions import Plan
from canimucal.sim.imu import ImuSimulator
from canimucal.sim.truth import Truth
from canimucal.simnode.backlog import VirtualBusBacklog
from canimucal.simnode.fault_hooks import FaultActions
from canimucal.simnode.faults import FaultInjector
from canimucal.simnode.od_access import ImuLocalNode, ObjectAccess
from canimucal.simnode.producer import SampleProducer
from canimucal.simnode.store import COMM_PARAMETERS, NonVolatileStore, factory_values
from canimucal.simnode.tpdo_gate import TpdoGate

log = logging.getLogger(__name__)

NMT_START, NMT_RESET_NODE, NMT_RESET_COMM = 0x01, 0x81, 0x82
SYNC_COB_ID = 0x80
NMT_COB_ID = 0x000
POSE_TRANSIENT_S = 1.0

Key = tuple[int, int]


class SimulatedImuNode:
    """The simulated IMU on a CAN bus (python-can bus or canopen ``Network``).

    Composed of collaborators: an :class:`ObjectAccess` (SDO callbacks, caches), a
    :class:`SampleProducer` (samples and TPDOs), a :class:`NonVolatileStore` (0x1010/0x1011)
    and a :class:`FaultActions` (what the :class:`FaultInjector` decides).

    ``truth`` defaults to a nominal unit; ``state_file`` is the node's non-volatile memory
    (JSON); ``time_scale`` is simulated seconds per wall second; ``seed`` seeds the noise.
    ``wall_clock`` keeps the unit's world on the wall clock when the host cannot keep up (the
    samples it could not send are dropped, as a real unit's; :mod:`~canimucal.simnode.producer`):
    for a node in a process of its own on a real bus.
    A truth whose ``faults`` name a ``twin_serial`` brings a second unit with that serial,
    answering as the same node-id on the same network (:attr:`twin`): two devices set to
    one node-id, as a misconfigured bus has them (docs/design.md §9).
    """

    def __init__(
        self,
        bus_or_network: can.BusABC | canopen.Network,
        node_id: int = 0x10,
        truth: Truth | None = None,
        *,
        state_file: Path | None = None,
        time_scale: float = 1.0,
        seed: int | None = None,
        wall_clock: bool = False,
        _twin_of: SimulatedImuNode | None = None,
    ) -> None:
        if not 1 <= int(node_id) <= 127:
            raise InputError(f"node id must be 1..127, got {node_id}")
        if not (math.isfinite(time_scale) and time_scale > 0.0):
            raise InputError(f"time_scale must be a positive number, got {time_scale}")
        self.node_id = int(node_id)
        self.truth = truth if truth is not None else Truth.from_dict({})
        self.time_scale = float(time_scale)
        self._lock = threading.RLock()
        self.faults = FaultInjector(self.truth.faults)  # validated before joining any bus
        """Fault injection: ``node.faults.set(...)``, ``clear()``, ``stats``."""
        self._network, self._own_network = _network_of(bus_or_network)
        eds = od.eds_path()
        if not eds.is_file():
            raise InputError(f"object dictionary not found: {eds}")
        dictionary = canopen.import_od(str(eds), self.node_id)
        if not self.truth.trim_object:  # a firmware before 0x2122: the 39-object CRC
            del dictionary[od.MOUNTING_TRIM]
        self._node = ImuLocalNode(self.node_id, dictionary)
        self._store = NonVolatileStore(state_file, self.truth.calibration_store_sub)
        self._simulator = ImuSimulator(self.truth, seed=seed)
        self._gate = TpdoGate(self.truth.store_pdo_mode, self._send_now)
        self._access = ObjectAccess(
            self._node,
            self.truth,
            self._lock,
            self._store,
            live=lambda: self._producer.live,
            set_rate=lambda hz: self._producer.set_rate(hz),
            store_blocking=self._gate.blocking,
        )
        self._producer = SampleProducer(
            self._simulator,
            self._lock,
            time_scale=self.time_scale,
            layouts=self._access.layouts,
            operational=self._operational,
            send=self._send,
            cal_active=self._access.calibration_active,
            on_time=lambda t_s: self._fault_actions.on_sim_time(t_s),
            wall_clock=wall_clock,
            backlog=VirtualBusBacklog(self._network.bus),
            timer_skew_ppm=self.truth.timer_skew_ppm,
            second_send_ms=self.truth.second_send_ms,
            before_sending=self._start_pending_plan,
        )
        self._fault_actions = FaultActions(
            self.node_id,
            self.faults,
            self._lock,
            self._node,
            self._network,
            self._producer,
            reboot=self.reboot,
            heartbeat_ms=lambda: int(self.od_value(od.HEARTBEAT, 0)),
        )
        self._fault_actions.wrap_sdo_server()
        self._node.after_store = self._access.after_write
        self._node.add_read_callback(self._access.on_read)
        self._node.add_write_callback(self._access.on_write)
        self._pending_plan: Plan | None = None
        self._started = False
        self._booting = False
        self._is_twin = _twin_of is not None
        self._load_defaults(comm_only=False)  # od_value() answers before start() too
        self.twin = self._make_twin(state_file, seed)
        """The second unit answering as this node-id (truth ``faults.twin_serial``), or None."""

    # -- public API --------------------------------------------------------------------------

    @property
    def simulator(self) -> ImuSimulator:
        """The :class:`ImuSimulator` behind the node (take care: the producer thread uses it)."""
        return self._simulator

    @property
    def local_node(self) -> canopen.LocalNode:
        """The canopen ``LocalNode`` (for tests and tools)."""
        return self._node

    @property
    def nmt_state(self) -> str:
        """The node's own NMT state (``PRE-OPERATIONAL``, ``OPERATIONAL``, ...)."""
        return str(self._node.nmt.state)

    @property
    def samples_produced(self) -> int:
        """Samples produced since start (OPERATIONAL or not)."""
        return self._producer.samples_produced

    @property
    def frames_dropped_in_store(self) -> int:
        """TPDO frames lost while a slow store blocked the node (truth ``store_pdo_mode``)."""
        return self._gate.dropped

    @property
    def frames_queued_in_store(self) -> int:
        """TPDO frames held during slow stores and sent late in a burst (``queue``)."""
        return self._gate.queued

    @property
    def clock_slip_s(self) -> float:
        """Simulated seconds the clock ran behind ``time_scale`` because the host lagged."""
        return self._producer.clock_slip_s

    @property
    def samples_dropped(self) -> int:
        """Samples never sent because the host lagged (``wall_clock`` nodes only)."""
        return self._producer.samples_dropped

    def _make_twin(self, state_file: Path | None, seed: int | None) -> SimulatedImuNode | None:
        """Build the unit that shares this node-id, when the truth asks for one."""
        serial = self.faults.config.twin_serial
        if serial is None or self._is_twin:
            return None
        doc = {**self.truth.to_dict(), "serial": serial, "faults": {}}
        twin_state = None
        if state_file is not None:
            twin_state = state_file.with_name(f"{state_file.stem}.twin{state_file.suffix}")
        return SimulatedImuNode(
            self._network,
            self.node_id,
            Truth.from_dict(doc),
            state_file=twin_state,
            time_scale=self.time_scale,
            seed=None if seed is None else seed + 1,
            wall_clock=self._producer.wall_clock,
            _twin_of=self,
        )

    def start(self) -> SimulatedImuNode:
        """Join the network, send the boot-up message, enter PRE-OPERATIONAL, start sampling."""
        if self._started:
            return self
        if self.twin is not None:
            self.twin.start()
        if self._is_twin:  # the network's node table keeps the first unit under this id
            self._node.associate_network(self._network)
        else:
            self._network.add_node(self._node)
        self._network.subscribe(NMT_COB_ID, self._on_nmt)
        self._network.subscribe(SYNC_COB_ID, self._on_sync)
        self._boot(reload=None)
        self._producer.start(self._odr_hz())
        self._started = True
        log.info("simulated IMU node %d started (time scale %g)", self.node_id, self.time_scale)
        return self

    def stop(self) -> None:
        """Stop sampling and heartbeats and leave the network (the bus stays open)."""
        if not self._started:
            self._stop_own_notifier()
            return
        self._started = False
        self._producer.stop()
        self._node.nmt.stop_heartbeat()
        self._network.unsubscribe(NMT_COB_ID, self._on_nmt)
        self._network.unsubscribe(SYNC_COB_ID, self._on_sync)
        if self._network.nodes.get(self.node_id) is self._node:
            del self._network[self.node_id]
        elif self._is_twin:
            self._node.remove_network()
        if self.twin is not None:
            self.twin.stop()
        self._stop_own_notifier()
        log.info(
            "simulated IMU node %d stopped (its clock slipped %.3g s behind %g× wall time; "
            "%d samples dropped, the host too slow to send them)",
            self.node_id,
            self.clock_slip_s,
            self.time_scale,
            self.samples_dropped,
        )

    def _stop_own_notifier(self) -> None:
        """Stop the notifier of a network this node made itself (never a caller's)."""
        if self._own_network and self._network.notifier is not None:
            self._network.notifier.stop(self._network.NOTIFIER_SHUTDOWN_TIMEOUT)

    def __enter__(self) -> SimulatedImuNode:
        return self.start()

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.stop()

    def set_pose(self, alpha: float, beta: float, psi: float = 0.0) -> None:
        """Move the unit to a pose (radians), with a short motion transient."""
        with self._lock:
            self._pending_plan = None
            self._simulator.set_pose(alpha, beta, psi, transient_s=POSE_TRANSIENT_S)

    def set_schedule(self, plan: Plan) -> None:
        """Follow ``plan`` from the next NMT start (at once if already OPERATIONAL)."""
        with self._lock:
            if self.nmt_state == "OPERATIONAL":
                self._simulator.set_schedule(plan, transient_s=POSE_TRANSIENT_S)
                self._pending_plan = None
            else:
                self._pending_plan = plan

    def reboot(self) -> None:
        """Power-cycle the node: unsaved values are lost, stored ones reloaded, boot-up again."""
        if not self._started:
            raise InputError("reboot() needs a started node")
        self._node.nmt.stop_heartbeat()
        self.faults.rebooted = True
        self._boot(reload=od.STORE_ALL_SUB)

    def od_value(self, index: int, sub: int = 0) -> Any:
        """Return the current decoded value of an object, as an SDO read would."""
        return self._access.value(index, sub)

    def send_emergency(self, code: int, register: int = 0x01) -> None:
        """Send an EMCY frame (0x80 + node id) and set the error register 0x1001."""
        self._fault_actions.send_emergency(code, register)

    def send_error_frame(self) -> None:
        """Put a CAN error frame on the bus (as a controller reporting a bus error does)."""
        self._fault_actions.send_error_frame()

    @property
    def store_log(self) -> list[int]:
        """0x1010 sub-index of every store this node made, in order."""
        return list(self._store.log)

    def stored_objects(self) -> dict[Key, bytes]:
        """Return the non-volatile memory: raw values a reboot reloads (0x1010 stored)."""
        return self._store.values()

    def calibration_block(self) -> od.CalibrationBlock:
        """Return the calibration block the node holds now (0x2100–0x2122)."""
        with self._lock:
            return od.CalibrationBlock.from_objects(self._access.calibration_values())

    def calibration_active(self) -> bool:
        """Tell whether valid = 1 and the stored CRC matches (the firmware applies it)."""
        return self._access.calibration_active()

    def corrected_sample(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Return the latest sample as the firmware corrects it: (m/s², rad/s), §4."""
        with self._lock:
            live = self._producer.live
            if not live:
                raise NoDeviceError("no sample produced yet")
            accel = [live[(od.ACCEL_RAW, k)] for k in (1, 2, 3)]
            gyro = [live[(od.GYRO_RAW, k)] for k in (1, 2, 3)]
            block, active = self.calibration_block(), self.calibration_active()
        lsbs = self.truth.accel.nominal_lsb, self.truth.gyro.nominal_lsb
        return od.apply_firmware(block, active, active, accel, gyro, *lsbs)

    # -- boot and reset ----------------------------------------------------------------------

    def _boot(self, reload: int | None) -> None:
        """Reload the object dictionary (``reload``: None/1 all, 2 comm) and boot up."""
        self._booting = True  # no TPDO from here until the boot-up is done
        try:
            with self._lock:
                self._load_defaults(comm_only=reload == od.STORE_COMM_SUB)
                self._producer.reset_counter()
                self._producer.error_register = 0
                self._access.invalidate()
            nmt = self._node.nmt
            nmt.send_command(NMT_RESET_NODE)  # INITIALISING: boot-up frame 0x700+id [0]
            nmt.send_command(0x80)  # PRE-OPERATIONAL; starts the producer heartbeat (0x1017)
            if self.truth.nmt_start == "operational":
                nmt.send_command(NMT_START)  # a node that starts itself (CANopenNode's habit)
                period_ms = int(self.od_value(od.HEARTBEAT, 0))
                if period_ms:  # a heartbeat at once on the state change, as CANopenNode
                    nmt.start_heartbeat(period_ms)
        finally:
            self._booting = False
        if self.truth.refuses_start:  # a blank storage reported at boot, as CANopenNode does
            self._fault_actions.send_emergency(0x5000, 0x01)
        if self._started:
            self._producer.set_rate(self._odr_hz())

    def _load_defaults(self, *, comm_only: bool) -> None:
        store = self._node.data_store
        if comm_only:
            for index in list(store):
                if 0x1000 <= index < 0x2000:
                    del store[index]
        else:
            store.clear()
        odr = int(self.od_value(od.NOMINAL, 3)) if comm_only else None
        for key, raw in factory_values(self.truth, odr).items():
            store.setdefault(key[0], {})[key[1]] = raw
        for key, raw in self._store.values().items():
            if not comm_only or key[0] in COMM_PARAMETERS:
                store.setdefault(key[0], {})[key[1]] = raw
        serial = self.faults.serial_override()
        if serial is not None:
            store.setdefault(od.IDENTITY, {})[4] = od.encode("u32", serial & 0xFFFFFFFF)

    # -- canopen callbacks (receive thread: no SDO calls, no blocking) ----------------------

    def _on_nmt(self, can_id: int, data: bytearray, timestamp: float) -> None:
        """Complete what ``NmtSlave`` leaves out: resets boot again; a start runs the plan."""
        if len(data) < 2 or data[1] not in (0, self.node_id):
            return
        command = data[0]
        if command == NMT_RESET_NODE:
            self._node.nmt.stop_heartbeat()
            self.faults.rebooted = True
            self._boot(reload=od.STORE_ALL_SUB)
        elif command == NMT_RESET_COMM:
            self._node.nmt.stop_heartbeat()
            self._boot(reload=od.STORE_COMM_SUB)
        elif command == NMT_START and self.truth.refuses_start:
            # CANopenNode's stock rule: back to PRE-OPERATIONAL while the error register is set
            self._node.nmt.state = "PRE-OPERATIONAL"
        elif command == NMT_START:
            with self._lock:
                self._start_pending_plan()

    def _start_pending_plan(self) -> None:
        """Start a plan waiting for OPERATIONAL at the next sample (lock held).

        Called from the NMT start and by the producer before each block it sends: the NMT
        state turns before this node's NMT callback runs, and a block sent in between would
        start the recorder's schedule clock (its first sample) before the unit's schedule.
        """
        if self._pending_plan is not None:
            self._simulator.set_schedule(self._pending_plan, transient_s=POSE_TRANSIENT_S)
            self._pending_plan = None

    def _on_sync(self, can_id: int, data: bytearray, timestamp: float) -> None:
        if not self._operational():
            return
        for cob_id, frame in self._producer.on_sync():
            self._send(cob_id, frame)

    # -- helpers ----------------------------------------------------------------------------

    def _odr_hz(self) -> int:
        return int(self.od_value(od.NOMINAL, 3))

    def _operational(self) -> bool:
        if self.truth.refuses_start:
            return False
        return not self._booting and self._node.nmt.state == "OPERATIONAL"

    def _send(self, cob_id: int, data: bytes) -> None:
        self._gate.send(cob_id, data)

    def _send_now(self, cob_id: int, data: bytes) -> None:
        if not self._started:
            return
        for frame_id, frame in self.faults.filter_tpdo(cob_id, data):
            self._network.send_message(frame_id, frame)


def _network_of(bus_or_network: can.BusABC | canopen.Network) -> tuple[canopen.Network, bool]:
    """Return the network to join and whether this node created it (and its notifier)."""
    if isinstance(bus_or_network, canopen.Network):
        network = bus_or_network
        if network.bus is None:
            raise NoDeviceError("the canopen network is not connected to a bus")
        if network.notifier is None:
            network.connect()
        return network, False
    if isinstance(bus_or_network, can.BusABC):
        network = canopen.Network(bus_or_network)
        network.NOTIFIER_CYCLE = NOTIFIER_CYCLE_S
        return network.connect(), True
    raise InputError(f"need a python-can bus or a canopen Network, got {type(bus_or_network)}")
