"""Smaller HIL checks over SocketCAN vcan against both IMU nodes (``start_node``).

The simulated node runs in another process, the independent durand node in this one on its
own socket; the client and the CLI as on the operator's laptop. Boot-up discovery, streaming
at 200 Hz with the default socket receive buffer (no loss expected: 400 frames/s), and a
write refused for another serial (exit 3, nothing written).
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import can
import numpy as np
import pytest

from canimucal.device.client import ImuClient

pytestmark = pytest.mark.vcan

STREAM_SECONDS = 10.0
SLOW = 12.0 if os.environ.get("IN_CAN_VM", "").strip() == "1" else 1.0
READY_TIMEOUT_S = 30.0 * SLOW
ACCEL_LSB = 9.80665 / 2048.0


def test_find_node_by_boot_up(start_node, vcan_channel: str) -> None:
    bus = can.Bus(interface="socketcan", channel=vcan_channel)
    try:
        with ImuClient(bus, 0x22, sdo_timeout_s=2.0 * SLOW) as client:
            sim = start_node(0x22, 77, wait=False)
            assert client.find_node(timeout_s=READY_TIMEOUT_S) == "boot-up"
            assert client.identity().serial == 77
            sim.wait_ready()
    finally:
        bus.shutdown()
    assert sim.stop() == 0


class _PdoCounter(can.Listener):
    """Counts the TPDO1/TPDO2 frames the socket delivered, by counter (bytes 6-7)."""

    def __init__(self, node: int) -> None:
        self.cob_ids = (0x180 + node, 0x280 + node)
        self.counters: dict[int, list[int]] = {cob: [] for cob in self.cob_ids}

    def stop(self) -> None:
        pass  # python-can 4.4 declares it abstract

    def on_message_received(self, msg: can.Message) -> None:
        if msg.arbitration_id in self.counters and len(msg.data) == 8:
            self.counters[msg.arbitration_id].append(int.from_bytes(msg.data[6:8], "little"))


def _repeats(counters: list[int], span: np.ndarray) -> int:
    """How many frames repeated a counter of ``span`` already delivered."""
    seen = np.asarray(counters)
    seen = seen[np.isin(seen, span)]
    return int(seen.size - np.unique(seen).size)


def test_stream_200hz_no_loss(start_node, vcan_channel: str) -> None:
    """200 Hz through the default socket buffer: nothing lost, and losses counted exactly.

    The raw TPDO frames the socket delivered are recorded beside the client's pairing. The
    pairer's ``lost_samples`` must equal the counters missing from both TPDOs, and natively
    nothing may be missing at all. In the emulated VM on a loaded host a starved receive
    thread does overflow the default buffer now and then (see docs/hil.md), so there the
    counting is checked, and the loss printed, not required to be zero.
    """
    start_node(0x23, 78)
    bus = can.Bus(interface="socketcan", channel=vcan_channel)
    frames = _PdoCounter(0x23)
    try:
        with ImuClient(bus, 0x23, sdo_timeout_s=2.0 * SLOW) as client:
            client.find_node(timeout_s=5.0)
            assert client.network.notifier is not None
            client.network.notifier.add_listener(frames)
            client.start_streaming()
            want = int(STREAM_SECONDS * 200)
            block = client.read_samples(want, timeout_s=STREAM_SECONDS * 3 + 10.0)
            client.stop_streaming()
    finally:
        bus.shutdown()
    first, last = int(block.counter[0]), int(block.counter[-1])
    span = np.arange(first, first + (last - first) % 65536 + 1) % 65536
    accel, gyro = (np.isin(span, frames.counters[cob]) for cob in frames.cob_ids)
    both_missing, one_missing = int(np.sum(~accel & ~gyro)), int(np.sum(accel ^ gyro))
    print(
        f"200 Hz over {vcan_channel}: {span.size} samples, {both_missing} lost, "
        f"{one_missing} halves lost in the socket; pairer: {block.lost_samples} lost, "
        f"{block.lost_accel + block.lost_gyro} halves given up, {block.late} late"
    )
    assert block.n + block.lost_samples == span.size  # every counter: a row or a lost sample
    assert block.lost_samples == both_missing
    # a duplicate is a half the device sent again (the durand node's event timer is a thread
    # of its own, and under load it fires twice between samples; the pairer counts each
    # repeated half): never more than the frames the socket delivered twice, none when
    # nothing came twice
    repeats = sum(_repeats(frames.counters[cob], span) for cob in frames.cob_ids)
    assert block.duplicates <= repeats
    # a half is given up when missing in the socket, or when it came after the 0.25 s grace
    # (late; a few may be counted in the block after the last one read: slack 5)
    halves = block.lost_accel + block.lost_gyro
    assert one_missing <= halves <= one_missing + block.late + 5
    if SLOW == 1.0:  # natively (a real kernel, an idle machine): nothing lost at all
        assert both_missing == one_missing == block.late == 0
        rate = (block.n - 1) / (block.t[-1] - block.t[0])  # CAN receive times
        assert abs(rate - 200.0) < 20.0


def test_write_refused_on_other_serial(
    tmp_path: Path, start_node, run_cli, vcan_channel: str
) -> None:
    start_node(0x24, 111)
    bus = ["--channel", vcan_channel, "--node-id", "0x24"]
    cal = tmp_path / "cal.json"
    cal.write_text(
        json.dumps(
            {
                "schema": "canimucal.calibration/1",
                "device": {"serial": 222},
                "accel": {"bias": [1.0, 2.0, 3.0], "K": (np.eye(3) / ACCEL_LSB).tolist()},
            }
        )
    )
    backups = tmp_path / "backups"
    refused = run_cli("write-params", cal, *bus, "--backup-dir", backups)
    assert refused.returncode == 3 and "serial" in refused.stderr, refused.stderr
    before = tmp_path / "before.json"
    assert run_cli("read-params", *bus, "--json", before).returncode == 0
    factory = json.loads(before.read_text())
    assert factory["readback"]["valid"] == 0
    assert not backups.exists()  # refused before the backup: nothing read, nothing written
    # (forcing, and restoring from the backup, are covered on the virtual bus in
    # tests/cli/test_device_cmds.py: each CLI run costs ~30 s in the emulated VM)
