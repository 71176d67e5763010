"""The IMU node of docs/design.md §4 on an independent CANopen responder stack: ``durand`` 0.5.0.

The client and :class:`~canimucal.simnode.node.SimulatedImuNode` both use python-canopen, so
protocol assumptions cancel out between them. This node shares nothing with either: its SDO
server, NMT slave, heartbeat, EMCY and PDO code are durand's; its object dictionary is
transcribed from docs/design.md §4 (not loaded from the EDS); the CRC and the range checks are
written again here. Nothing in this module imports ``canopen`` or ``canimucal``.

It reproduces what CANopenNode devices do (``Behaviour``): a store that blocks the SDO
answer while flash is erased (TPDOs dropped, queued or continuing meanwhile), storage
sub-indices other than 1..4, an OPERATIONAL start-up, heartbeat off, TPDOs on SYNC, EMCY
(0x0000 included) and an event timer that runs off the sensor clock.

Threads (daemons): the python-can notifier of the node's own bus (NMT, SDO, SYNC; every
frame handled under ``self.lock``), one process-wide scheduler thread (durand's heartbeat and
inhibit timers) and the producer thread (sensor clock and TPDO event timers).

Use each side's own ``can.Bus(interface="virtual", channel=X)`` on the same channel
(python-can refuses one bus in two notifiers); never python-can's ``udp_multicast``.
"""

from __future__ import annotations

import heapq
import itertools
import logging
import math
import random
import struct
import threading
import time
import zlib
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import can
from durand import Array, CANBusNetwork, Node, Record, Variable, set_scheduler
from durand import DatatypeEnum as DT
from durand.network import NodeListener
from durand.node import NodeCapabilities
from durand.scheduler import AbstractScheduler
from durand.services.nmt import StateEnum
from durand.services.sdo.server import SDODomainAbort

log = logging.getLogger(__name__)

# -- docs/design.md §4, transcribed ---------------------------------------------------------------
SAVE = 0x65766173  # 'save'
LOAD = 0x64616F6C  # 'load'
ABORT_RANGE = 0x06090030
ABORT_STORE = 0x08000020
ODR_CHOICES = (50, 100, 200, 250, 500, 1000)
G = 9.80665
ACCEL_LSB = G / 2048
GYRO_LSB = math.pi / (180 * 16.4)

ACCEL_RAW, GYRO_RAW, SAMPLE_INFO, NOMINAL = 0x2000, 0x2001, 0x2002, 0x2010
ACCEL_BIAS, ACCEL_M, GYRO_BIAS, GYRO_N, GYRO_G, TILT, CAL_INFO = (
    0x2100,
    0x2101,
    0x2110,
    0x2111,
    0x2112,
    0x2120,
    0x2121,
)
HEARTBEAT = 0x1017

Key = tuple[int, int]

CRC_ORDER: list[tuple[int, int, str]] = (
    [(ACCEL_BIAS, s, "<f") for s in (1, 2, 3)]
    + [(ACCEL_M, s, "<f") for s in range(1, 10)]
    + [(GYRO_BIAS, s, "<f") for s in (1, 2, 3)]
    + [(GYRO_N, s, "<f") for s in range(1, 10)]
    + [(GYRO_G, s, "<f") for s in range(1, 10)]
    + [(TILT, s, "<f") for s in (1, 2)]
    + [(CAL_INFO, 1, "<I"), (CAL_INFO, 2, "<B"), (CAL_INFO, 3, "<f"), (CAL_INFO, 4, "<f")]
)
COMM_KEYS: list[Key] = (
    [(HEARTBEAT, 0)]
    + [(0x1800 + i, s) for i in range(3) for s in (1, 2, 3, 5, 6)]
    + [(0x1A00 + i, s) for i in range(3) for s in range(0, 9)]
)
APP_KEYS: list[Key] = [(NOMINAL, 3)]
CAL_KEYS: list[Key] = [(i, s) for i, s, _ in CRC_ORDER] + [(CAL_INFO, 5), (CAL_INFO, 6)]
STORE_GROUPS = {1: COMM_KEYS + APP_KEYS + CAL_KEYS, 2: COMM_KEYS, 3: APP_KEYS, 4: CAL_KEYS}
TPDO_MAPS: tuple[list[Key], ...] = (
    [(ACCEL_RAW, 1), (ACCEL_RAW, 2), (ACCEL_RAW, 3), (SAMPLE_INFO, 2)],
    [(GYRO_RAW, 1), (GYRO_RAW, 2), (GYRO_RAW, 3), (SAMPLE_INFO, 2)],
    [(SAMPLE_INFO, 1), (SAMPLE_INFO, 2), (SAMPLE_INFO, 3)],
)


def _f32(x: float) -> float:
    return float(struct.unpack("<f", struct.pack("<f", x))[0])


def block_crc(values: dict[Key, Any]) -> int:
    """CRC-32/ISO-HDLC (zlib.crc32, start 0) over the LE SDO encodings, in §4 order."""
    crc = 0
    for index, sub, fmt in CRC_ORDER:
        crc = zlib.crc32(struct.pack(fmt, values[(index, sub)]), crc)
    return crc & 0xFFFFFFFF


def factory_calibration(accel_lsb: float, gyro_lsb: float) -> dict[Key, Any]:
    """Factory calibration block: zero biases, diagonal M and N from the LSBs, valid 0."""
    v: dict[Key, Any] = {}
    for i in (ACCEL_BIAS, GYRO_BIAS):
        for s in (1, 2, 3):
            v[(i, s)] = 0.0
    for i, lsb in ((ACCEL_M, accel_lsb), (GYRO_N, gyro_lsb)):
        for s in range(1, 10):
            v[(i, s)] = _f32(lsb) if s in (1, 5, 9) else 0.0
    for s in range(1, 10):
        v[(GYRO_G, s)] = 0.0
    v[(TILT, 1)] = v[(TILT, 2)] = 0.0
    v[(CAL_INFO, 1)] = v[(CAL_INFO, 2)] = 0
    v[(CAL_INFO, 3)] = v[(CAL_INFO, 4)] = 0.0
    v[(CAL_INFO, 5)] = 0
    v[(CAL_INFO, 6)] = block_crc(v)
    return v


@dataclass
class Behaviour:
    """Device behaviours (truth JSON keys, docs/design.md §5, plus CANopenNode habits)."""

    device_name: bytes = b"canimucal IMU"
    hardware_version: bytes = b"1.0"
    software_version: bytes = b"durand node"
    vendor_id: int = 0
    product_code: int = 0
    revision: int = 0x00010000
    serial: int = 0
    accel_lsb: float = ACCEL_LSB
    gyro_lsb: float = GYRO_LSB
    odr_hz: int = 200
    nmt_start: str = "pre-operational"  # or "operational" (CANopenNode's default)
    heartbeat_ms: int = 1000  # 0: heartbeat off (CANopenNode's example OD)
    store_delay_s: float = 0.0  # the store blocks the SDO answer this long (flash erase)
    store_pdo_mode: str = "drop"  # meanwhile TPDOs are "drop"ped, "queue"d or "continue"
    storage_subs: tuple[int, ...] = (1, 2, 3, 4)  # 0x1010/0x1011 sub-indices present
    sync_pdos: bool = False  # TPDO1-3 on every SYNC (transmission type 1) instead of 254
    timer_skew_ppm: float = 0.0  # TPDO event timers slow (+) / fast (-) vs the sensor clock
    noise_counts: float = 2.0
    seed: int = 0


class _ThreadScheduler(AbstractScheduler):  # type: ignore[type-arg]
    """A heap and a condition variable; callbacks run on one daemon thread.

    durand's own ``SyncScheduler`` can lose a wake-up and never notices an earlier event.
    """

    def __init__(self) -> None:
        self._cv = threading.Condition()
        self._heap: list[tuple[float, int, list[Any]]] = []
        self._seq = itertools.count()
        self._lock = threading.Lock()
        threading.Thread(target=self._run, name="durand-scheduler", daemon=True).start()

    def add(self, delay: float, callback: Any, args: Any = (), kwargs: Any = None) -> list[Any]:
        entry = [time.monotonic() + delay, callback, args, kwargs or {}, True]
        with self._cv:
            heapq.heappush(self._heap, (entry[0], next(self._seq), entry))
            self._cv.notify()
        return entry

    def cancel(self, entry: list[Any]) -> None:
        entry[4] = False

    def _run(self) -> None:
        while True:
            with self._cv:
                while True:
                    while self._heap and not self._heap[0][2][4]:
                        heapq.heappop(self._heap)
                    if not self._heap:
                        self._cv.wait()
                        continue
                    due = self._heap[0][0] - time.monotonic()
                    if due <= 0:
                        entry = heapq.heappop(self._heap)[2]
                        break
                    self._cv.wait(due)
            if entry[4]:
                try:
                    entry[1](*entry[2], **entry[3])
                except Exception:
                    log.exception("scheduler callback failed")

    @property
    def lock(self) -> threading.Lock:
        return self._lock


_SCHEDULER: _ThreadScheduler | None = None


def _scheduler() -> _ThreadScheduler:
    """durand's scheduler is process-global: install ours once for every node."""
    global _SCHEDULER
    if _SCHEDULER is None:
        _SCHEDULER = _ThreadScheduler()
        set_scheduler(_SCHEDULER)
    return _SCHEDULER


class _LockedNetwork(CANBusNetwork):
    """durand's python-can network, each received frame handled under the node's lock.

    Built like ``CANBusNetwork`` but with a 0.1 s receive poll, so ``stop()`` is quick.
    durand keeps one callback per COB-ID: subscribing again replaces the handler.
    """

    def __init__(self, bus: can.BusABC, lock: threading.RLock) -> None:
        self.node_lock = lock
        self._bus = bus
        self._loop = None
        self.lock = threading.Lock()
        self.subscriptions: dict[int, Callable[[int, bytes], None]] = {}
        self._notifier = can.Notifier(bus, (NodeListener(self),), 0.1)

    def add_subscription(self, cob_id: int, callback: Callable[[int, bytes], None]) -> None:
        def locked(cob: int, data: bytes) -> None:
            with self.node_lock:
                callback(cob, data)

        super().add_subscription(cob_id, locked)


class IndependentImuNode:
    """The docs/design.md §4 IMU node on durand; ``start()``/``stop()`` or a context manager."""

    def __init__(
        self, bus: can.BusABC, node_id: int = 0x10, behaviour: Behaviour | None = None
    ) -> None:
        self.bus = bus
        self.node_id = node_id
        self.behaviour = behaviour or Behaviour()
        self.lock = threading.RLock()
        self.node: Any = None
        self.network: _LockedNetwork | None = None
        self.flash: dict[Key, Any] = {}
        """What 0x1010 stored (reloaded at NMT reset node)."""
        self.stats = {"samples": 0, "dropped": 0, "stores": 0, "tx": [0, 0, 0]}
        self.store_log: list[int] = []
        """0x1010 sub-index of every completed store, in order."""
        self._restore_pending: set[int] = set()
        self._stop = threading.Event()
        self._producer: threading.Thread | None = None
        self._rng = random.Random(self.behaviour.seed)
        self._counter = 0
        self._odr = self.behaviour.odr_hz
        self._schedule_reset = threading.Event()

    # -- lifecycle ------------------------------------------------------------------------
    def start(self) -> IndependentImuNode:
        """Send the boot-up, enter PRE-OPERATIONAL (or OPERATIONAL), start sampling."""
        _scheduler()
        with self.lock:  # frames received meanwhile wait until the OD is complete
            self.network = _LockedNetwork(self.bus, self.lock)
            caps = NodeCapabilities(sdo_servers=1, rpdos=0, tpdos=3)
            self.node = Node(self.network, self.node_id, capabilities=caps)  # boot-up
            self._lock_heartbeat()
            self._build_od()
            if self.behaviour.nmt_start == "operational":  # before 0x1017: first HB says 05
                self.node.nmt.set_state(StateEnum.OPERATIONAL)
            self._load(all_objects=True)
            self.network.add_subscription(0, self._on_nmt)  # in front of durand's handler
        self._producer = threading.Thread(target=self._produce, name="durand-imu", daemon=True)
        self._producer.start()
        return self

    def stop(self) -> None:
        """Stop sampling and the heartbeat, and the node's notifier (the bus stays open)."""
        self._stop.set()
        if self._producer is not None:
            self._producer.join(2)
        with self.lock:
            if self.node is not None:
                self.node.object_dictionary.write(HEARTBEAT, 0, 0)  # cancels the heartbeat
        if self.network is not None:
            self.network.stop()

    def __enter__(self) -> IndependentImuNode:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    @property
    def nmt_state(self) -> str:
        """``PRE-OPERATIONAL``, ``OPERATIONAL``, ``STOPPED`` (the names canopen uses)."""
        state = self.node.nmt.state
        return {StateEnum.OPERATIONAL: "OPERATIONAL", StateEnum.STOPPED: "STOPPED"}.get(
            state, "PRE-OPERATIONAL"
        )

    def od_value(self, index: int, sub: int = 0) -> Any:
        """The current value of an object (as durand holds it)."""
        with self.lock:
            return self.node.object_dictionary.read(index, sub)

    def calibration_active(self) -> bool:
        """valid = 1 and the stored CRC-32 matches the block: the firmware applies it (§4)."""
        with self.lock:
            return self._cal_active()

    def emcy(self, code: int, register: int | None = None) -> None:
        """Send an EMCY (0x80 + id); code 0x0000 is the error reset / CAN bus warning."""
        if register is None:
            register = 0 if code == 0 else (0x10 if code >> 8 in (0x81, 0x82) else 0x01)
        with self.lock:
            self.node.emcy.set(code, register)

    def _lock_heartbeat(self) -> None:
        """Heartbeats run under the node lock, so a blocking store pauses them too."""
        hb = self.node.heartbeat_producer
        original = hb._process_heartbeat

        def locked(interval: Any) -> None:
            with self.lock:
                if hb._handle is None and self.node.object_dictionary.read(HEARTBEAT, 0) == 0:
                    return
                original(interval)

        hb._process_heartbeat = locked

    # -- object dictionary ----------------------------------------------------------------
    def _build_od(self) -> None:
        b, node = self.behaviour, self.node
        od = node.object_dictionary
        od[0x1000] = Variable(DT.UNSIGNED32, "ro", 0, name="Device type")
        od[0x1008] = Variable(DT.VISIBLE_STRING, "const", b.device_name, name="Device name")
        od[0x1009] = Variable(DT.VISIBLE_STRING, "const", b.hardware_version, name="HW version")
        od[0x100A] = Variable(DT.VISIBLE_STRING, "const", b.software_version, name="SW version")
        for sub, val in enumerate((b.vendor_id, b.product_code, b.revision, b.serial), 1):
            od.write(0x1018, sub, val)
        for index, signature, name in (
            (0x1010, SAVE, "Store parameters"),
            (0x1011, LOAD, "Restore default parameters"),
        ):
            rec = Record(name=name)
            for sub in b.storage_subs:
                rec[sub] = Variable(DT.UNSIGNED32, "rw", 1, name=f"{name} {sub}")
                od.set_read_callback(index, sub, lambda: 1)  # bit 0: on command
                od.validate_callbacks[(index, sub)].add(_signature_check(index, sub, signature))
                action = self._store if index == 0x1010 else self._restore
                od.download_callbacks[(index, sub)].add(
                    lambda _v, s=sub, act=action: act(s)  # type: ignore[misc]
                )
            od[index] = rec
        for i in range(3):  # durand's TPDO records have sub 1..3 only
            rec = od[0x1800 + i]
            rec[5] = Variable(DT.UNSIGNED16, "rw", 0, name="Event timer")
            rec[6] = Variable(DT.UNSIGNED8, "rw", 0, name="SYNC start value")
            for sub in (2, 5):
                od.update_callbacks[(0x1800 + i, sub)].add(lambda _v: self._schedule_reset.set())
        od[ACCEL_RAW] = Array(Variable(DT.INTEGER16, "ro", 0, name="Accel raw"), 3, name="Accel")
        od[GYRO_RAW] = Array(Variable(DT.INTEGER16, "ro", 0, name="Gyro raw"), 3, name="Gyro")
        info = Record(name="Sample info")
        info[1] = Variable(DT.INTEGER16, "ro", 2500, name="Temperature")
        info[2] = Variable(DT.UNSIGNED16, "ro", 0, name="Sample counter")
        info[3] = Variable(DT.UNSIGNED8, "ro", 0, name="Status")
        od[SAMPLE_INFO] = info
        nominal = Record(name="Nominal scaling")
        nominal[1] = Variable(DT.REAL32, "ro", b.accel_lsb, name="Nominal accel LSB")
        nominal[2] = Variable(DT.REAL32, "ro", b.gyro_lsb, name="Nominal gyro LSB")
        nominal[3] = Variable(DT.UNSIGNED16, "rw", b.odr_hz, name="Output data rate")
        od[NOMINAL] = nominal
        store_sub = 4 if 4 in b.storage_subs else 1  # 0x2011: where the calibration is stored
        od[0x2011] = Variable(DT.UNSIGNED8, "ro", store_sub, name="Calibration store sub-index")
        od.validate_callbacks[(NOMINAL, 3)].add(self._range_check(NOMINAL, 3))
        od.update_callbacks[(NOMINAL, 3)].add(self._on_odr)
        for index, n, name in (
            (ACCEL_BIAS, 3, "Accel bias"),
            (ACCEL_M, 9, "Accel M"),
            (GYRO_BIAS, 3, "Gyro bias"),
            (GYRO_N, 9, "Gyro N"),
            (GYRO_G, 9, "Gyro G"),
            (TILT, 2, "Base tilt"),
        ):
            od[index] = Array(Variable(DT.REAL32, "rw", 0.0, name=name), n, name=name)
        cal = Record(name="Calibration info")
        cal[1] = Variable(DT.UNSIGNED32, "rw", 0, name="Calibration time")
        cal[2] = Variable(DT.UNSIGNED8, "rw", 0, name="Plan code")
        cal[3] = Variable(DT.REAL32, "rw", 0.0, name="Temperature at calibration")
        cal[4] = Variable(DT.REAL32, "rw", 0.0, name="Fit residual rms")
        cal[5] = Variable(DT.UNSIGNED8, "rw", 0, name="Valid flag")
        cal[6] = Variable(DT.UNSIGNED32, "rw", 0, name="CRC-32")
        od[CAL_INFO] = cal
        for index, sub in CAL_KEYS:
            od.validate_callbacks[(index, sub)].add(self._range_check(index, sub))
        for i, mapping in enumerate(TPDO_MAPS):
            # durand's default type 255 would send on every write of a mapped object
            node.tpdo[i].transmission_type = self._defaults()[(0x1800 + i, 2)]
            node.tpdo[i].mapping = mapping

    def _defaults(self) -> dict[Key, Any]:
        b = self.behaviour
        period = 1000 // b.odr_hz
        values: dict[Key, Any] = {(HEARTBEAT, 0): b.heartbeat_ms, (NOMINAL, 3): b.odr_hz}
        ttype = 1 if b.sync_pdos else 254  # durand sends types 2..240 on every SYNC too
        for i, (tt, et) in enumerate(((ttype, period), (ttype, period), (ttype, 100))):
            values[(0x1800 + i, 2)] = tt
            values[(0x1800 + i, 3)] = 0
            values[(0x1800 + i, 5)] = et
            values[(0x1800 + i, 6)] = 0
        values.update(factory_calibration(b.accel_lsb, b.gyro_lsb))
        return values

    def _load(self, all_objects: bool) -> None:
        """Reset: factory defaults, then what 0x1010 stored (comm objects only if not all)."""
        for group in self._restore_pending:
            for key in STORE_GROUPS[group]:
                self.flash.pop(key, None)
        self._restore_pending.clear()
        values = self._defaults()
        values.update(self.flash)
        od = self.node.object_dictionary
        for (index, sub), value in values.items():
            if not all_objects and index >= 0x2000:
                continue
            if 0x1A00 <= index <= 0x1A02 or (0x1800 <= index <= 0x1802 and sub in (1, 2)):
                continue  # mapping and transmission type: through durand's TPDO API below
            od.write(index, sub, value)
        for i in range(3):
            if (0x1800 + i, 2) in values:
                self.node.tpdo[i].transmission_type = values[(0x1800 + i, 2)]
            stored = [values.get((0x1A00 + i, s)) for s in range(0, 9)]
            if stored[0] is not None:
                entries = [int(v or 0) for v in stored[1 : 1 + int(stored[0])]]
                self.node.tpdo[i].mapping = [(v >> 16, (v >> 8) & 0xFF) for v in entries]
        self._odr = od.read(NOMINAL, 3)
        self._schedule_reset.set()

    def _range_check(self, index: int, sub: int) -> Callable[[Any], None]:
        def check(value: Any) -> None:
            problem = self._range_problem(index, sub, value)
            if problem:
                log.info("refused 0x%04X:%02X = %r: %s", index, sub, value, problem)
                raise SDODomainAbort(ABORT_RANGE, (index, sub))

        return check

    def _range_problem(self, index: int, sub: int, value: Any) -> str | None:
        if index == NOMINAL:
            return None if value in ODR_CHOICES else "ODR not allowed"
        if isinstance(value, float) and not math.isfinite(value):
            return "not finite"
        v = float(value)
        if index in (ACCEL_BIAS, GYRO_BIAS) and abs(v) > 65536:
            return "|bias| > 65536"
        if index in (ACCEL_M, GYRO_N):
            b = self.behaviour
            lsb = abs(b.accel_lsb if index == ACCEL_M else b.gyro_lsb)
            if sub in (1, 5, 9):
                return None if 0.5 * lsb <= abs(v) <= 1.5 * lsb else "|diagonal| off by > 50 %"
            diag = self.node.object_dictionary.read(index, 1 + 4 * ((sub - 1) // 3))
            return None if abs(v) <= 0.2 * abs(diag) else "|off-diagonal| > 0.2 |diagonal|"
        if index == GYRO_G and abs(v) > 1000:
            return "|G| > 1000"
        if index == TILT and abs(v) > 0.2:
            return "|tilt| > 0.2 rad"
        if index == CAL_INFO and sub == 5 and v not in (0, 1):
            return "valid flag not 0/1"
        return None

    def _on_odr(self, odr: int) -> None:
        self._odr = odr
        for i in (0, 1):
            self.node.object_dictionary.write(0x1800 + i, 5, 1000 // odr)
        self._schedule_reset.set()

    # -- store / restore: in the notifier thread, inside the SDO handler (as CANopenNode) ---
    def _store(self, sub: int) -> None:
        delay = self.behaviour.store_delay_s
        if delay > 0 and self.behaviour.store_pdo_mode == "continue":
            depth = 0  # release the lock: TPDOs and heartbeat go on, the SDO answer waits
            while True:
                try:
                    self.lock.release()
                except RuntimeError:
                    break
                depth += 1
            try:
                time.sleep(delay)
            finally:
                for _ in range(depth):
                    self.lock.acquire()
        elif delay > 0:
            time.sleep(delay)  # lock held: the producer drops or queues meanwhile
        od = self.node.object_dictionary
        for key in STORE_GROUPS[sub]:
            try:
                self.flash[key] = od.read(*key)
            except KeyError:
                pass
        self.stats["stores"] += 1
        self.store_log.append(sub)
        log.info("stored group 0x1010:%02X", sub)

    def _restore(self, sub: int) -> None:
        self._restore_pending.add(sub)  # CiA 301: effective at the next reset

    def power_cycle(self) -> None:
        """Reboot: RAM lost, flash reloaded, boot-up, then the start-up NMT state."""
        with self.lock:
            self.node.nmt.handle_msg(0, bytes([0x81, self.node_id]))
            self._after_reset(0x81)

    def _on_nmt(self, cob_id: int, msg: bytes) -> None:
        if len(msg) != 2 or msg[1] not in (0, self.node_id):
            return
        self.node.nmt.handle_msg(cob_id, msg)  # durand: boot-up, then PRE-OPERATIONAL
        if msg[0] in (0x81, 0x82):
            self._after_reset(msg[0])

    def _after_reset(self, command: int) -> None:
        self._load(all_objects=command == 0x81)
        if command == 0x81:
            self._counter = 0
        if self.behaviour.nmt_start == "operational":
            self.node.nmt.set_state(StateEnum.OPERATIONAL)

    # -- producer: the sensor clock and the TPDO event timers ------------------------------
    def _sample(self) -> tuple[list[int], list[int], int, int]:
        b, rng = self.behaviour, self._rng
        saturated = False

        def counts(x: float) -> int:
            nonlocal saturated
            c = int(round(x + rng.gauss(0.0, b.noise_counts)))
            saturated = saturated or not -32768 <= c <= 32767
            return max(-32768, min(32767, c))

        accel = [counts(0.0), counts(-G / b.accel_lsb), counts(0.0)]  # f_L = [0, -g, 0]
        gyro = [counts(0.0) for _ in range(3)]
        return accel, gyro, 2500 + int(rng.gauss(0, 2)), int(saturated)

    def _cal_active(self) -> bool:
        od = self.node.object_dictionary
        if od.read(CAL_INFO, 5) != 1:
            return False
        values = {(i, s): od.read(i, s) for i, s, _ in CRC_ORDER}
        return bool(od.read(CAL_INFO, 6) == block_crc(values))

    def _periods(self) -> tuple[float, list[float | None]]:
        od = self.node.object_dictionary
        skew = 1 + self.behaviour.timer_skew_ppm * 1e-6
        tx: list[float | None] = []
        for i in range(3):
            tt, et = od.read(0x1800 + i, 2), od.read(0x1800 + i, 5)
            tx.append(et / 1000.0 * skew if tt in (254, 255) and et else None)
        return 1.0 / self._odr, tx

    def _produce(self) -> None:
        with self.lock:
            sample_t, tx_t = self._periods()
        now = time.monotonic()
        next_sample, next_tx = now, [now + (p or 0) for p in tx_t]
        while not self._stop.is_set():
            if self._schedule_reset.is_set():
                self._schedule_reset.clear()
                with self.lock:
                    sample_t, tx_t = self._periods()
                now = time.monotonic()
                next_sample, next_tx = now, [now + (p or 0) for p in tx_t]
            due = min([next_sample] + [t for t, p in zip(next_tx, tx_t, strict=True) if p])
            wait = due - time.monotonic()
            if wait > 0:
                self._stop.wait(wait)
                continue
            if next_sample <= due:  # the sample first when times tie
                self._do_sample()
                next_sample += sample_t
            else:
                i = next(
                    k for k, (t, p) in enumerate(zip(next_tx, tx_t, strict=True)) if p and t == due
                )
                self._do_tx(i)
                next_tx[i] += tx_t[i] or 0.0

    def _acquire(self) -> bool:
        if self.behaviour.store_pdo_mode == "drop":
            return self.lock.acquire(blocking=False)
        self.lock.acquire()  # "queue": wait, then catch up with every missed event
        return True

    def _do_sample(self) -> None:
        accel, gyro, temp, saturated = self._sample()
        self._counter = (self._counter + 1) & 0xFFFF
        self.stats["samples"] += 1  # type: ignore[operator]
        if not self._acquire():
            self.stats["dropped"] += 1  # type: ignore[operator]
            return
        try:
            od = self.node.object_dictionary
            for k in range(3):
                od.write(ACCEL_RAW, k + 1, accel[k])
                od.write(GYRO_RAW, k + 1, gyro[k])
            od.write(SAMPLE_INFO, 1, temp)
            od.write(SAMPLE_INFO, 2, self._counter)
            od.write(SAMPLE_INFO, 3, saturated | (4 if self._cal_active() else 0))
        finally:
            self.lock.release()

    def _do_tx(self, i: int) -> None:
        if not self._acquire():
            self.stats["dropped"] += 1  # type: ignore[operator]
            return
        try:
            tpdo = self.node.tpdo[i]
            if self.node.nmt.state == StateEnum.OPERATIONAL and tpdo._cache is not None:
                tpdo.transmit()
                self.stats["tx"][i] += 1  # type: ignore[index]
        finally:
            self.lock.release()


def _signature_check(index: int, sub: int, signature: int) -> Callable[[Any], None]:
    def check(value: Any) -> None:
        if value != signature:
            raise SDODomainAbort(ABORT_STORE, (index, sub))

    return check
