"""The tool against the reference firmware: CANopenNode v4 + CANopenLinux + ``imu_cal`` (issue 24).

The node is ``firmware/build/imu_node`` (``make -C firmware node``, built on the host by
``scripts/test_vcan.sh``), a process of its own on vcan0 with its storage in a directory that
survives restarts; its synthetic unit follows a pose schedule (``firmware/linux/sensor.h``).

- The whole job: read, record a plan, solve, write and store, restart the node process, read
  back valid with the same CRC, restore the backup. The node starts on empty storage: its
  first boot sends EMCY 0x5000 and still starts (docs/firmware.md §5).
- The issue's four cases, each failing on the client before issue 24:
  1. the calibration stored on another 0x1010 sub-index than 4 (CANopenLinux keeps its own
     record on 4): after a restart the node must still hold it;
  2. a node that refuses to start (CANopenLinux's stock error-register rule, empty storage):
     ``record`` must say so from the heartbeat, error register and EMCY, not "sent no sample";
  3. a TPDO event timer beside data-ready sending: duplicate sends are reported as such, kept
     out of the recording, and not taken for a timer skew;
  4. the EDS builds on stock CANopenLinux: the node made from it answers every object as the
     EDS says, and refuses out-of-range calibration values with abort 0x06090030.

Only the workflow's ``record`` runs as its own process (a CLI process costs 1-2 min in the
emulated VM); the other commands run in this process through the CLI's ``main``, as
``tests/cli`` does.
"""

from __future__ import annotations

import json
import os
import re
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import can
import canopen
import numpy as np
import pytest
from canopen.objectdictionary import ODArray, ODRecord, ODVariable

from canimucal.cli.main import main
from canimucal.device import od
from canimucal.device.client import ImuClient
from canimucal.device.stream import SECOND_TRIGGER_GAP_PERIODS, SECOND_TRIGGER_MIN_GAPS
from canimucal.io.calibration import read_calibration
from canimucal.io.plans import write_plan
from canimucal.model.plan import builtin_plan
from canimucal.model.positions import Plan
from canimucal.runtime.inputs import read_recording
from tests.support.firmware_node import NODE_BINARY, FirmwareNode

pytestmark = pytest.mark.vcan

SLOW = 12.0 if os.environ.get("IN_CAN_VM", "").strip() == "1" else 1.0
READY_S = 20.0 * SLOW
SDO_S = 2.0 * SLOW
ABORT_READ_ONLY = 0x06010002  # CiA 301: attempt to write a read-only object
NODE = 0x31
SERIAL = 24024
ACCEL_LSB = float(np.float32(9.80665 / 2048.0))
UNIT = {  # the synthetic unit's errors (counts, relative scale, degrees)
    "IMU_NODE_ACCEL_BIAS": "31.5,-22.25,48",
    "IMU_NODE_ACCEL_SCALE": "0.012,-0.007,0.018",
    "IMU_NODE_GYRO_BIAS": "6,-4,3",
    "IMU_NODE_BASE_TILT_DEG": "0.4,-0.3",
    "IMU_NODE_NOISE": "3",
    "IMU_NODE_SEED": "24",
}
SECONDS = 4.0
"""Seconds per position of the workflow's plan (the eight recommended poses, ~40 s)."""


@dataclass(frozen=True)
class CliRun:
    """Exit status and captured streams of one in-process ``canimucal`` run."""

    code: int
    out: str
    err: str


@pytest.fixture(scope="module")
def node_binary() -> Path:
    if not NODE_BINARY.is_file():
        pytest.skip(f"no reference node at {NODE_BINARY} (make -C firmware node)")
    return NODE_BINARY


@pytest.fixture
def start_firmware(
    node_binary: Path, vcan_channel: str, tmp_path: Path
) -> Iterator[Callable[..., FirmwareNode]]:
    """Factory ``start_firmware(node_id, respawn=False, **env)``; stopped at teardown."""
    started: list[FirmwareNode] = []

    def start(node_id: int = NODE, *, respawn: bool = False, **env: object) -> FirmwareNode:
        storage = tmp_path / f"flash-{node_id:02x}-{len(started)}"
        node = FirmwareNode(vcan_channel, node_id, storage, env, respawn=respawn)
        started.append(node)
        node.start().wait_ready(READY_S)
        return node

    yield start
    for node in started:
        node.stop()


@pytest.fixture
def cli(capsys: pytest.CaptureFixture[str]) -> Callable[..., CliRun]:
    """Run ``canimucal ARGV`` in this process; return its status and output."""

    def run(*argv: object) -> CliRun:
        capsys.readouterr()
        code = main([str(a) for a in argv])
        captured = capsys.readouterr()
        return CliRun(code, captured.out, captured.err)

    return run


def _bus(channel: str, node: int = NODE) -> list[str]:
    return ["--channel", channel, "--node-id", hex(node)]


def _readout(channel: str, node: int = NODE) -> tuple[int, int, bool]:
    """Valid flag, stored CRC and whether it matches, read from the node."""
    bus = can.Bus(interface="socketcan", channel=channel)
    try:
        with ImuClient(bus, node, sdo_timeout_s=SDO_S) as client:
            client.find_node(timeout_s=SDO_S)
            readout = client.read_calibration_block()
    finally:
        bus.shutdown()
    return readout.valid, readout.crc_stored, readout.crc_ok


def _cal_file(path: Path, serial: int = SERIAL) -> Path:
    document = {
        "schema": "canimucal.calibration/1",
        "device": {"serial": serial},
        "accel": {
            "bias": [3.0, -2.5, 1.25],
            "K": (np.diag([1.01, 0.99, 1.0]) / ACCEL_LSB).tolist(),
        },
        "gyro": {"bias": [0.5, -0.25, 2.0]},
    }
    path.write_text(json.dumps(document))
    return path


def _written_crc(out: str) -> int:
    found = re.search(r"CRC 0x([0-9A-F]{8})", out)
    assert found is not None, out
    return int(found.group(1), 16)


def _plan(seconds: float) -> Plan:
    plan = builtin_plan("recommended").with_total_seconds(seconds * 8)
    wrapped = [replace(p, psi=float(np.angle(np.exp(1j * p.psi)))) for p in plan.positions]
    return Plan(plan.name, tuple(wrapped))


def test_whole_job_against_the_reference_firmware(
    tmp_path: Path, start_firmware, run_cli, cli, vcan_channel: str
) -> None:
    poses = write_plan(tmp_path / "poses.json", _plan(SECONDS), overwrite=False)
    node = start_firmware(IMU_NODE_SERIAL=SERIAL, IMU_NODE_POSES=poses, **UNIT)
    bus = _bus(vcan_channel)
    before = tmp_path / "before.json"
    read = cli("read-params", *bus, "--json", before)
    assert read.code == 0, read.err + "\n".join(node.lines)
    assert json.loads(before.read_text())["readback"]["valid"] == 0
    # first boot on empty storage: EMCY 0x5000 (CANopenLinux's files missing), and it starts
    assert any("errorCode=0x5000" in line for line in node.lines), node.lines

    out = tmp_path / "session.csv"
    rec = run_cli("record", out, "--plan", poses, "--follow-schedule", *bus)
    assert rec.returncode == 0, rec.stderr + rec.stdout + "\n".join(node.lines)
    print(rec.stdout)
    recording = read_recording(out)
    labels, counts = np.unique(recording.position[recording.position >= 0], return_counts=True)
    assert labels.tolist() == list(range(8)) and np.all(counts >= 50), counts
    assert recording.header["device_serial"] == SERIAL

    cal = tmp_path / "cal.json"
    assert cli("solve", out, "--tilt", "--json", cal).code == 0
    written = cli("write-params", cal, *bus, "--backup-dir", tmp_path / "backups")
    assert written.code == 0, written.err + written.out
    assert "stored (0x1010:04)" in written.out
    crc = _written_crc(written.out)

    node.restart(READY_S)  # a power cycle: what is left is what flash holds
    assert _readout(vcan_channel) == (1, crc, True)

    # the solved unit agrees with the synthetic one: bias, scale and base tilt within 4 sigma
    record = read_calibration(cal)
    bias = np.array([31.5, -22.25, 48.0])
    k_diag = (1.0 + np.array([0.012, -0.007, 0.018])) / ACCEL_LSB
    est = np.concatenate([record.accel.bias, np.diag(np.asarray(record.accel.K, float))])
    sig = np.concatenate(
        [record.accel.bias_sigma, np.diag(np.asarray(record.accel.K_sigma, float))]
    )
    z = (est - np.concatenate([bias, k_diag])) / sig
    assert record.base_tilt_deg is not None and record.base_tilt_deg.sigma is not None
    tilt = np.array([record.base_tilt_deg.alpha0, record.base_tilt_deg.beta0])
    z = np.append(z, (tilt - [0.4, -0.3]) / np.asarray(record.base_tilt_deg.sigma, float))
    assert np.all(np.abs(z) < 4.0), z

    # the backup puts the factory set back, stored
    (backup,) = (tmp_path / "backups").iterdir()
    restored = cli("write-params", backup, *bus, "--backup-dir", tmp_path / "backups2")
    assert restored.code == 0, restored.err
    node.restart(READY_S)
    assert _readout(vcan_channel) == (0, 0x36701FFB, True)  # 42 objects: with 0x2122


def test_case1_calibration_stored_where_the_node_says(
    tmp_path: Path, start_firmware, cli, vcan_channel: str
) -> None:
    """Case 1: calibration on 0x1010:03, CANopenLinux's own record on sub 4."""
    node = start_firmware(IMU_NODE_SERIAL=SERIAL, IMU_NODE_CAL_STORE_SUB=3, respawn=True)
    bus = _bus(vcan_channel)
    written = cli("write-params", _cal_file(tmp_path / "cal.json"), *bus, "--backup-dir", tmp_path)
    assert written.code == 0, written.err
    assert "stored (0x1010:03)" in written.out, written.out
    crc = _written_crc(written.out)
    node.restart(READY_S)
    assert _readout(vcan_channel) == (1, crc, True), "the calibration did not survive a restart"

    # the commissioning check: NMT reset node, boot-up, valid and CRC read back
    again = cli(
        "write-params",
        _cal_file(tmp_path / "cal2.json"),
        *bus,
        "--backup-dir",
        tmp_path / "b2",
        "--verify-after-restart",
    )
    assert again.code == 0, again.err
    crc = _written_crc(again.out)
    assert f"verified after a restart: valid, CRC 0x{crc:08X}" in again.out, again.out
    assert node.starts == 3  # the reset ended the process and it came back, as an MCU resets


def test_case2_node_that_refuses_to_start_is_named(
    tmp_path: Path, start_firmware, cli, vcan_channel: str
) -> None:
    """Case 2: empty storage plus CANopenLinux's stock rule: PRE-OPERATIONAL after every start."""
    start_firmware(IMU_NODE_SERIAL=SERIAL, IMU_NODE_NMT_CONTROL="stock")
    run = cli(
        "record",
        tmp_path / "r.csv",
        "--position",
        0,
        "--alpha-deg",
        0,
        "--beta-deg",
        0,
        "--psi-deg",
        0,
        "--seconds",
        2,
        "--no-pose-check",
        *_bus(vcan_channel),
    )
    assert run.code == 3, run.err
    assert f"node {NODE} stays pre-operational after start" in run.err, run.err
    assert "error register 0x01" in run.err and "sent no sample" not in run.err


class _TpdoFrames(can.Listener):
    def __init__(self, cob_id: int) -> None:
        self.cob_id = cob_id
        self.counters: list[int] = []
        self.times: list[float] = []

    def on_message_received(self, msg: can.Message) -> None:
        if msg.arbitration_id == self.cob_id and len(msg.data) == 8:
            self.counters.append(int.from_bytes(msg.data[6:8], "little"))
            self.times.append(msg.timestamp)


def test_case3_duplicate_sends_are_not_skew(
    tmp_path: Path, start_firmware, cli, vcan_channel: str
) -> None:
    """Case 3: 0x1800:05/0x1801:05 = 5 ms beside data-ready sending at 200 Hz."""
    start_firmware(IMU_NODE_SERIAL=SERIAL, IMU_NODE_EVENT_TIMER_MS=5)
    listener_bus = can.Bus(interface="socketcan", channel=vcan_channel)
    frames = _TpdoFrames(0x180 + NODE)
    notifier = can.Notifier(listener_bus, [frames])
    out = tmp_path / "r.csv"
    try:
        run = cli(
            "record",
            out,
            "--position",
            0,
            "--alpha-deg",
            0,
            "--beta-deg",
            0,
            "--psi-deg",
            0,
            "--seconds",
            8,
            "--no-pose-check",
            *_bus(vcan_channel),
        )
    finally:
        notifier.stop()
        listener_bus.shutdown()
    assert run.code == 0, run.err
    print(run.out)
    sent, times = np.asarray(frames.counters), np.asarray(frames.times)
    # the node did send samples twice: its event timer restarts at every send, so it fires
    # only when a data-ready send comes late, and how often depends on the host's jitter
    # (18 % and 2 % of samples in two CI runs, 4.6 % and 0.4 % in idle VMs, hence 8 s); the
    # late sample then follows its copy closely, which tells these repeats from a fast clock
    repeats = np.flatnonzero(np.diff(sent) == 0) + 1
    follow = repeats[repeats + 1 < sent.size]
    gaps_ms = 1e3 * (times[follow + 1] - times[follow])
    print(f"{repeats.size} repeats of {sent.size} TPDO1; next sample after a repeat:", end=" ")
    near = np.mean(gaps_ms < 5.0 * SECOND_TRIGGER_GAP_PERIODS)
    print(
        f"median {np.median(gaps_ms):.2f} ms, {near:.0%} within {SECOND_TRIGGER_GAP_PERIODS} period"
    )
    assert repeats.size >= SECOND_TRIGGER_MIN_GAPS, "the node repeated too few samples"
    found = re.search(r"(\d+) duplicate sends", run.out)
    assert found is not None and int(found.group(1)) > 0, run.out
    assert re.search(r"timer skew [+-]\d+ ppm", run.out) is None, run.out
    assert "timer skew" not in run.err
    counter = read_recording(out).counter
    assert np.all(np.mod(np.diff(counter), 65536) >= 1)  # no row twice


def _eds_variables() -> Iterator[ODVariable]:
    eds = canopen.import_od(str(od.eds_path()), node_id=NODE)
    for entry in eds.values():
        if isinstance(entry, ODArray | ODRecord):
            yield from (entry[s] for s in sorted(entry.subindices))
        else:
            yield entry


LIVE = {0x1001, 0x2000, 0x2001, 0x2002}
"""Objects whose value is the node's state, not an EDS default (error register, samples)."""


def test_case4_the_eds_builds_a_node_that_answers_as_the_eds_says(
    start_firmware, vcan_channel: str
) -> None:
    """Case 4: the EDS, generated into CANopenNode v4 and built with stock CANopenLinux."""
    start_firmware(IMU_NODE_SERIAL=SERIAL)
    bus = can.Bus(interface="socketcan", channel=vcan_channel)
    network = canopen.Network(bus)
    network.connect()
    try:
        remote = network.add_node(NODE, str(od.eds_path()))
        remote.sdo.RESPONSE_TIMEOUT = SDO_S
        checked = _check_every_object(remote)
        assert checked > 120
        _check_refusals(remote)
    finally:
        network.disconnect()


def _check_every_object(remote: canopen.RemoteNode) -> int:
    checked = 0
    for var in _eds_variables():
        raw = remote.sdo.upload(var.index, var.subindex)
        if var.index in LIVE:
            assert len(raw) == len(var) // 8, (hex(var.index), var.subindex)
        elif (var.index, var.subindex) == (0x1018, 4):
            assert var.decode_raw(raw) == SERIAL
        else:
            assert raw == var.encode_raw(var.default), (hex(var.index), var.subindex, raw.hex())
        checked += 1
    return checked


def _abort(remote: canopen.RemoteNode, index: int, sub: int, data: bytes) -> int:
    try:
        remote.sdo.download(index, sub, data)
    except canopen.SdoAbortedError as exc:
        return int(exc.code)
    return 0


def _check_refusals(remote: canopen.RemoteNode) -> None:
    cases: Sequence[tuple[int, int, bytes, int]] = (
        (0x2100, 1, od.encode("f32", 70000.0), od.ABORT_VALUE_RANGE),
        (0x2101, 1, od.encode("f32", 0.0), od.ABORT_VALUE_RANGE),
        (0x2101, 2, od.encode("f32", 0.3 * ACCEL_LSB), od.ABORT_VALUE_RANGE),
        (0x2112, 9, od.encode("f32", float("nan")), od.ABORT_VALUE_RANGE),
        (0x2121, 5, od.encode("u8", 2), od.ABORT_VALUE_RANGE),
        (0x2122, 2, od.encode("f32", 0.25), od.ABORT_VALUE_RANGE),  # |trim| ≤ 0.2 rad
        (0x2010, 3, od.encode("u16", 300), od.ABORT_VALUE_RANGE),
        (0x2100, 4, od.encode("f32", 0.0), od.ABORT_NO_SUBINDEX),
        (0x2010, 1, od.encode("f32", 0.1), ABORT_READ_ONLY),
    )
    for index, sub, data, code in cases:
        before = remote.sdo.upload(index, sub) if code != od.ABORT_NO_SUBINDEX else b""
        assert _abort(remote, index, sub, data) == code, (hex(index), sub)
        if before:
            assert remote.sdo.upload(index, sub) == before  # refused: unchanged
    # accepted values move the gate: valid = 1 over the factory set opens it (status bit 2),
    # a changed bias closes it (the CRC no longer matches)
    assert _abort(remote, 0x2121, 5, od.encode("u8", 1)) == 0
    _wait_status(remote, active=True)
    assert _abort(remote, 0x2100, 1, od.encode("f32", 1.0)) == 0
    _wait_status(remote, active=False)


def _wait_status(remote: canopen.RemoteNode, *, active: bool) -> None:
    """Status bit 2 of the next samples (0x2002:03) as ``active`` says, within the SDO time."""
    deadline = time.monotonic() + SDO_S
    while bool(remote.sdo.upload(0x2002, 3)[0] & od.STATUS_CAL_ACTIVE) != active:
        assert time.monotonic() < deadline, f"status bit 2 did not become {active}"
