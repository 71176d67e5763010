"""SIGTERM to the TUI in a real terminal (tmux): exit 143, no traceback, terminal and NMT restored.

The TUI runs in a fresh interpreter under tmux and joins a cross-process bus
(:mod:`tests.support.tcpbus`) through ``tests.support.hub_cli``; the simulated node is
``canimucal sim`` in a process of its own. This test watches the node's heartbeat and
TPDOs through its own connection to the bus: streaming (OPERATIONAL) on the position
screen, PRE-OPERATIONAL and silent after the TUI was terminated.
"""

from __future__ import annotations

import os
import signal
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import can
import pytest

from tests.support import tcpbus
from tests.support.canbus import FrameRecorder
from tests.support.processes import bus_flags, start_sim_node
from tests.tui.test_tmux import ROOT, _pane, _tmux, _wait_for

NODE_ID = 0x10
TPDO1, HEARTBEAT = 0x180 + NODE_ID, 0x700 + NODE_ID
PRE_OPERATIONAL, OPERATIONAL = 0x7F, 0x05


@pytest.fixture
def hub_node(tmp_path: Path) -> Iterator[tuple[tcpbus.TcpHub, FrameRecorder]]:
    """A hub, ``canimucal sim`` on it, and a recorder of what the bus carries."""
    tcpbus.register()
    with tcpbus.TcpHub() as hub:
        node = start_sim_node(
            hub, tmp_path, {"serial": 4242, "sample_rate_hz": 50, "heartbeat_ms": 50}
        )
        observer = tcpbus.TcpBus(hub.channel)
        frames = FrameRecorder()
        notifier = can.Notifier(observer, [frames], timeout=0.05)
        try:
            yield hub, frames
        finally:
            notifier.stop()
            observer.shutdown()
            node.stop()


def _tui_pid(session: str) -> int:
    shell = _tmux("display-message", "-p", "-t", session, "#{pane_pid}").strip()
    children = Path(f"/proc/{shell}/task/{shell}/children").read_text().split()
    assert len(children) == 1, children
    return int(children[0])


def test_sigterm_on_the_position_screen_exits_143_and_restores_all(
    hub_node: tuple[tcpbus.TcpHub, FrameRecorder], tmp_path: Path
) -> None:
    hub, frames = hub_node
    session = f"canimucal-term-{os.getpid()}-{time.monotonic_ns() % 10**6}"
    command = (
        f"cd {ROOT} && PYTHONPATH={ROOT} {sys.executable} -m tests.support.hub_cli tui "
        f"{' '.join(bus_flags(hub, NODE_ID))} --out {tmp_path / 'out'} --no-warmup --g 9.81; "
        "echo EXITED $?; sleep 60"
    )
    _tmux("new-session", "-d", "-s", session, "-x", "80", "-y", "24", command)
    try:
        _wait_for(session, "canimucal · connection", "none (nominal)")
        _tmux("send-keys", "-t", session, "Enter")
        _wait_for(session, "canimucal · plan", "Start")
        _tmux("send-keys", "-t", session, "Enter")  # the position screen starts streaming
        frames.wait_count(TPDO1, 50, timeout=60.0)
        assert _tmux("display-message", "-p", "-t", session, "#{alternate_on}").strip() == "1"
        assert frames.frames(HEARTBEAT)[-1].data[0] == OPERATIONAL
        os.kill(_tui_pid(session), signal.SIGTERM)
        screen = _wait_for(session, "EXITED 143", timeout_s=30.0)
        stopped = time.time()
        assert "terminated" in screen and "Traceback" not in screen, screen
        modes = "#{alternate_on} #{mouse_any_flag} #{cursor_flag}"
        assert _tmux("display-message", "-p", "-t", session, modes).split() == ["0", "0", "1"]
        time.sleep(0.5)
        assert not [f for f in frames.frames(TPDO1) if f.timestamp > stopped], "still streaming"
        beats = [f.data[0] for f in frames.frames(HEARTBEAT) if f.timestamp > stopped]
        assert beats and set(beats) == {PRE_OPERATIONAL}, _pane(session)
    finally:
        _tmux("kill-session", "-t", session)
