"""``ImuClient``: the tool's side of one IMU node (docs/design.md §4, STYLE "CANopen").

SDO access with a retry policy (timeouts retried with exponential backoff, aborts never),
node discovery, identity, nominal LSBs, the PDO layout read from the node, the calibration
block, heartbeat watching and streaming of paired samples. Quiet by default: NMT only to
the target node, no SYNC unless ``sync_producer=True``, no ODR change unless asked.

Receive callbacks (canopen's notifier thread) only enqueue raw frames; decoding and pairing
run on the client's consumer thread (:mod:`canimucal.device.stream`).
"""

from __future__ import annotations

import contextlib
import logging
import math
import queue
import threading
import time
from typing import NamedTuple

import can
import canopen

from canimucal.device import od
from canimucal.device.bus import BACKOFF_START_S, SdoChannel, default_sdo_timeout_s
from canimucal.device.busload import BusLoad, BusLoadMeter
from canimucal.device.events import (
    EMCY_BASE,
    HEARTBEAT_BASE,
    DeviceEvent,
    NodeMonitor,
    SerialChanged,
)
from canimucal.device.nmt_state import NmtFound, infer_nmt_state
from canimucal.device.pdo_layout import read_layout
from canimucal.device.sdo_tally import SdoAnswerTally
from canimucal.device.stream import SampleLayout, SamplePairer
from canimucal.device.stream_consumer import StreamConsumer
from canimucal.errors import DeviceError, DeviceSilentError, NoDeviceError, SdoAbort
from canimucal.model.samples import SampleBlock, concat_blocks
from canimucal.model.vocabulary.constants import OUTPUT_DATA_RATES_HZ
from canimucal.untrusted import DEVICE_TEXT_MAX_BYTES, device_text

logger = logging.getLogger(__name__)

NMT_START = 0x01
NMT_RESET_NODE = 0x81
SKEW_NOTICE_PPM = 1000.0
"""Event-timer skew worth a warning when streaming stops (one sample in a thousand)."""
DEFAULT_STORE_TIMEOUT_S = 10.0
"""How long a 0x1010 store may take to answer (flash erase inside the SDO handler)."""
SDO_REQUEST_BASE = 0x600
"""COB-ID base of SDO requests (client to server) of the default SDO channel."""
NMT_COB_ID = 0x000
"""COB-ID of NMT commands (CiA 301)."""
SDO_RESPONSE_BASE = 0x580
"""COB-ID base of SDO responses (server to client) of the default SDO channel."""
UPLOAD_RESPONSE = 0x40
"""SDO command specifier of an upload (read) response (CiA 301)."""
ANSWER_WINDOW_FLOOR_S = 0.005
"""After the first answer to a serial read, how long at least to listen for a second device."""
LSB_UNITS = (("accel", "m/s² per count"), ("gyro", "rad/s per count"))
"""What 0x2010:01 and 0x2010:02 scale, and their units."""
NOTIFIER_CYCLE_S = 0.1
"""Receive-thread wake-up of a network the client makes itself (bounds :meth:`close`)."""


class Identity(NamedTuple):
    """0x1018:01–04, 0x1008 and 0x1009/0x100A.

    The strings are the device's, made printable (:func:`canimucal.untrusted.printable`)
    and cut at 256 bytes; empty when the node does not have the object.
    """

    vendor_id: int
    product_code: int
    revision: int
    serial: int
    device_name: str
    hardware_version: str = ""
    software_version: str = ""


class CalibrationReadout(NamedTuple):
    """The calibration block as read: values, valid flag, stored CRC and whether it matches.

    ``objects`` holds every :data:`od.CALIBRATION_OBJECTS` value the node has (valid and
    CRC included; a node without 0x2122 has no mounting trim); ``raw`` their bytes: as the
    node returned them when read (``read_bytes``), else re-encoded (exact for every finite
    value; a NaN keeps its payload only when read).
    """

    block: od.CalibrationBlock
    valid: int
    crc_stored: int
    crc_ok: bool
    objects: dict[tuple[int, int], float | int]
    read_bytes: dict[tuple[int, int], bytes] | None = None

    @property
    def trim(self) -> bool:
        """Whether the node has the mounting-trim object (the 42-object CRC layout)."""
        return od.has_trim(self.objects)

    @property
    def raw(self) -> dict[tuple[int, int], bytes]:
        """Little-endian SDO bytes of every object."""
        if self.read_bytes is not None:
            return dict(self.read_bytes)
        return {key: od.encode(od.OBJECT_CODES[key], v) for key, v in self.objects.items()}


class ImuClient:
    """One IMU node on a canopen :class:`~canopen.Network` (or a python-can bus).

    Given a bus, the client makes its own network (and notifier) on it and leaves the bus
    open on :meth:`close`; given a network, it only adds and removes its node.
    """

    def __init__(
        self,
        network_or_bus: canopen.Network | can.BusABC,
        node_id: int,
        *,
        sdo_timeout_s: float | None = None,
        sdo_retries: int = 2,
        sync_producer: bool = False,
        sync_period_s: float = 0.005,
        sdo_backoff_s: float = BACKOFF_START_S,
        bitrate_bps: int | None = None,
    ) -> None:
        if not 1 <= node_id <= 127:
            raise ValueError(f"node id must be 1..127, got {node_id}")
        self._owns_network = isinstance(network_or_bus, can.BusABC)
        if isinstance(network_or_bus, can.BusABC):
            network = canopen.Network(network_or_bus)
            network.NOTIFIER_CYCLE = NOTIFIER_CYCLE_S
            network.connect()
        else:
            network = network_or_bus
        self.network = network
        self.node_id = node_id
        self.node = canopen.RemoteNode(node_id, canopen.ObjectDictionary())
        network.add_node(self.node)
        timeout = default_sdo_timeout_s() if sdo_timeout_s is None else sdo_timeout_s
        # SimpleQueue, not Queue: its get and put are single C calls, so a Ctrl-C landing in
        # the main thread's get cannot leave a lock held that the producing thread then waits
        # on forever (Queue's Python-level Condition can; see StreamConsumer.stop)
        self.events: queue.SimpleQueue[DeviceEvent] = queue.SimpleQueue()
        """Boot-ups, heartbeat loss, EMCY, serial changes and bus errors, as they happen."""
        self.heartbeat = NodeMonitor(node_id, self.events)
        self.sdo = SdoChannel(
            self.node, timeout, sdo_retries, backoff_s=sdo_backoff_s, boots=self._boots
        )
        network.subscribe(HEARTBEAT_BASE + node_id, self.heartbeat.on_heartbeat)
        network.subscribe(EMCY_BASE + node_id, self.heartbeat.on_emergency)
        self.foreign_sdo_requests = 0
        """SDO requests to the node that this client did not send (another SDO client)."""
        network.subscribe(SDO_REQUEST_BASE + node_id, self._on_foreign_sdo_request)
        self.foreign_nmt_commands = 0
        """NMT commands to this node (or to all) sent by another master on the bus."""
        network.subscribe(NMT_COB_ID, self._on_foreign_nmt)
        self._answer_tally = SdoAnswerTally()
        self._answer_tally.attach(self.node.sdo)
        network.subscribe(SDO_RESPONSE_BASE + node_id, self._answer_tally.on_response)
        self.bus_meter = BusLoadMeter(bitrate_bps)
        """Every frame the network receives (``bitrate_bps=None``: 500 kbit/s assumed)."""
        if network.notifier is not None:
            network.notifier.add_listener(self.heartbeat)  # error frames
            network.notifier.add_listener(self.bus_meter)
        self._serial: int | None = None
        self._negative_lsb_told: set[int] = set()
        self._original_odr: int | None = None
        self.nmt_found: NmtFound | None = None
        """The NMT state the node was found in (set by :meth:`observe_nmt_state`)."""
        self._nmt_sent = False
        self.nmt_commands = 0
        """NMT commands this client sent (a state change after one is not a reset)."""
        self._closed = False
        self.sync_producer = sync_producer
        self.sync_period_s = sync_period_s
        self.samples: queue.SimpleQueue[SampleBlock] = queue.SimpleQueue()
        self._stream: StreamConsumer | None = None

    # ----------------------------------------------------------------- typed SDO access
    def read_value(self, index: int, sub: int, code: str) -> float | int:
        """Read one object and decode it as ``code`` (``f32``, ``u32``, ``u16``, ``u8``)."""
        return od.decode(code, self.read_raw(index, sub, code))

    def read_raw(self, index: int, sub: int, code: str) -> bytes:
        """Read one object's bytes, checked against the size of ``code``."""
        data = self.sdo.upload(index, sub)
        size = len(od.encode(code, 0))
        if len(data) > size and not any(data[size:]):
            data = data[:size]  # some devices answer U8/U16 objects with 4 bytes
        if len(data) != size:
            raise DeviceError(
                f"{od.format_key(index, sub)} answered {len(data)} bytes, expected {size}"
            )
        return data

    def write_value(self, index: int, sub: int, code: str, value: float | int) -> None:
        """Encode ``value`` as ``code`` and write it (expedited download)."""
        self.sdo.download(index, sub, od.encode(code, value))

    # ------------------------------------------------------------------ node and identity
    def find_node(self, timeout_s: float = 1.0) -> str:
        """Confirm the node is there: ``"boot-up"``/``"heartbeat"`` seen, else ``"sdo"``.

        Waits up to ``timeout_s`` for a boot-up or heartbeat frame, then probes 0x1018:01 by
        SDO. Raises :class:`NoDeviceError` (exit 4) when nothing answers.
        """
        if self.heartbeat.seen.wait(timeout_s):
            return "boot-up" if self.heartbeat.booted.is_set() else "heartbeat"
        try:
            self.read_value(od.IDENTITY, 1, "u32")
        except DeviceSilentError as exc:
            raise NoDeviceError(
                f"no CANopen node {self.node_id} on the bus: no boot-up or heartbeat "
                f"within {timeout_s:g} s and no SDO answer"
            ) from exc
        return "sdo"

    def identity(self) -> Identity:
        """Read 0x1018:01–04 and the device name 0x1008."""
        vendor, product, revision, serial = (
            int(self.read_value(od.IDENTITY, sub, "u32")) for sub in (1, 2, 3, 4)
        )
        if self._serial is not None and serial != self._serial:
            logger.warning("node %d serial changed: %d -> %d", self.node_id, self._serial, serial)
            self.events.put(SerialChanged(self.node_id, self._serial, serial))
        self._serial = serial
        name, hardware, software = (
            self.device_string(index)
            for index in (od.DEVICE_NAME, od.HARDWARE_VERSION, od.SOFTWARE_VERSION)
        )
        return Identity(vendor, product, revision, serial, name, hardware, software)

    def device_string(self, index: int) -> str:
        """Read a VISIBLE_STRING object (sub 0): at most 256 bytes, made printable.

        ``""`` when the node does not have the object.
        """
        try:
            raw, cut = self.sdo.upload_bounded(index, 0, DEVICE_TEXT_MAX_BYTES)
        except SdoAbort:
            return ""
        return device_text(raw, cut)

    def nominal_lsb(self) -> tuple[float, float]:
        """Nominal accel (m/s² per count) and gyro (rad/s per count) LSB, signed (0x2010).

        A zero or non-finite LSB is a :class:`DeviceError` (nothing can be scaled by it); a
        negative one is legal (the axes count against the quantity) and is logged once.
        """
        lsbs = (
            float(self.read_value(od.NOMINAL, 1, "f32")),
            float(self.read_value(od.NOMINAL, 2, "f32")),
        )
        for sub, (what, unit), lsb in zip((1, 2), LSB_UNITS, lsbs, strict=True):
            if not (math.isfinite(lsb) and lsb != 0.0):
                raise DeviceError(
                    f"node {self.node_id} reports a nominal {what} LSB of {lsb:g} {unit} "
                    f"(0x2010:{sub:02X}): unusable; nothing can be scaled by it"
                )
            if lsb < 0.0 and sub not in self._negative_lsb_told:
                self._negative_lsb_told.add(sub)
                logger.warning(
                    "node %d reports a negative nominal %s LSB (%g %s, 0x2010:%02X): its axes "
                    "count against the %s; the calibration keeps that sign",
                    self.node_id,
                    what,
                    lsb,
                    unit,
                    sub,
                    "acceleration" if sub == 1 else "rotation",
                )
        return lsbs

    def output_data_rate(self) -> int:
        """Output data rate (Hz, 0x2010:03)."""
        return int(self.read_value(od.NOMINAL, 3, "u16"))

    def set_output_data_rate(self, rate_hz: int) -> None:
        """Change the output data rate (only when the user asks: docs/design.md §4 quiet bus)."""
        if rate_hz not in OUTPUT_DATA_RATES_HZ:
            raise ValueError(
                f"output data rate must be one of {OUTPUT_DATA_RATES_HZ}, got {rate_hz}"
            )
        if self._original_odr is None:
            self._original_odr = self.output_data_rate()
        self.write_value(od.NOMINAL, 3, "u16", rate_hz)

    def pdo_mapping(self) -> SampleLayout:
        """Read TPDO1–3 COB-IDs (0x1800–0x1802) and mappings (0x1A00–0x1A02) from the node."""

        def read(index: int, sub: int) -> int:
            return int(self.read_value(index, sub, "u8" if sub == 0 else "u32"))

        try:
            return read_layout(read)
        except ValueError as exc:
            raise DeviceError(f"unusable PDO mapping: {exc}") from exc

    def pdo_objects(self) -> dict[tuple[int, int], int]:
        """Read the TPDO objects the mapping is built from (0x1800–0x1802:01, 0x1A00–0x1A02).

        What ``read-params --json`` keeps, so ``import-log --pdo-map`` decodes a log of this
        node with its own mapping; a mapping that cannot stream is returned as read all the
        same (the objects up to the first TPDO that has none).
        """
        seen: dict[tuple[int, int], int] = {}

        def read(index: int, sub: int) -> int:
            seen[(index, sub)] = int(self.read_value(index, sub, "u8" if sub == 0 else "u32"))
            return seen[(index, sub)]

        with contextlib.suppress(ValueError):
            read_layout(read)
        return seen

    def has_trim_object(self) -> bool:
        """Tell whether the node has the mounting-trim object 0x2122 (docs/design.md §4).

        A firmware before it answers the upload of 0x2122:01 with abort 0x06020000 ("object
        does not exist"; 0x06090011 is taken the same way): False, and its calibration CRC
        covers the 39 objects of 0x2100–0x2121:04. Any other abort, or silence, raises.
        """
        try:
            self.read_raw(*od.TRIM_KEYS[0], "f32")
        except SdoAbort as exc:
            if exc.code in (od.ABORT_NO_OBJECT, od.ABORT_NO_SUBINDEX):
                return False
            raise
        return True

    def read_calibration_block(self) -> CalibrationReadout:
        """Read every calibration object (docs/design.md §4), the valid flag and the stored CRC.

        A node without the mounting-trim object (its upload of 0x2122:01 aborts, as in
        :meth:`has_trim_object`) is read in the 39-object layout.
        """
        objects: dict[tuple[int, int], float | int] = {}
        read: dict[tuple[int, int], bytes] = {}
        legacy = False
        for index, sub, code in od.CALIBRATION_OBJECTS:
            if legacy and (index, sub) in od.TRIM_KEYS:
                continue
            try:
                read[(index, sub)] = self.read_raw(index, sub, code)
            except SdoAbort as exc:
                first_trim = (index, sub) == od.TRIM_KEYS[0]
                if not (first_trim and exc.code in (od.ABORT_NO_OBJECT, od.ABORT_NO_SUBINDEX)):
                    raise
                legacy = True  # a firmware before 0x2122: the 39-object layout
                continue
            objects[(index, sub)] = od.decode(code, read[(index, sub)])
        crc_stored = int(objects[(od.CAL_INFO, od.CAL_CRC_SUB)])
        valid = int(objects[(od.CAL_INFO, od.CAL_VALID_SUB)])
        crc_ok = od.block_crc(objects) == crc_stored
        return CalibrationReadout(
            od.CalibrationBlock.from_objects(objects), valid, crc_stored, crc_ok, objects, read
        )

    def store_supported(self, sub: int) -> bool:
        """Tell whether 0x1010:``sub`` exists and reports "save on command" (bit 0).

        A missing object or sub-index (abort 0x06020000 / 0x06090011) is False; any other
        abort or a silent node raises.
        """
        try:
            value = int(self.read_value(od.STORE, sub, "u32"))
        except SdoAbort as exc:
            if exc.code in (od.ABORT_NO_OBJECT, od.ABORT_NO_SUBINDEX):
                return False
            raise
        return bool(value & 1)

    def store(self, sub: int, timeout_s: float = DEFAULT_STORE_TIMEOUT_S) -> None:
        """Write 'save' to 0x1010:``sub`` once, waiting up to ``timeout_s`` for the answer.

        Never retried: a device that stores inside its SDO handler (CANopenNode erases
        flash there) may answer seconds late, and a second 'save' stores twice.
        Raises :class:`~canimucal.errors.StoreTimeoutError` when no answer comes in time.
        """
        self.sdo.download_once(od.STORE, sub, od.encode("u32", od.SAVE_SIGNATURE), timeout_s)

    def undo_ram_changes(self) -> None:
        """Write back what this client changed in the node's RAM besides the calibration.

        The output data rate (and with it the TPDO1/2 event timers), so that a store of
        every parameter (0x1010:01) keeps only the calibration the tool was asked to write.
        """
        if self._original_odr is not None:
            self.write_value(od.NOMINAL, 3, "u16", self._original_odr)
            self._original_odr = None

    def bus_load(self, *, full_window: bool = False) -> BusLoad:
        """Load of the bus over the last second, all frames seen (:mod:`~.busload`).

        ``full_window``: wait until the client has listened for a whole second first.
        """
        return self.bus_meter.load(full_window=full_window)

    # ----------------------------------------------------------------------- streaming
    def _on_foreign_sdo_request(self, can_id: int, data: bytearray, timestamp: float) -> None:
        """Count a request on 0x600+id: the bus never echoes our own, so it is not ours."""
        self.foreign_sdo_requests += 1
        self._answer_tally.on_foreign_request(data)

    def _on_foreign_nmt(self, can_id: int, data: bytearray, timestamp: float) -> None:
        """Count an NMT command for this node or all (the bus never echoes our own)."""
        if len(data) >= 2 and data[1] in (0, self.node_id):
            self.foreign_nmt_commands += 1

    @property
    def extra_sdo_answers(self) -> int:
        """SDO answers from the node beyond one per request seen (ours and others').

        Grows when a second device answers as this node-id (docs/design.md §9); compare it
        before and after a stretch of transfers. A lost answer makes it fall.
        """
        return self._answer_tally.surplus

    def answering_serials(self) -> list[int | None]:
        """Read the serial (0x1018:04) once and return what every answer said.

        One entry per device answering as this node-id (``None`` for an answer that was
        not a serial: an abort); empty when none answered within the SDO timeout. Answers
        to another client's requests meanwhile are not counted as a second device.
        """
        key = bytes([od.IDENTITY & 0xFF, od.IDENTITY >> 8, 4])
        started = time.monotonic() - self.sdo.timeout_s  # an earlier request's late answer
        answers = self.sdo.answers(od.IDENTITY, 4, ANSWER_WINDOW_FLOOR_S)
        ours = [a for a in answers if bytes(a[1:4]) == key]  # another object: not to us
        others = self._answer_tally.foreign_since(started, key)  # another client asked too
        if len(ours) - others <= 1:
            ours = ours[:1]
        return [
            int.from_bytes(a[4:8], "little") if a[0] & 0xE0 == UPLOAD_RESPONSE else None
            for a in ours
        ]

    def _boots(self) -> int:
        return self.heartbeat.boots

    @property
    def boots(self) -> int:
        """Boot-up frames seen from the node since the client was made."""
        return self.heartbeat.boots

    def watch_heartbeat(self, timeout_s: float | None = None) -> float:
        """Emit :class:`~canimucal.device.events.HeartbeatLost` after ``timeout_s`` of silence.

        Without ``timeout_s``: three producer-heartbeat periods (0x1017, read once).
        Returns the timeout used; :class:`DeviceError` if the node sends no heartbeat.
        """
        if timeout_s is None:
            period_ms = int(self.read_value(od.HEARTBEAT, 0, "u16"))
            if period_ms == 0:
                raise DeviceError(f"node {self.node_id} sends no heartbeat (0x1017 = 0)")
            timeout_s = 3.0 * period_ms / 1000.0
        self.heartbeat.watch(timeout_s)
        return timeout_s

    def resume_streaming(self) -> None:
        """NMT start the target node again (after a reboot put it in PRE-OPERATIONAL)."""
        if self._stream is None:
            raise DeviceError("not streaming: call start_streaming() first")
        self._nmt(NMT_START)

    def observe_nmt_state(self) -> NmtFound:
        """Find out (once) the NMT state the node is in now, to leave it so (docs/design.md §9)."""
        if self.nmt_found is None:
            self.nmt_found = infer_nmt_state(
                self.read_value,
                self.heartbeat.recent_state,
                self.network.subscribe,
                self.network.unsubscribe,
            )
            logger.info("node %d found %s", self.node_id, self.nmt_found.describe())
        return self.nmt_found

    def restore_nmt_state(self) -> None:
        """Put the node back into the NMT state it was found in, if this client changed it.

        Safe on every exit path (errors, Ctrl-C, SIGTERM, the TUI quitting): it sends at
        most one NMT command, to the target node only, and none when the state was unknown
        or this client never sent NMT. A failing bus is logged, not raised.
        """
        found = self.nmt_found
        if not self._nmt_sent or found is None or found.command is None:
            return
        try:
            self._nmt(found.command)
        except DeviceError as exc:
            logger.error("%s; node %d may not be %s", exc, self.node_id, found.state)
            return
        self._nmt_sent = False
        logger.info("node %d left %s", self.node_id, found.state)

    def reset_node(self) -> None:
        """NMT reset node to the target node only; :meth:`close` puts it back as found.

        The node restarts: unsaved values are lost and it boots with what it stored.
        """
        self.observe_nmt_state()
        self._nmt(NMT_RESET_NODE)

    def _nmt(self, command: int) -> None:
        """NMT command to the target node only; a failing bus is a DeviceError."""
        self._nmt_sent = True
        self.nmt_commands += 1
        try:
            self.node.nmt.send_command(command)
        except can.CanError as exc:
            raise DeviceError(
                f"cannot send NMT 0x{command:02X} to node {self.node_id}: {exc}"
            ) from exc

    @property
    def node_state(self) -> str | None:
        """NMT state the node last reported by heartbeat (None before any)."""
        return self.heartbeat.state

    @property
    def last_heartbeat_s(self) -> float | None:
        """CAN timestamp of the last heartbeat or boot-up frame."""
        return self.heartbeat.last_time_s

    def start_streaming(
        self,
        *,
        layout: SampleLayout | None = None,
        rate_hz: float | None = None,
        nmt_start: bool = True,
    ) -> SampleLayout:
        """Read the layout and ODR, subscribe TPDO1–3, then NMT start the target node only.

        ``layout``/``rate_hz`` skip the SDO reads (a known device); ``nmt_start=False``
        listens to a node someone else started. The NMT state is observed first: a node
        already OPERATIONAL gets no NMT, and one in an unknown state (SYNC-only TPDOs, no
        heartbeat) none either; :meth:`stop_streaming` puts it back as found.
        """
        if self._stream is not None:
            return self._stream.pairer.layout
        found = self.observe_nmt_state() if nmt_start else None  # before SYNC or NMT
        layout = self.pdo_mapping() if layout is None else layout
        rate = self.output_data_rate() if rate_hz is None else rate_hz
        period_s = 1.0 / max(rate, 1)
        pairer = SamplePairer(layout, period_s, clock=time.monotonic)
        self._stream = StreamConsumer(pairer, self.samples)
        for cob_id in self._stream.cob_ids():
            self.network.subscribe(cob_id, self._stream.on_frame)
        self.network.subscribe(HEARTBEAT_BASE + self.node_id, self._stream.on_boot)
        self._stream.start()
        if self.sync_producer:
            self.network.sync.start(self.sync_period_s)
        if found is not None and found.state not in (None, "OPERATIONAL"):
            try:
                self._nmt(NMT_START)
            except DeviceError:
                self.stop_streaming(keep_operational=True)
                raise
        return layout

    def stop_streaming(self, *, keep_operational: bool = False) -> None:
        """Leave the node in the NMT state it was found in and drain the stream.

        ``keep_operational``: send no NMT at all (the node stays as it is now).
        """
        stream, self._stream = self._stream, None
        if stream is None:
            return
        skew = stream.pairer.skew_ppm
        if stream.pairer.second_trigger:
            logger.warning(
                "node %d sends samples twice (duplicate sends, not a clock): a second send "
                "trigger, e.g. a TPDO event timer beside data-ready sending; set 0x1800:05 and "
                "0x1801:05 to 0 (docs/firmware.md §4)",
                self.node_id,
            )
        elif skew is not None and abs(skew) >= SKEW_NOTICE_PPM:
            logger.warning(
                "node %d: TPDO event timer %+.0f ppm off the sensor clock: the device %s",
                self.node_id,
                skew,
                "skipped counters (lost samples)" if skew > 0 else "re-sent counters",
            )
        if not keep_operational:
            self.restore_nmt_state()
        if self.sync_producer:
            self.network.sync.stop()
        for cob_id in stream.cob_ids():
            self.network.unsubscribe(cob_id, stream.on_frame)
        self.network.unsubscribe(HEARTBEAT_BASE + self.node_id, stream.on_boot)
        stream.stop()

    @property
    def skew_ppm(self) -> float | None:
        """TPDO event timer against the sensor clock while streaming, ppm (None: not yet).

        Positive: the timer is slow and the device skips counters (lost samples that no bus
        fault caused); negative: it is fast and re-sends counters (duplicates, not losses).
        """
        return self._stream.pairer.skew_ppm if self._stream is not None else None

    @property
    def second_send_trigger(self) -> bool:
        """Whether the node sends its samples twice while streaming (duplicate sends, not skew)."""
        return self._stream is not None and self._stream.pairer.second_trigger

    @property
    def consumer_thread(self) -> threading.Thread | None:
        """The decode/pairing thread while streaming."""
        return self._stream.thread if self._stream is not None else None

    def get_block(self, timeout_s: float | None = None) -> SampleBlock | None:
        """Return the next block of paired samples, or None if none came within ``timeout_s``."""
        try:
            return self.samples.get(timeout=timeout_s)
        except queue.Empty:
            return None

    def read_samples(self, n: int, timeout_s: float) -> SampleBlock:
        """At least ``n`` samples (blocks joined), or whatever came within ``timeout_s``."""
        blocks: list[SampleBlock] = []
        deadline = time.monotonic() + timeout_s
        while sum(b.n for b in blocks) < n:
            block = self.get_block(max(deadline - time.monotonic(), 0.0))
            if block is None:
                break
            blocks.append(block)
        return concat_blocks(blocks)

    def close(self) -> None:
        """Stop streaming and leave the NMT state as found; stop our own notifier.

        The node is removed from the network; the bus stays open. Idempotent (a signal
        handler and the normal exit path may both call it).
        """
        if self._closed:
            return
        self._closed = True
        self.stop_streaming()
        self.restore_nmt_state()
        self.heartbeat.unwatch()
        self.network.unsubscribe(HEARTBEAT_BASE + self.node_id, self.heartbeat.on_heartbeat)
        self.network.unsubscribe(EMCY_BASE + self.node_id, self.heartbeat.on_emergency)
        self.network.unsubscribe(SDO_REQUEST_BASE + self.node_id, self._on_foreign_sdo_request)
        self.network.unsubscribe(SDO_RESPONSE_BASE + self.node_id, self._answer_tally.on_response)
        self.network.unsubscribe(NMT_COB_ID, self._on_foreign_nmt)
        if self.network.notifier is not None:
            for listener in (self.heartbeat, self.bus_meter):
                try:
                    self.network.notifier.remove_listener(listener)
                except ValueError:
                    pass
        if self.node_id in self.network:
            del self.network[self.node_id]
        if self._owns_network and self.network.notifier is not None:
            self.network.notifier.stop(self.network.NOTIFIER_SHUTDOWN_TIMEOUT)

    def __enter__(self) -> ImuClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
