"""CANopenNode scenarios over SocketCAN vcan, against both IMU nodes (issue 11).

The node is either kind (``start_node``): the simulated one in its own process, the
independent durand node in this test process on its own socket; the tool runs as separate
``python -m canimucal`` processes, as on the operator's laptop. Scenarios: a slow store
(the durand node also drops its frames meanwhile), storage without 0x1010:04, an
OPERATIONAL node without heartbeat that must stay OPERATIONAL after ``read-params`` (seen
from outside: its TPDOs keep coming).
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import pytest

pytestmark = pytest.mark.vcan

NODE = 0x23


def _cal_file(tmp_path: Path) -> Path:
    lsb = float(np.float32(9.80665 / 2048.0))
    document = {
        "schema": "canimucal.calibration/1",
        "plan": "five",
        "device": {"serial": 0},
        "accel": {"bias": [3.0, -2.5, 1.25], "K": (np.diag([1.01, 0.99, 1.0]) / lsb).tolist()},
        "gyro": {"bias": [0.5, -0.25, 2.0]},
    }
    path = tmp_path / "cal.json"
    path.write_text(json.dumps(document))
    return path


def _bus(vcan_channel: str) -> list[str]:
    return ["--channel", vcan_channel, "--node-id", str(NODE)]


def _tpdos_seen(vcan_channel: str, seconds: float = 1.0) -> int:
    """TPDO1 frames of ``NODE`` received within ``seconds`` on a fresh socket."""
    import can

    bus = can.Bus(interface="socketcan", channel=vcan_channel)
    seen, deadline = 0, time.monotonic() + seconds
    try:
        while (left := deadline - time.monotonic()) > 0:
            msg = bus.recv(left)
            seen += msg is not None and msg.arbitration_id == 0x180 + NODE
    finally:
        bus.shutdown()
    return seen


def test_slow_store_over_vcan(tmp_path: Path, start_node, run_cli, vcan_channel: str) -> None:
    node = start_node(NODE, store_delay_s=2.5, nmt_start="operational")
    run = run_cli(
        "write-params", _cal_file(tmp_path), *_bus(vcan_channel), "--backup-dir", tmp_path / "b"
    )
    assert run.returncode == 0, run.stderr
    assert "stored (0x1010:04)" in run.stdout and "restored" not in run.stdout + run.stderr
    assert node.stored_valid()
    if node.kind == "independent":  # the durand node: stored once, frames dropped meanwhile
        assert node.node.store_log == [4] and node.node.stats["dropped"] > 0
    assert _tpdos_seen(vcan_channel) > 0  # still OPERATIONAL: write-params sends no NMT


def test_no_sub_4_is_stored_through_sub_1_over_vcan(
    tmp_path: Path, start_node, run_cli, vcan_channel: str
) -> None:
    node = start_node(NODE, storage_subs=(1, 2, 3))
    run = run_cli(
        "write-params", _cal_file(tmp_path), *_bus(vcan_channel), "--backup-dir", tmp_path / "b"
    )
    assert run.returncode == 0, run.stderr
    assert "stored (0x1010:01)" in run.stdout and node.stored_valid()
    if node.kind == "independent":
        assert node.node.store_log == [1]


def test_operational_node_stays_operational_over_vcan(
    tmp_path: Path, start_node, run_cli, vcan_channel: str
) -> None:
    start_node(NODE, nmt_start="operational", heartbeat_ms=0)
    assert _tpdos_seen(vcan_channel) > 0
    run = run_cli("read-params", *_bus(vcan_channel), "--json", tmp_path / "r.json")
    assert run.returncode == 0, run.stderr
    assert _tpdos_seen(vcan_channel) > 0  # TPDOs keep coming: left OPERATIONAL
