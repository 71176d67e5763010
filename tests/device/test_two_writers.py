"""Two SDO clients writing one node (issue 13, failure 1; docs/design.md §9 "Two writers").

During a write transaction any request on 0x600+id that this client did not send aborts it:
rolled back, exit 3, "another SDO client is using node N". Two writers whose transactions
overlap: at most one reports success and the device holds exactly its set, or the old set
with both told. Back-to-back writes both succeed.

Every test runs against both nodes (``device_kind``); the foreign request at random points
uses the synchronous loopback rig of test_write_faults (``either_loop_rig``).
"""

from __future__ import annotations

import json
import logging
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import can
import canopen
import numpy as np
import pytest

from canimucal.device import od
from canimucal.device.calibration_map import record_from_readout
from canimucal.device.client import ImuClient
from canimucal.device.transaction import WriteReport, write_calibration_transaction
from canimucal.errors import DeviceError, RollbackIncompleteError
from canimucal.io.calibration import Calibration, calibration_to_dict, calibration_to_json
from tests.device.test_write_faults import (
    NODE_ID,
    SERIAL,
    LoopRig,
    _old_and_new,
    calibration,
    either_loop_rig,  # noqa: F401  (a fixture)
)
from tests.support.nodes import DeviceUnderTest, node_on

FOREIGN = can.Message(arbitration_id=0x600 + NODE_ID, data=bytes([0x40, 0x18, 0x10, 4, 0, 0, 0, 0]))


def test_a_foreign_request_mid_write_rolls_back(either_loop_rig: LoopRig) -> None:  # noqa: F811
    rig = either_loop_rig
    old, _, n_requests = _old_and_new(rig)
    node_end = rig.node_end  # frames it sends reach the client, as another client's
    rng = np.random.default_rng(13)
    outcomes = set()
    for k in rng.integers(1, n_requests - 1, 12):
        rig.load(old)
        count = [0]

        def tap(msg: can.Message, k: int = int(k), count: list[int] = count) -> None:
            if msg.arbitration_id == 0x600 + NODE_ID:
                count[0] += 1
                if count[0] == k:
                    node_end.send(FOREIGN)

        taps = rig.faulty._inner.taps  # type: ignore[attr-defined]
        taps.append(tap)
        try:
            with pytest.raises(DeviceError) as raised:
                write_calibration_transaction(
                    rig.client,
                    Calibration.from_dict(calibration(0.97, -12.0)),
                    backup_dir=rig.backups,
                )
        finally:
            taps.remove(tap)
        message = str(raised.value)
        assert f"another SDO client is using node {NODE_ID}" in message
        assert raised.value.exit_code == 3
        assert rig.raw() == old, message
        outcomes.add("nothing written" if "nothing written" in message else "rolled back")
    assert outcomes == {"nothing written", "rolled back"}


@pytest.fixture
def two_clients(
    bus_channel: str, device_kind: str
) -> Iterator[tuple[DeviceUnderTest, list[ImuClient]]]:
    buses = [can.Bus(interface="virtual", channel=bus_channel) for _ in range(3)]
    networks = [canopen.Network(bus) for bus in buses[1:]]
    for net in networks:
        net.NOTIFIER_CYCLE = 0.05
        net.connect()
    node = node_on(
        device_kind, buses[0], NODE_ID, start=False, sim_options={"seed": 2}, serial=SERIAL
    )
    clients = [ImuClient(net, NODE_ID, sdo_timeout_s=0.2, sdo_retries=1) for net in networks]
    node.start()
    yield node, clients
    for client in clients:
        client.close()
    node.stop()
    for net in networks:
        assert net.notifier is not None
        net.notifier.stop()
    for bus in buses:
        bus.shutdown()


def _raw(node: DeviceUnderTest) -> dict[tuple[int, int], bytes]:
    return node.raw_objects()


def _holds(node: DeviceUnderTest, report: WriteReport) -> bool:
    final = {(w.index, w.sub): w.data for w in report.writes if w.index != od.STORE}
    raw = _raw(node)
    return all(raw[key] == data for key, data in final.items())


def test_overlapping_writers_never_both_succeed(
    two_clients: tuple[DeviceUnderTest, list[ImuClient]], tmp_path: Path
) -> None:
    node, clients = two_clients
    records = [Calibration.from_dict(calibration(s, b)) for s, b in ((1.03, 5.0), (0.98, -7.0))]
    # back to back: both succeed
    for client, record in zip(clients, records, strict=True):
        report = write_calibration_transaction(client, record, backup_dir=tmp_path, store=False)
        assert _holds(node, report)
        time.sleep(0.5)  # an SDO retry a loaded machine sends late belongs to this write
    tally: dict[str, int] = {}
    for _ in range(4):
        old = _raw(node)
        results: list[WriteReport | DeviceError | None] = [None, None]
        start = threading.Barrier(2)

        def write(
            i: int,
            results: list[WriteReport | DeviceError | None] = results,
            start: threading.Barrier = start,
        ) -> None:
            start.wait()
            try:
                results[i] = write_calibration_transaction(
                    clients[i], records[i], backup_dir=tmp_path, store=False
                )
            except DeviceError as exc:
                results[i] = exc

        threads = [threading.Thread(target=write, args=(i,)) for i in (0, 1)]
        for t in threads:
            t.start()
        for t in threads:
            t.join(60)
        done = [r for r in results if isinstance(r, WriteReport)]
        assert len(done) <= 1, "both writers reported success"
        state = _raw(node)
        valid = state[(od.CAL_INFO, od.CAL_VALID_SUB)]
        if done:
            assert _holds(node, done[0]), "success reported but the device holds another set"
        else:
            assert all(isinstance(r, DeviceError) for r in results)
            assert state == old or valid == b"\x00", "both told, yet a mixed set is valid"
        told = sum(f"another SDO client is using node {NODE_ID}" in str(r) for r in results)
        key = f"{len(done)} ok, {told} told of the other"
        tally[key] = tally.get(key, 0) + 1
    print(f"\noverlapping writers: {tally}")


def test_backup_with_mismatched_crc_is_restored_invalid(
    two_clients: tuple[DeviceUnderTest, list[ImuClient]],
    tmp_path: Path,
    caplog: pytest.LogCaptureFixture,
) -> None:
    node, (client, _) = two_clients
    write_calibration_transaction(
        client, Calibration.from_dict(calibration(1.02, 3.0)), backup_dir=tmp_path, store=False
    )
    readout = client.read_calibration_block()
    backup = calibration_to_dict(record_from_readout(readout, client.identity(), NODE_ID))
    assert backup["objects"]["0x2121:05"] == 1
    backup["objects"]["0x2100:01"] += 1.0  # edited (or taken mid-write): CRC no longer matches
    with caplog.at_level(logging.WARNING):
        report = write_calibration_transaction(
            client, Calibration.from_dict(backup), backup_dir=tmp_path, store=False
        )
    assert report.restore and report.valid == 0
    assert "does not match its values (0x" in caplog.text
    assert "restored with valid = 0, nominal values apply" in caplog.text
    after = client.read_calibration_block()
    assert (
        after.valid == 0 and not after.crc_ok and after.crc_stored == backup["objects"]["0x2121:06"]
    )
    assert after.objects[(0x2100, 1)] == backup["objects"]["0x2100:01"]
    # a valid = 0 backup is restored as it is
    invalid = calibration_to_dict(record_from_readout(after, client.identity(), NODE_ID))
    report = write_calibration_transaction(
        client, Calibration.from_dict(invalid), backup_dir=tmp_path, store=False
    )
    assert report.valid == 0 and client.read_calibration_block().raw == after.raw


def test_device_holding_nan_is_backed_up_raw_and_recalibrated(
    two_clients: tuple[DeviceUnderTest, list[ImuClient]], tmp_path: Path
) -> None:
    node, (client, _) = two_clients
    write_calibration_transaction(
        client, Calibration.from_dict(calibration(1.02, 3.0)), backup_dir=tmp_path, store=False
    )
    nan = bytes.fromhex("0100c0ff")  # a NaN with a payload and the sign bit
    node.poke(0x2100, 1, nan)  # past the node's own checks
    readout = client.read_calibration_block()
    backup = record_from_readout(readout, client.identity(), NODE_ID)
    assert backup.objects_raw == {"0x2100:01": "0100c0ff"}
    assert backup.objects is not None and "0x2100:01" not in backup.objects
    again = Calibration.from_dict(json.loads(calibration_to_json(backup)))  # JSON holds it
    assert again.objects_raw == backup.objects_raw
    # recalibration works: the backup (with the NaN's bytes) is written first
    report = write_calibration_transaction(
        client, Calibration.from_dict(calibration(0.99, -2.0)), backup_dir=tmp_path, store=False
    )
    assert report.valid == 1 and _holds(node, report)
    assert report.backup_path is not None
    saved = json.loads(report.backup_path.read_text())
    assert saved["objects_raw"] == {"0x2100:01": "0100c0ff"}
    # its restore plan writes the NaN's exact bytes and ends valid = 0
    planned = write_calibration_transaction(
        client, Calibration.from_dict(saved), backup_dir=tmp_path, dry_run=True
    )
    assert planned.valid == 0
    assert [w.data for w in planned.writes if (w.index, w.sub) == (0x2100, 1)] == [nan]


def test_rollback_to_non_finite_values_ends_invalid(
    two_clients: tuple[DeviceUnderTest, list[ImuClient]],
    tmp_path: Path,
    caplog: pytest.LogCaptureFixture,
) -> None:
    node, (client, _) = two_clients
    write_calibration_transaction(
        client, Calibration.from_dict(calibration(1.02, 3.0)), backup_dir=tmp_path, store=False
    )
    nan = bytes.fromhex("0100c0ff")
    node.poke(0x2100, 1, nan)
    # refused once inside "write block", after the backup: the rollback follows
    armed = [0x08000020]
    node.intercept_write((od.GYRO_CORRECTION, 5), lambda: armed.pop() if armed else None)
    with caplog.at_level(logging.WARNING), pytest.raises(DeviceError) as raised:
        write_calibration_transaction(
            client, Calibration.from_dict(calibration(0.99, -2.0)), backup_dir=tmp_path, store=False
        )
    assert not armed  # the refusal fired
    after = client.read_calibration_block()
    assert after.valid == 0, raised.value
    assert "non-finite values in 0x2100:01: left valid = 0" in caplog.text
    # this node refuses NaN downloads (range check), so the rollback cannot finish: it says
    # so and names the backup; a device taking them back would end valid = 0 all the same
    assert isinstance(raised.value, RollbackIncompleteError), raised.value
    assert "restore with canimucal write-params" in str(raised.value)
