"""ImuClient against both IMU nodes on python-can's virtual bus; bus settings.

Every test with a node runs against the simulated and the independent (durand) node
(``device_kind``); the tests without a node (no device, bus settings) run once.
"""

from __future__ import annotations

import time
import uuid
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import can
import canopen
import numpy as np
import pytest

from canimucal.device import od
from canimucal.device.bus import (
    DEFAULT_SDO_TIMEOUT_S,
    VM_SDO_TIMEOUT_S,
    BusSettings,
    default_sdo_timeout_s,
    open_bus,
)
from canimucal.device.client import ImuClient
from canimucal.errors import DeviceSilentError, InputError, NoDeviceError, SdoAbort
from canimucal.model.sensor import DEFAULT_ACCEL_LSB, DEFAULT_GYRO_LSB
from tests.support.nodes import DeviceUnderTest, node_on

NODE_ID = 0x10
SERIAL = 4242


class FilteringNetwork(canopen.Network):
    """A client-side network that drops received frames chosen by ``drop`` (a bus shim)."""

    def __init__(self, bus: can.BusABC) -> None:
        super().__init__(bus)
        self.drop = lambda can_id, data: False

    def notify(self, can_id: int, data: bytearray, timestamp: float) -> None:
        if not self.drop(can_id, bytes(data)):
            super().notify(can_id, data, timestamp)


@dataclass
class Rig:
    channel: str
    buses: list[can.BusABC]
    networks: list[canopen.Network]
    network: FilteringNetwork
    node: DeviceUnderTest
    client: ImuClient

    def bus(self) -> can.BusABC:
        bus = can.Bus(interface="virtual", channel=self.channel)
        self.buses.append(bus)
        return bus


def make_rig(tmp_path: Path, kind: str = "simulated", *, start_node: bool = True) -> Rig:
    channel = f"h6b-client-{uuid.uuid4().hex}"
    node_bus = can.Bus(interface="virtual", channel=channel)
    client_bus = can.Bus(interface="virtual", channel=channel)
    network = FilteringNetwork(client_bus)
    network.NOTIFIER_CYCLE = 0.05  # quick teardown
    network.connect()
    client = ImuClient(network, NODE_ID, sdo_timeout_s=0.3, sdo_retries=1)
    node = node_on(
        kind,
        node_bus,
        NODE_ID,
        start=start_node,
        sim_options={"state_file": tmp_path / "nv.json", "seed": 3},
        serial=SERIAL,
    )
    return Rig(channel, [node_bus, client_bus], [network], network, node, client)


def close_rig(rig: Rig) -> None:
    rig.client.close()
    rig.node.stop()
    for net in rig.networks:
        if net.notifier is not None:
            net.notifier.stop()
    for bus in rig.buses:
        bus.shutdown()


@pytest.fixture
def rig(tmp_path: Path, device_kind: str) -> Iterator[Rig]:
    rig = make_rig(tmp_path, device_kind)
    yield rig
    close_rig(rig)


# ----------------------------------------------------------------------- discovery


def test_find_node_sees_boot_up(tmp_path: Path, device_kind: str) -> None:
    rig = make_rig(tmp_path, device_kind, start_node=False)
    try:
        rig.node.start()  # boot-up 0x710 [00] after the client listens
        assert rig.client.find_node(1.0) == "boot-up"
        assert rig.client.node_state == "PRE-OPERATIONAL"
    finally:
        close_rig(rig)


def test_find_node_falls_back_to_sdo_probe(tmp_path: Path, device_kind: str) -> None:
    rig = make_rig(tmp_path, device_kind, start_node=False)
    rig.network.drop = lambda can_id, data: can_id == 0x700 + NODE_ID  # no boot-up/heartbeat
    try:
        rig.node.start()
        t0 = time.monotonic()
        assert rig.client.find_node(0.2) == "sdo"
        assert time.monotonic() - t0 >= 0.2  # listened the whole window first
        assert rig.client.last_heartbeat_s is None
    finally:
        close_rig(rig)


def test_find_node_without_node_is_no_device(tmp_path: Path) -> None:
    rig = make_rig(tmp_path, start_node=False)
    try:
        with pytest.raises(NoDeviceError, match="no CANopen node 16") as info:
            rig.client.find_node(0.1)
        assert info.value.exit_code == 4
    finally:
        close_rig(rig)


# ------------------------------------------------------------------ identity, mapping


def test_identity_nominal_lsb_and_rate(rig: Rig) -> None:
    identity = rig.client.identity()
    assert identity.serial == SERIAL
    assert identity.device_name  # 0x1008 is a non-empty VSTRING
    accel_lsb, gyro_lsb = rig.client.nominal_lsb()
    assert accel_lsb == pytest.approx(DEFAULT_ACCEL_LSB, rel=1e-7)  # REAL32 rounding
    assert gyro_lsb == pytest.approx(DEFAULT_GYRO_LSB, rel=1e-7)
    assert rig.client.output_data_rate() == 200


def test_pdo_mapping_decoded_from_node(rig: Rig) -> None:
    layout = rig.client.pdo_mapping()
    assert (layout.accel.cob_id, layout.gyro.cob_id) == (0x190, 0x290)
    assert layout.info is not None and layout.info.cob_id == 0x390
    assert [(f.index, f.sub, f.bits, f.signed) for f in layout.accel.fields] == [
        (0x2000, 1, 16, True),
        (0x2000, 2, 16, True),
        (0x2000, 3, 16, True),
        (0x2002, 2, 16, False),
    ]
    assert [f.offset_bits for f in layout.gyro.fields] == [0, 16, 32, 48]
    assert [(f.index, f.sub, f.bits) for f in layout.info.fields] == [
        (0x2002, 1, 16),
        (0x2002, 2, 16),
        (0x2002, 3, 8),
    ]


def test_factory_calibration_block(rig: Rig) -> None:
    readout = rig.client.read_calibration_block()
    accel_lsb, gyro_lsb = rig.client.nominal_lsb()
    assert readout.valid == 0 and readout.crc_ok
    factory = od.factory_block(accel_lsb, gyro_lsb)
    np.testing.assert_array_equal(readout.block.accel_correction, factory.accel_correction)
    np.testing.assert_array_equal(readout.block.gyro_bias, np.zeros(3))
    expected = od.calibration_objects(rig.node.trim)  # the independent node: no 0x2122
    assert set(readout.objects) == {(i, s) for i, s, _ in expected}
    assert readout.trim is rig.node.trim
    block, valid, crc_stored, crc_ok, objects, read = readout  # the bytes read come last
    assert read is not None and read == readout.raw
    assert crc_stored == od.block_crc(objects) and crc_ok and valid == 0
    assert readout.raw[(od.CAL_INFO, od.CAL_CRC_SUB)] == od.encode("u32", crc_stored)


# ------------------------------------------------------------------------ SDO policy


def test_sdo_abort_is_not_retried_and_names_the_code(rig: Rig) -> None:
    requests: list[bytes] = []
    spy = rig.bus()
    t0 = time.monotonic()
    with pytest.raises(SdoAbort, match="0x06010002") as info:
        rig.client.write_value(od.IDENTITY, 4, "u32", 1)  # read-only
    assert time.monotonic() - t0 < 0.3  # answered, no timeout, no backoff
    assert info.value.code == 0x06010002 and info.value.exit_code == 3
    while (msg := spy.recv(0.05)) is not None:
        if msg.arbitration_id == 0x600 + NODE_ID:
            requests.append(bytes(msg.data))
    assert len(requests) == 1  # one request, no retry


def test_sdo_timeout_retried_with_backoff(tmp_path: Path) -> None:
    rig = make_rig(tmp_path, start_node=False)
    client = ImuClient(rig.bus(), 0x22, sdo_timeout_s=0.1, sdo_retries=2)
    spy = rig.bus()
    try:
        t0 = time.monotonic()
        with pytest.raises(DeviceSilentError, match="after 3 tries"):
            client.read_value(od.IDENTITY, 1, "u32")
        elapsed = time.monotonic() - t0
        # 3 timeouts of 0.1 s and backoffs of 0.1 s + 0.2 s
        assert 0.6 <= elapsed < 1.5
        uploads = []
        while (msg := spy.recv(0.05)) is not None:
            if msg.arbitration_id == 0x622 and msg.data[0] == 0x40:
                uploads.append(bytes(msg.data))
        assert len(uploads) == 3
    finally:
        client.close()
        close_rig(rig)


# --------------------------------------------------------------- heartbeat, quiet bus


def test_heartbeat_state_and_nmt_to_target_only(rig: Rig) -> None:
    spy = rig.bus()
    rig.client.start_streaming()
    deadline = time.monotonic() + 2.5  # heartbeat period 1 s
    while rig.client.node_state != "OPERATIONAL" and time.monotonic() < deadline:
        time.sleep(0.05)
    assert rig.client.node_state == "OPERATIONAL"  # what the node reported, not what we sent
    rig.client.stop_streaming()
    nmt, sync = [], 0
    while (msg := spy.recv(0.05)) is not None:
        if msg.arbitration_id == 0:
            nmt.append(bytes(msg.data))
        sync += msg.arbitration_id == 0x80
    assert nmt == [bytes([0x01, NODE_ID]), bytes([0x80, NODE_ID])]  # never broadcast (id 0)
    assert sync == 0  # no SYNC unless sync_producer=True


# ---------------------------------------------------------------------- bus settings


def test_bus_settings_default_socketcan_with_channel(monkeypatch: pytest.MonkeyPatch) -> None:
    for name in ("CAN_INTERFACE", "CAN_CHANNEL", "CAN_BITRATE", "CAN_CONFIG"):
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setattr(can.util, "load_file_config", lambda path=None, section="default": {})
    config = BusSettings(channel="can7").resolve()
    assert config["interface"] == "socketcan" and config["channel"] == "can7"
    monkeypatch.setenv("CAN_INTERFACE", "virtual")
    assert BusSettings(channel="can7").resolve()["interface"] == "virtual"  # env names one
    assert BusSettings(interface="virtual", channel="x", bitrate=500000).resolve()["bitrate"] == (
        500000
    )


def test_bus_settings_environment_and_config_file(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    for name in ("CAN_INTERFACE", "CAN_CHANNEL", "CAN_BITRATE", "CAN_CONFIG"):
        monkeypatch.delenv(name, raising=False)
    conf = tmp_path / "can.conf"
    conf.write_text("[default]\ninterface = virtual\nchannel = from-file\nbitrate = 250000\n")
    config = BusSettings(config_path=str(conf)).resolve()
    assert (config["interface"], config["channel"], config["bitrate"]) == (
        "virtual",
        "from-file",
        250000,
    )
    monkeypatch.setenv("CAN_CHANNEL", "from-env")
    assert BusSettings(config_path=str(conf)).resolve()["channel"] == "from-env"
    assert BusSettings(channel="flag", config_path=str(conf)).resolve()["channel"] == "flag"


def test_open_bus_errors(monkeypatch: pytest.MonkeyPatch) -> None:
    for name in ("CAN_INTERFACE", "CAN_CHANNEL", "CAN_BITRATE", "CAN_CONFIG"):
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setattr(can.util, "load_file_config", lambda path=None, section="default": {})
    with pytest.raises(InputError, match="unknown CAN interface"):
        open_bus(BusSettings(interface="no-such-bus", channel="x"))
    with pytest.raises(NoDeviceError, match="no CAN bus configured"):
        open_bus(BusSettings())

    def refuse(**kwargs: object) -> can.BusABC:
        raise OSError(97, "Address family not supported by protocol")

    monkeypatch.setattr(can, "Bus", refuse)
    with pytest.raises(NoDeviceError, match="cannot open CAN bus socketcan/vcan9") as info:
        open_bus(BusSettings(channel="vcan9"))
    assert info.value.exit_code == 4 and "\n" not in str(info.value)


def test_open_bus_virtual_works() -> None:
    bus = open_bus(BusSettings(interface="virtual", channel=f"h6b-{uuid.uuid4().hex}"))
    try:
        assert isinstance(bus, can.BusABC)
    finally:
        bus.shutdown()


def test_sdo_timeout_defaults() -> None:
    assert default_sdo_timeout_s({}) == DEFAULT_SDO_TIMEOUT_S == 0.5
    assert default_sdo_timeout_s({"IN_CAN_VM": "1"}) == VM_SDO_TIMEOUT_S >= 2.0


def test_sync_only_when_asked(tmp_path: Path, device_kind: str) -> None:
    rig = make_rig(tmp_path, device_kind)
    client = ImuClient(rig.bus(), NODE_ID, sync_producer=True, sync_period_s=0.01)
    spy = rig.bus()
    try:
        client.start_streaming()
        time.sleep(0.3)
        client.stop_streaming()
        syncs = 0
        while (msg := spy.recv(0.05)) is not None:
            syncs += msg.arbitration_id == 0x80
        assert 10 <= syncs <= 45  # ~30 at 10 ms over 0.3 s, generous for a loaded machine
    finally:
        client.close()
        close_rig(rig)
