"""The transactional calibration write (docs/design.md §4) against both IMU nodes.

Every test with a node runs against the simulated and the independent durand node
(``device_kind``). Failures are injected: at the node, a hook before the write of one object
(:meth:`DeviceUnderTest.intercept_write`) that refuses it with an SDO abort, or mutes the
node's bus (it sends nothing more) mid-write; at the client, one read-back with a flipped bit.
"""

from __future__ import annotations

import re
import time
from collections.abc import Iterator
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import can
import canopen
import numpy as np
import pytest

from canimucal.device import od, transaction
from canimucal.device.calibration_map import (
    block_from_record,
    readback_of,
    record_from_readout,
)
from canimucal.device.client import ImuClient
from canimucal.device.transaction import (
    default_backup_dir,
    save_backup,
    write_calibration_transaction,
)
from canimucal.errors import DeviceError, InputError, RollbackIncompleteError
from canimucal.io.calibration import Calibration, calibration_to_dict, read_calibration
from canimucal.model.vocabulary.plans import PLANS
from canimucal.schema import to_plain
from tests.support.nodes import DeviceUnderTest, node_on

NODE_ID = 0x10
SERIAL = 777
ACCEL_LSB = 9.80665 / 2048.0
GYRO_LSB = float(np.pi / (180.0 * 16.4))
BACKUP_NAME = re.compile(r"^777-\d{8}T\d{6}\.\d{3}Z(-\d+)?\.json$")


class MuteableBus(can.BusABC):
    """The node's end of the bus; once ``muted`` it sends nothing (the node goes silent)."""

    def __init__(self, inner: can.BusABC) -> None:
        self._inner = inner
        self.muted = False
        self.channel_info = f"muteable({inner.channel_info})"
        super().__init__(channel="muteable")

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        if not self.muted:
            self._inner.send(msg, timeout)

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        return self._inner.recv(timeout), False

    def shutdown(self) -> None:
        super().shutdown()
        self._inner.shutdown()


@dataclass
class Rig:
    node: DeviceUnderTest
    node_bus: MuteableBus
    client: ImuClient
    spy: can.BusABC
    backups: Path

    def raw_objects(self) -> dict[tuple[int, int], bytes]:
        return self.node.raw_objects()

    def sdo_requests(self) -> list[bytes]:
        frames = []
        while (msg := self.spy.recv(0.02)) is not None:
            if msg.arbitration_id == 0x600 + NODE_ID:
                frames.append(bytes(msg.data))
        return frames


@pytest.fixture
def rig(bus_channel: str, tmp_path: Path, device_kind: str) -> Iterator[Rig]:
    buses = [can.Bus(interface="virtual", channel=bus_channel) for _ in range(3)]
    node_bus, client_net = MuteableBus(buses[0]), canopen.Network(buses[1])
    client_net.NOTIFIER_CYCLE = 0.05
    client_net.connect()
    node = node_on(
        device_kind,
        node_bus,
        NODE_ID,
        start=False,
        sim_options={"state_file": tmp_path / "nv.json", "seed": 2},
        serial=SERIAL,
    )
    client = ImuClient(client_net, NODE_ID, sdo_timeout_s=0.1, sdo_retries=1)
    node.start()
    assert client.find_node(1.0) == "boot-up"
    yield Rig(node, node_bus, client, buses[2], tmp_path / "backups")
    client.close()
    node.stop()
    assert client_net.notifier is not None
    client_net.notifier.stop()
    node_bus.shutdown()
    for bus in buses[1:]:
        bus.shutdown()


def calibration(serial: int = SERIAL, scale: float = 1.01, bias: float = 12.5) -> dict[str, Any]:
    """A calibration JSON dict close to nominal, with cross-axis terms and nulls."""
    k = np.diag([scale, -scale, 0.99]) / ACCEL_LSB
    k[0, 1] = 0.01 / ACCEL_LSB
    s = np.eye(3) * 1.02 / GYRO_LSB
    s[2, 0] = -0.005 / GYRO_LSB
    return {
        "schema": "canimucal.calibration/1",
        "created": "2026-03-04T05:06:07Z",
        "plan": "five",
        "device": {"node_id": NODE_ID, "serial": serial},
        "conditions": {"temp_c": 23.5},
        "accel": {"bias": [bias, -3.25, None], "K": k.tolist()},
        "gyro": {
            "bias": [1.0, 2.0, 3.0],
            "S": s.tolist(),
            "G": [[0.5, 0, 0], [0, 0, 0], [0, 0, 0]],
        },
        "base_tilt_deg": {"alpha0": 0.3, "beta0": -0.2},
        "fit": {"rms": 0.0012, "dof": 3},
    }


def test_block_from_record_inverts_and_fills_nominal() -> None:
    d = calibration()
    block = block_from_record(Calibration.from_dict(d), ACCEL_LSB, GYRO_LSB)
    np.testing.assert_allclose(
        block.accel_correction @ np.array(d["accel"]["K"]), np.eye(3), atol=1e-12
    )
    assert block.accel_bias[2] == 0.0  # null: nominal
    assert block.base_tilt_rad[0] == pytest.approx(np.deg2rad(0.3))
    assert block.plan_code == PLANS["five"].device_code
    assert block.time_unix_s == int(datetime(2026, 3, 4, 5, 6, 7, tzinfo=UTC).timestamp())
    assert (block.temp_c, block.rms_ms2) == (23.5, 0.0012)
    d["gyro"]["S"] = None
    assert np.allclose(
        block_from_record(Calibration.from_dict(d), ACCEL_LSB, GYRO_LSB).gyro_correction,
        np.eye(3) * GYRO_LSB,
    )
    d["accel"]["K"] = [[1, 2, 3], [2, 4, 6], [0, 0, 1]]
    with pytest.raises(InputError, match="singular"):
        block_from_record(Calibration.from_dict(d), ACCEL_LSB, GYRO_LSB)


def test_full_write_readback_bit_exact_valid_crc_stored(rig: Rig) -> None:
    before = rig.raw_objects()
    report = write_calibration_transaction(
        rig.client, Calibration.from_dict(calibration()), backup_dir=rig.backups
    )
    assert report.stored and not report.dry_run and report.backup_path is not None
    readout = rig.client.read_calibration_block()
    assert readout.valid == 1 and readout.crc_ok and readout.crc_stored == report.crc
    for write in report.writes[1:]:  # the first write is valid = 0, superseded by the last
        if (write.index, write.sub) in readout.raw:
            assert readout.raw[(write.index, write.sub)] == write.data, write.key
    assert rig.node.calibration_active()
    # the backup holds the device's previous set verbatim, under a never-reused name
    assert BACKUP_NAME.match(report.backup_path.name)
    backup = calibration_to_dict(read_calibration(report.backup_path))
    for (index, sub), raw in before.items():
        code = od.OBJECT_CODES[(index, sub)]
        assert od.encode(code, backup["objects"][od.format_key(index, sub)]) == raw
    # stored: survives a power cycle
    written = rig.raw_objects()
    rig.node.power_cycle()
    time.sleep(0.05)
    assert rig.raw_objects() == written
    rb = to_plain(readback_of(readout.block, readout.valid, readout.crc_ok))
    assert rb["valid"] == 1 and rb["crc_ok"] is True and len(rb["accel_correction"]) == 3


def test_no_store_is_lost_on_reboot(rig: Rig) -> None:
    before = rig.raw_objects()
    report = write_calibration_transaction(
        rig.client, Calibration.from_dict(calibration()), store=False, backup_dir=rig.backups
    )
    assert not report.stored
    assert not any(w.index == od.STORE for w in report.writes)
    rig.node.power_cycle()
    time.sleep(0.05)
    assert rig.raw_objects() == before


def test_serial_mismatch_refused_before_anything_is_written(rig: Rig) -> None:
    before = rig.raw_objects()
    rig.sdo_requests()  # discard what came before
    with pytest.raises(DeviceError, match="serial 777 differs .* 778; nothing written") as info:
        write_calibration_transaction(
            rig.client, Calibration.from_dict(calibration(serial=778)), backup_dir=rig.backups
        )
    assert info.value.exit_code == 3
    assert rig.raw_objects() == before
    downloads = [f for f in rig.sdo_requests() if f[0] & 0xE0 == 0x20]
    assert downloads == [] and not rig.backups.exists()


def test_force_writes_over_a_serial_mismatch(rig: Rig) -> None:
    report = write_calibration_transaction(
        rig.client,
        Calibration.from_dict(calibration(serial=778)),
        force=True,
        backup_dir=rig.backups,
    )
    assert report.serial_forced
    assert rig.client.read_calibration_block().valid == 1


def test_range_refusal_before_writing(rig: Rig) -> None:
    before = rig.raw_objects()
    bad = calibration(scale=3.0)  # M diagonal at 1/3 of nominal: outside ±50 %
    rig.sdo_requests()
    with pytest.raises(InputError, match="outside the device's ranges: 0x2101:01") as info:
        write_calibration_transaction(
            rig.client, Calibration.from_dict(bad), backup_dir=rig.backups
        )
    assert info.value.exit_code == 2
    assert rig.raw_objects() == before
    assert [f for f in rig.sdo_requests() if f[0] & 0xE0 == 0x20] == []
    assert not rig.backups.exists()


def test_dry_run_plans_and_writes_nothing(rig: Rig) -> None:
    before = rig.raw_objects()
    report = write_calibration_transaction(
        rig.client, Calibration.from_dict(calibration()), dry_run=True, backup_dir=rig.backups
    )
    assert report.dry_run and report.backup_path is None
    assert rig.raw_objects() == before and not rig.backups.exists()
    keys = [w.key for w in report.writes]
    assert keys[0] == "0x2121:05" and report.writes[0].value == 0
    order = od.crc_order(rig.node.trim)  # the independent node has no 0x2122
    assert keys[1 : 1 + len(order)] == [od.format_key(i, s) for i, s, _ in order]
    assert report.trim_object is rig.node.trim
    assert keys[-3:] == ["0x2121:06", "0x2121:05", "0x1010:04"]
    assert report.writes[-2].value == 1


def install_abort(node: DeviceUnderTest, key: tuple[int, int], code: int) -> list[int]:
    """Make the node refuse the next write of ``key`` (once: the rollback may write it)."""
    armed = [1]

    def refuse() -> int | None:
        if armed:
            armed.pop()
            return code
        return None

    node.intercept_write(key, refuse)
    return armed


def test_rollback_after_device_abort_restores_old_set(rig: Rig) -> None:
    write_calibration_transaction(
        rig.client, Calibration.from_dict(calibration()), backup_dir=rig.backups
    )
    old = rig.raw_objects()
    assert od.decode("u8", old[(od.CAL_INFO, od.CAL_VALID_SUB)]) == 1
    install_abort(rig.node, (od.GYRO_CORRECTION, 5), 0x06090030)
    with pytest.raises(DeviceError) as info:
        write_calibration_transaction(
            rig.client, Calibration.from_dict(calibration(bias=99.0)), backup_dir=rig.backups
        )
    message = str(info.value)
    assert not isinstance(info.value, RollbackIncompleteError)
    assert message.startswith("calibration write refused at write block: device refused write")
    assert "0x2111:05" in message and "0x06090030 value range of parameter exceeded" in message
    backups = sorted(rig.backups.iterdir())
    assert message.endswith(f"previous calibration restored from {backups[-1]}")
    assert rig.raw_objects() == old  # complete old set, valid as before
    assert rig.node.calibration_active()


def test_rollback_after_readback_mismatch(rig: Rig, monkeypatch: pytest.MonkeyPatch) -> None:
    """One read-back of 0x2100:02 (after it was written) comes back with a flipped bit."""
    old = rig.raw_objects()
    sdo = rig.client.sdo
    download, upload = sdo.download, sdo.upload
    state = {"written": False, "flipped": False}

    def spy_download(index: int, sub: int, data: bytes) -> None:
        state["written"] |= (index, sub) == (od.ACCEL_BIAS, 2)
        download(index, sub, data)

    def flipping_upload(index: int, sub: int) -> bytes:
        data = upload(index, sub)
        if state["written"] and not state["flipped"] and (index, sub) == (od.ACCEL_BIAS, 2):
            state["flipped"] = True
            return bytes([data[0] ^ 0x01]) + data[1:]
        return data

    monkeypatch.setattr(sdo, "download", spy_download)
    monkeypatch.setattr(sdo, "upload", flipping_upload)
    with pytest.raises(
        DeviceError, match=r"failed at verify block: 0x2100:02 read back .*"
    ) as info:
        write_calibration_transaction(
            rig.client, Calibration.from_dict(calibration()), backup_dir=rig.backups
        )
    assert "previous calibration restored from" in str(info.value)
    assert rig.raw_objects() == old


def test_rollback_impossible_when_node_goes_silent(rig: Rig) -> None:
    original = rig.raw_objects()

    def go_silent() -> None:
        rig.node_bus.muted = True

    remove_hook = rig.node.intercept_write((od.ACCEL_CORRECTION, 5), go_silent)
    with pytest.raises(RollbackIncompleteError) as info:
        write_calibration_transaction(
            rig.client, Calibration.from_dict(calibration()), backup_dir=rig.backups
        )
    (backup,) = list(rig.backups.iterdir())
    assert str(info.value) == (
        f"rollback incomplete; device invalidated; restore with canimucal write-params {backup}"
    )
    assert info.value.exit_code == 3
    assert rig.node.value(od.CAL_INFO, od.CAL_VALID_SUB) == 0  # never valid over a mix
    # the device answers again: the backup, given as the record, restores bit-exactly
    rig.node_bus.muted = False
    remove_hook()
    report = write_calibration_transaction(
        rig.client, read_calibration(backup), backup_dir=rig.backups
    )
    assert report.restore
    assert rig.raw_objects() == original


def test_backup_names_are_never_reused(rig: Rig, monkeypatch: pytest.MonkeyPatch) -> None:
    class Frozen(datetime):
        @classmethod
        def now(cls, tz: Any = None) -> Frozen:
            return cls(2026, 1, 2, 3, 4, 5, 678000, tzinfo=UTC)

    monkeypatch.setattr(transaction, "datetime", Frozen)
    readout = rig.client.read_calibration_block()
    identity = rig.client.identity()
    first = save_backup(readout, identity, NODE_ID, rig.backups)
    second = save_backup(readout, identity, NODE_ID, rig.backups)
    assert first.name == "777-20260102T030405.678Z.json"
    assert second.name == "777-20260102T030405.678Z-1.json"
    assert first.read_text() == second.read_text()


def test_default_backup_dir(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.setenv("XDG_STATE_HOME", "/x/state")
    assert default_backup_dir() == Path("/x/state/canimucal/backups")
    monkeypatch.delenv("XDG_STATE_HOME")
    monkeypatch.setenv("HOME", str(tmp_path))
    assert default_backup_dir() == tmp_path / ".local/state/canimucal/backups"


def test_backup_record_round_trip(rig: Rig, tmp_path: Path) -> None:
    write_calibration_transaction(
        rig.client, Calibration.from_dict(calibration()), backup_dir=rig.backups
    )
    readout = rig.client.read_calibration_block()
    record = record_from_readout(readout, rig.client.identity(), NODE_ID)
    d = calibration_to_dict(record)
    assert (d["device"]["serial"], d["device"]["node_id"]) == (SERIAL, NODE_ID)
    assert d["plan"] == "five" and d["created"] == "2026-03-04T05:06:07Z"
    assert d["objects"]["0x2121:05"] == 1
    assert len(d["objects"]) == len(od.calibration_objects(rig.node.trim))
    # without its objects map the record still maps back to the same block (M = K⁻¹ again)
    d.pop("objects")
    again = block_from_record(Calibration.from_dict(d), *rig.client.nominal_lsb())
    np.testing.assert_allclose(again.accel_correction, readout.block.accel_correction, rtol=1e-12)
    np.testing.assert_allclose(again.gyro_g, readout.block.gyro_g)
    assert again.base_tilt_rad == pytest.approx(readout.block.base_tilt_rad, rel=1e-12)
