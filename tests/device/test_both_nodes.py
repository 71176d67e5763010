"""The client and ``write-params`` against both IMU nodes: python-canopen's and durand's.

Each test runs once per node kind (``device_kind``, tests/support/nodes.py) unless a
behaviour exists in one node only. The store scenarios are those of CANopenNode devices
(docs/design.md §9 "Device behaviour"): a store that blocks the SDO answer for seconds, storage
without 0x1010:04, a store that answers after the tool gave up.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import canopen
import numpy as np
import pytest

from canimucal.cli.main import main
from canimucal.device import od
from canimucal.device.client import ImuClient
from canimucal.errors import DeviceError
from canimucal.simnode.node import SimulatedImuNode
from tests.support.canbus import NODE_ID
from tests.support.independent_node import IndependentImuNode
from tests.support.nodes import DeviceUnderTest

MakeDevice = Callable[..., DeviceUnderTest]
TIMEOUT_MESSAGE = (
    "store not confirmed in {t} s; RAM holds the new set (valid, CRC ok); what flash holds "
    "is known only after a power cycle"
)


@pytest.fixture
def client(client_network: canopen.Network) -> ImuClient:
    return ImuClient(client_network, NODE_ID, sdo_timeout_s=1.0)


@pytest.fixture
def cal_file(tmp_path: Path) -> Path:
    """A calibration for serial 0 (both nodes' default) within every device range."""
    lsb = float(np.float32(9.80665 / 2048.0))
    document = {
        "schema": "canimucal.calibration/1",
        "plan": "five",
        "device": {"serial": 0},
        "accel": {"bias": [3.0, -2.5, 1.25], "K": np.diag([1.01, 0.99, 1.002]) / lsb},
        "gyro": {"bias": [0.5, -0.25, 2.0]},
        "base_tilt_deg": {"alpha0": 0.2, "beta0": -0.1},
    }
    document["accel"]["K"] = document["accel"]["K"].tolist()  # type: ignore[index]
    path = tmp_path / "cal.json"
    path.write_text(json.dumps(document))
    return path


def write_params(
    capsys: pytest.CaptureFixture[str], channel: str, cal: Path, *extra: Any
) -> tuple[int, str, str]:
    argv: Sequence[str] = [
        "write-params",
        str(cal),
        "--interface",
        "virtual",
        "--channel",
        channel,
        "--sdo-timeout",
        "1",
        "--backup-dir",
        str(cal.parent / "backups"),
        *map(str, extra),
    ]
    capsys.readouterr()
    code = main(list(argv))
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def test_client_reads_identity_and_streams_paired_samples(
    make_device: MakeDevice, client: ImuClient
) -> None:
    device = make_device()
    assert client.find_node(1.0) in ("boot-up", "heartbeat", "sdo")
    assert client.identity().serial == 0
    accel_lsb, _ = client.nominal_lsb()
    assert accel_lsb == pytest.approx(9.80665 / 2048.0, rel=1e-6)
    layout = client.start_streaming()
    try:
        block = client.read_samples(100, timeout_s=5.0)
    finally:
        client.stop_streaming()
    assert layout is not None and block.n >= 100
    gravity_counts = float(np.linalg.norm(np.mean(block.accel, axis=0)))
    assert gravity_counts == pytest.approx(2048.0, rel=0.05), device.kind


def test_out_of_range_write_is_refused_by_either_node(
    make_device: MakeDevice, client: ImuClient
) -> None:
    make_device()
    with pytest.raises(Exception) as info:
        client.write_value(od.ACCEL_BIAS, 1, "f32", 1e6)
    assert getattr(info.value, "code", None) == od.ABORT_VALUE_RANGE
    assert client.read_value(od.ACCEL_BIAS, 1, "f32") == 0.0


def test_write_params_stores_with_sub_4_and_survives_power_cycle(
    make_device: MakeDevice, capsys: pytest.CaptureFixture[str], bus_channel: str, cal_file: Path
) -> None:
    device = make_device()
    code, out, err = write_params(capsys, bus_channel, cal_file)
    assert code == 0, err
    assert "stored (0x1010:04)" in out
    assert device.store_log == [od.STORE_CALIBRATION_SUB]
    device.power_cycle()
    assert device.calibration_valid()
    assert device.value(od.ACCEL_BIAS, 1) == pytest.approx(3.0)


def test_serial_refusal_and_backup_restore(
    make_device: MakeDevice, capsys: pytest.CaptureFixture[str], bus_channel: str, cal_file: Path
) -> None:
    device = make_device()
    other = cal_file.with_name("other.json")
    document = json.loads(cal_file.read_text())
    other.write_text(json.dumps(document | {"device": {"serial": 99}}))
    code, _, err = write_params(capsys, bus_channel, other)
    assert code == 3 and "differs from the calibration file's 99; nothing written" in err
    assert device.store_log == [] and not device.calibration_valid()
    code, out, err = write_params(capsys, bus_channel, cal_file)
    assert code == 0, err
    backup = next((cal_file.parent / "backups").glob("*.json"))  # the factory set
    code, out, err = write_params(capsys, bus_channel, backup)
    assert code == 0, err
    assert "restore of a backup" in out and not device.calibration_valid()
    assert device.value(od.ACCEL_BIAS, 1) == 0.0 and device.store_log == [4, 4]


def test_slow_store_dropping_frames_ends_exit_0_stored_once(
    make_device: MakeDevice, capsys: pytest.CaptureFixture[str], bus_channel: str, cal_file: Path
) -> None:
    # CANopenNode erases flash inside the SDO handler; both nodes drop their TPDOs meanwhile
    # (store_pdo_mode "drop", the default; the independent node its heartbeat too)
    device = make_device(store_delay_s=2.5, nmt_start="operational")  # TPDOs flowing
    started = time.monotonic()
    code, out, err = write_params(capsys, bus_channel, cal_file)
    assert code == 0, err
    assert time.monotonic() - started >= 2.5
    assert "stored (0x1010:04)" in out and "restored" not in out + err
    assert device.store_log == [od.STORE_CALIBRATION_SUB]  # once: never retried
    assert device.dropped_in_store > 100  # 2.5 s of TPDOs lost
    assert device.nmt_state == "OPERATIONAL"  # write-params sends no NMT


def test_slow_store_queueing_frames_ends_exit_0_stored_once(
    make_device: MakeDevice, capsys: pytest.CaptureFixture[str], bus_channel: str, cal_file: Path
) -> None:
    # frames held back during the store and sent as a burst after it
    device = make_device(store_delay_s=1.0, store_pdo_mode="queue", nmt_start="operational")
    code, out, err = write_params(capsys, bus_channel, cal_file)
    assert code == 0, err
    assert "stored (0x1010:04)" in out and "restored" not in out + err
    assert device.store_log == [od.STORE_CALIBRATION_SUB]
    assert device.dropped_in_store == 0
    if isinstance(device.node, SimulatedImuNode):
        assert device.node.frames_queued_in_store > 200  # 1 s of TPDO1/2 at 200 Hz, late


def test_node_without_sub_4_is_stored_through_sub_1(
    make_device: MakeDevice, capsys: pytest.CaptureFixture[str], bus_channel: str, cal_file: Path
) -> None:
    device = make_device(storage_subs=(1, 2, 3))  # stock CANopenNode storage groups
    code, out, err = write_params(capsys, bus_channel, cal_file)
    assert code == 0, err
    assert "stored (0x1010:01)" in out
    assert device.store_log == [od.STORE_ALL_SUB]
    device.power_cycle()
    assert device.calibration_valid()


def test_sub_3_only_when_asked_and_nothing_written_without_a_group(
    make_device: MakeDevice,
    capsys: pytest.CaptureFixture[str],
    bus_channel: str,
    cal_file: Path,
    caplog: pytest.LogCaptureFixture,
) -> None:
    device = make_device(storage_subs=(2, 3))
    code, _, err = write_params(capsys, bus_channel, cal_file)
    assert code == 3 and "offers no 0x1010:01" in err
    assert not device.calibration_valid() and device.store_log == []
    assert not list((cal_file.parent / "backups").glob("*.json"))  # refused before step 3
    code, out, err = write_params(capsys, bus_channel, cal_file, "--store-sub", "3")
    assert code == 0, err
    assert "stored (0x1010:03)" in out and device.store_log == [od.STORE_APP_SUB]
    assert any("0x1010:03" in r.getMessage() for r in caplog.records if r.levelname == "WARNING")


def test_store_timeout_is_not_retried_nor_rolled_back(
    make_device: MakeDevice, capsys: pytest.CaptureFixture[str], bus_channel: str, cal_file: Path
) -> None:
    device = make_device(store_delay_s=1.5)
    code, _, err = write_params(capsys, bus_channel, cal_file, "--store-timeout-s", "0.5")
    assert code == 3
    assert TIMEOUT_MESSAGE.format(t="0.5") in err
    assert "restored" not in err and "rollback" not in err
    deadline = time.monotonic() + 3.0
    while not device.store_log and time.monotonic() < deadline:
        time.sleep(0.05)
    time.sleep(0.3)
    assert device.store_log == [od.STORE_CALIBRATION_SUB]  # the one late store, no second
    assert device.calibration_valid()  # RAM keeps the new set: nothing rolled back
    device.power_cycle()
    assert device.calibration_valid()  # and the late store did reach flash


# -- NMT left as found (docs/design.md §9) --------------------------------------------------------


@pytest.mark.parametrize(
    ("behaviour", "found", "source"),
    [
        ({}, "PRE-OPERATIONAL", "heartbeat"),
        ({"nmt_start": "operational"}, "OPERATIONAL", "heartbeat"),
        ({"nmt_start": "operational", "heartbeat_ms": 0}, "OPERATIONAL", "tpdo"),
        ({"heartbeat_ms": 0}, "PRE-OPERATIONAL", "sdo"),
    ],
)
def test_streaming_leaves_the_node_in_the_state_found(
    make_device: MakeDevice,
    client: ImuClient,
    behaviour: dict[str, Any],
    found: str,
    source: str,
) -> None:
    device = make_device(**behaviour)
    client.start_streaming()
    try:
        assert client.read_samples(50, timeout_s=5.0).n >= 50
        assert device.nmt_state == "OPERATIONAL"
    finally:
        client.close()
    assert client.nmt_found is not None
    assert (client.nmt_found.state, client.nmt_found.source) == (found, source)
    assert device.nmt_state == found


def test_sync_only_node_without_heartbeat_gets_no_nmt(
    make_device: MakeDevice, client: ImuClient
) -> None:
    device = make_device(sync_pdos=True, heartbeat_ms=0)  # skipped for the simulated node
    client.start_streaming()
    client.close()
    assert client.nmt_found is not None and client.nmt_found.state is None
    assert device.nmt_state == "PRE-OPERATIONAL"  # never started: no NMT was sent at all


def test_sync_pdos_stream_paired_samples_on_the_clients_sync(
    make_device: MakeDevice, client_network: canopen.Network
) -> None:
    make_device(sync_pdos=True, nmt_start="operational")  # transmission type 1: every SYNC
    client = ImuClient(client_network, NODE_ID, sdo_timeout_s=1.0, sync_producer=True)
    assert [client.read_value(0x1800 + i, 2, "u8") for i in range(3)] == [1, 1, 1]
    client.start_streaming()
    try:
        block = client.read_samples(100, timeout_s=5.0)
    finally:
        client.close()
    assert block.n >= 100 and block.lost_accel == block.lost_gyro == 0
    assert float(np.linalg.norm(np.nanmean(block.accel, axis=0))) == pytest.approx(2048, rel=0.05)


def test_read_params_leaves_an_operational_node_operational(
    make_device: MakeDevice, capsys: pytest.CaptureFixture[str], bus_channel: str, tmp_path: Path
) -> None:
    device = make_device(nmt_start="operational", heartbeat_ms=0)
    argv = ["read-params", "--interface", "virtual", "--channel", bus_channel]
    code = main([*argv, "--json", str(tmp_path / "r.json")])
    assert code == 0, capsys.readouterr().err
    assert device.nmt_state == "OPERATIONAL"


# -- TPDO timing and mapping -----------------------------------------------------------------


@pytest.mark.parametrize("skew_ppm", [5000.0, -5000.0])
def test_timer_skew_is_reported_and_repeats_are_not_losses(
    make_device: MakeDevice, client: ImuClient, skew_ppm: float
) -> None:
    # the event timer 0.5 % off the sensor clock (both nodes): slow skips a
    # counter every 200 frames, fast re-sends one; 3 s at 200 Hz is ~600 frames
    make_device(timer_skew_ppm=skew_ppm, nmt_start="operational")
    client.start_streaming()
    try:
        block = client.read_samples(600, timeout_s=6.0)
        skew = client.skew_ppm
    finally:
        client.close()
    assert skew is not None and abs(skew - skew_ppm) < 2500, skew
    expected_skips = block.n * skew_ppm * 1e-6
    if skew_ppm < 0:
        assert block.lost_samples == 0 and block.lost_accel == block.lost_gyro == 0
        assert block.duplicates >= 2  # repeated pairs: both halves again
    else:
        assert block.duplicates == 0
        assert block.lost_samples <= expected_skips + 3  # the device's skips, nothing more


def test_no_skew_reads_near_zero(make_device: MakeDevice, client: ImuClient) -> None:
    make_device(nmt_start="operational")
    client.start_streaming()
    try:
        block = client.read_samples(400, timeout_s=5.0)
        skew = client.skew_ppm
    finally:
        client.close()
    assert block.lost_samples == 0 and skew is not None and abs(skew) < 2500, skew


def test_mapping_longer_than_8_bytes_is_refused(
    make_independent_node: Callable[..., IndependentImuNode], client_network: canopen.Network
) -> None:
    node = make_independent_node()
    with node.lock:  # durand accepts a 12-byte mapping (and would send 12-byte frames)
        node.node.tpdo[0].mapping = [
            (0x2000, 1),
            (0x2000, 2),
            (0x2000, 3),
            (0x2002, 2),
            (0x2100, 1),
        ]
    client = ImuClient(client_network, NODE_ID, sdo_timeout_s=1.0)
    with pytest.raises(DeviceError, match="96 bits .12 bytes.; a classic CAN frame holds 8"):
        client.start_streaming()
    assert node.nmt_state == "PRE-OPERATIONAL"  # refused before any NMT
