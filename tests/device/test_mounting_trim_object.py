"""The mounting trim on the device (docs/design.md §4): 0x2122, its CRC layout, old nodes.

Against the simulated node with 0x2122 (``trim``) and one configured as a firmware before it
(``legacy``: truth ``trim_object`` false; its upload of 0x2122 aborts with "object does not
exist"), on python-can's virtual bus. The trim is written, read back bit-exactly, covered by
the CRC (a flipped trim byte closes the node's gate and fails the client's CRC check) and
survives a restore (backup → write → restore → read back); a legacy node is written without
it in the 39-object layout, with a warning; backups move between the layouts or are refused.
"""

from __future__ import annotations

import logging
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import can
import canopen
import numpy as np
import pytest

from canimucal.device import od
from canimucal.device.calibration_map import record_from_readout
from canimucal.device.client import ImuClient
from canimucal.device.transaction import write_calibration_transaction
from canimucal.errors import InputError, SdoAbort
from canimucal.io.calibration import Calibration
from tests.support.nodes import DeviceUnderTest, node_on

NODE_ID = 0x10
SERIAL = 2122
ACCEL_LSB = 9.80665 / 2048.0
GYRO_LSB = float(np.pi / (180.0 * 16.4))
TRIM_DEG = (1.25, -0.75, 1.8)


@dataclass
class Rig:
    node: DeviceUnderTest
    client: ImuClient
    backups: Path


def _rig(kind: str, channel: str, tmp_path: Path) -> Iterator[Rig]:
    node_bus = can.Bus(interface="virtual", channel=channel)
    client_net = canopen.Network(can.Bus(interface="virtual", channel=channel))
    client_net.NOTIFIER_CYCLE = 0.05
    client_net.connect()
    behaviour: dict[str, Any] = {"serial": SERIAL}
    if kind == "legacy":
        behaviour["trim_object"] = False
    node = node_on("simulated", node_bus, NODE_ID, start=False, **behaviour)
    client = ImuClient(client_net, NODE_ID, sdo_timeout_s=0.2, sdo_retries=1)
    node.start()
    assert client.find_node(1.0) == "boot-up"
    yield Rig(node, client, tmp_path / "backups")
    client.close()
    node.stop()
    client_net.disconnect()
    node_bus.shutdown()


@pytest.fixture(params=["trim", "legacy"])
def rig(request: pytest.FixtureRequest, bus_channel: str, tmp_path: Path) -> Iterator[Rig]:
    yield from _rig(str(request.param), bus_channel, tmp_path)


@pytest.fixture
def trim_rig(bus_channel: str, tmp_path: Path) -> Iterator[Rig]:
    yield from _rig("trim", bus_channel, tmp_path)


@pytest.fixture
def legacy_rig(bus_channel: str, tmp_path: Path) -> Iterator[Rig]:
    yield from _rig("legacy", bus_channel, tmp_path)


def calibration(
    trim_deg: tuple[float, float, float] | None = TRIM_DEG, bias: float = 4.0
) -> Calibration:
    document: dict[str, Any] = {
        "schema": "canimucal.calibration/1",
        "created": "2026-05-06T07:08:09Z",
        "plan": "vehicle",
        "device": {"node_id": NODE_ID, "serial": SERIAL},
        "accel": {"bias": [bias, -2.0, 1.5], "K": (np.eye(3) * 1.004 / ACCEL_LSB).tolist()},
        "base_tilt_deg": {"alpha0": 1.5, "beta0": -2.5},
    }
    if trim_deg is not None:
        alpha, beta, psi = trim_deg
        document["mounting_trim_deg"] = {
            "alpha": alpha,
            "beta": beta,
            "psi": psi,
            "sigma": [0.6, 0.6, 1.5],
        }
    return Calibration.from_dict(document)


def _trim_bytes(rig: Rig) -> list[bytes]:
    return [rig.client.read_raw(i, s, "f32") for i, s in od.TRIM_KEYS]


def test_the_trim_is_written_read_back_bit_exactly_and_the_node_applies_it(trim_rig: Rig) -> None:
    report = write_calibration_transaction(
        trim_rig.client, calibration(), backup_dir=trim_rig.backups
    )
    assert report.trim_object and report.trim_written
    wanted = [od.encode("f32", float(np.deg2rad(t))) for t in TRIM_DEG]
    assert _trim_bytes(trim_rig) == wanted  # bit for bit, REAL32 radians
    readout = trim_rig.client.read_calibration_block()
    assert readout.trim and readout.valid == 1 and readout.crc_ok
    assert readout.crc_stored == od.block_crc(readout.objects, trim=True)
    assert readout.crc_stored != od.block_crc(readout.objects, trim=False)
    assert trim_rig.node.calibration_active()
    block = readout.block
    assert block.mounting_trim_rad is not None
    np.testing.assert_array_equal(block.mounting_trim_rad, [od.decode("f32", b) for b in wanted])


def test_a_flipped_trim_byte_fails_the_crc_on_the_node_and_in_the_client(trim_rig: Rig) -> None:
    write_calibration_transaction(trim_rig.client, calibration(), backup_dir=trim_rig.backups)
    assert trim_rig.node.calibration_active()
    index, sub = od.TRIM_KEYS[1]
    data = bytearray(trim_rig.client.read_raw(index, sub, "f32"))
    data[0] ^= 0x01  # one bit of the mantissa: 1e-7 of the angle, a value in range
    trim_rig.client.sdo.download(index, sub, bytes(data))
    readout = trim_rig.client.read_calibration_block()
    assert readout.valid == 1 and not readout.crc_ok
    assert not trim_rig.node.calibration_active()


def test_the_trim_survives_a_restore(trim_rig: Rig) -> None:
    write_calibration_transaction(trim_rig.client, calibration(), backup_dir=trim_rig.backups)
    before = trim_rig.node.raw_objects()
    report = write_calibration_transaction(
        trim_rig.client, calibration((-0.5, 0.25, -1.0), bias=9.0), backup_dir=trim_rig.backups
    )
    assert report.backup_path is not None and trim_rig.node.raw_objects() != before
    backup = Calibration.from_json(report.backup_path)
    assert backup.mounting_trim_deg is not None
    assert backup.mounting_trim_deg.alpha == pytest.approx(TRIM_DEG[0], abs=1e-5)
    restored = write_calibration_transaction(trim_rig.client, backup, backup_dir=trim_rig.backups)
    assert restored.restore and restored.valid == 1
    assert trim_rig.node.raw_objects() == before  # every byte, the trim's, valid and CRC too
    assert trim_rig.client.read_calibration_block().crc_ok


def test_a_node_without_the_object_keeps_the_39_object_crc(
    legacy_rig: Rig, caplog: pytest.LogCaptureFixture
) -> None:
    rig = legacy_rig
    with pytest.raises(SdoAbort) as info:
        rig.client.read_raw(*od.TRIM_KEYS[0], "f32")
    assert info.value.code == od.ABORT_NO_OBJECT
    assert not rig.client.has_trim_object()
    factory = rig.client.read_calibration_block()
    assert not factory.trim and factory.crc_stored == 0x88E40123  # the old factory vector
    with caplog.at_level(logging.WARNING):
        report = write_calibration_transaction(rig.client, calibration(), backup_dir=rig.backups)
    assert not report.trim_object and not report.trim_written
    assert "mounting trim was not written" in caplog.text
    readout = rig.client.read_calibration_block()
    assert set(readout.objects) == {(i, s) for i, s, _ in od.calibration_objects(False)}
    assert readout.valid == 1 and readout.crc_ok
    assert readout.crc_stored == od.block_crc(readout.objects, trim=False)
    assert rig.node.calibration_active()


def _backup_of(kind: str, record: Calibration, channel: str, tmp_path: Path) -> Calibration:
    """A backup (objects and all) of a node of ``kind`` holding ``record``."""
    source = _rig(kind, channel, tmp_path)
    other = next(source)
    try:
        write_calibration_transaction(other.client, record, backup_dir=other.backups)
        readout = other.client.read_calibration_block()
        return record_from_readout(readout, other.client.identity(), NODE_ID)
    finally:
        next(source, None)


def test_backups_move_between_the_layouts_or_are_refused(rig: Rig, tmp_path: Path) -> None:
    """A backup of the other layout: a zero trim is added or dropped with the CRC recomputed;
    a non-zero trim onto a node without 0x2122 is refused before anything is written."""
    other = "legacy" if rig.node.trim else "trim"
    channel = f"{other}-{tmp_path.name}"
    backup = _backup_of(other, calibration((0.0, 0.0, 0.0)), channel, tmp_path / other)
    assert (backup.mounting_trim_deg is not None) is (other == "trim")
    restored = write_calibration_transaction(rig.client, backup, backup_dir=rig.backups)
    assert restored.restore and restored.valid == 1
    readout = rig.client.read_calibration_block()
    assert readout.trim is rig.node.trim and readout.valid == 1 and readout.crc_ok
    assert rig.node.calibration_active()
    if rig.node.trim:
        assert _trim_bytes(rig) == [od.encode("f32", 0.0)] * 3
        return
    trimmed = _backup_of(other, calibration(), channel + "-2", tmp_path / "trimmed")
    before = rig.node.raw_objects()
    with pytest.raises(InputError, match="mounting trim .* does not have"):
        write_calibration_transaction(rig.client, trimmed, backup_dir=rig.backups)
    assert rig.node.raw_objects() == before
