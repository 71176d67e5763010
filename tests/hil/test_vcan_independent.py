"""The tool against the independent (durand) IMU node over SocketCAN vcan (issue 11).

The node runs in this test process on its own socketcan bus; the tool runs as separate
``python -m canimucal`` processes, as on the operator's laptop. Scenarios of CANopenNode
devices: a slow store that drops frames, storage without 0x1010:04, an OPERATIONAL node
without heartbeat that must stay OPERATIONAL after ``read-params``.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

pytestmark = pytest.mark.vcan
durand = pytest.importorskip("durand")

from tests.support.independent_node import Behaviour, IndependentImuNode  # noqa: E402

NODE = 0x23


@pytest.fixture
def make_node(vcan_channel: str) -> Iterator[Callable[..., IndependentImuNode]]:
    import can

    made: list[tuple[IndependentImuNode, Any]] = []

    def make(**behaviour: Any) -> IndependentImuNode:
        bus = can.Bus(interface="socketcan", channel=vcan_channel)
        node = IndependentImuNode(bus, NODE, Behaviour(**behaviour)).start()
        made.append((node, bus))
        return node

    yield make
    for node, bus in made:
        node.stop()
        bus.shutdown()


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


def test_slow_store_dropping_frames_over_vcan(
    tmp_path: Path, make_node, run_cli, vcan_channel: str
) -> None:
    node = make_node(store_delay_s=2.5, store_pdo_mode="drop", nmt_start="operational")
    run = run_cli(
        "write-params", _cal_file(tmp_path), *_bus(vcan_channel), "--backup-dir", tmp_path / "b"
    )
    assert run.returncode == 0, run.stderr
    assert "stored (0x1010:04)" in run.stdout
    assert node.store_log == [4] and node.stats["dropped"] > 0
    assert node.nmt_state == "OPERATIONAL"


def test_no_sub_4_is_stored_through_sub_1_over_vcan(
    tmp_path: Path, make_node, run_cli, vcan_channel: str
) -> None:
    node = make_node(storage_subs=(1, 2, 3))
    run = run_cli(
        "write-params", _cal_file(tmp_path), *_bus(vcan_channel), "--backup-dir", tmp_path / "b"
    )
    assert run.returncode == 0, run.stderr
    assert "stored (0x1010:01)" in run.stdout and node.store_log == [1]


def test_operational_node_stays_operational_over_vcan(
    tmp_path: Path, make_node, run_cli, vcan_channel: str
) -> None:
    node = make_node(nmt_start="operational", heartbeat_ms=0)
    run = run_cli("read-params", *_bus(vcan_channel), "--json", tmp_path / "r.json")
    assert run.returncode == 0, run.stderr
    assert node.nmt_state == "OPERATIONAL"
