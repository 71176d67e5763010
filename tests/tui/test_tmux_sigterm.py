"""SIGTERM, SIGHUP and a closed terminal to the TUI (tmux): no traceback, terminal and NMT restored.

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
from tests.tui.test_tmux import ROOT, _tmux, _wait_for

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


def _to_the_position_screen(
    hub: tcpbus.TcpHub, frames: FrameRecorder, tmp_path: Path, session: str
) -> None:
    """Start the TUI under tmux (80×24) and go to the position screen, which streams."""
    command = (
        f"cd {ROOT} && PYTHONPATH={ROOT} {sys.executable} -m tests.support.hub_cli tui "
        f"{' '.join(bus_flags(hub, NODE_ID))} --out {tmp_path / 'out'} --no-warmup --g 9.81; "
        "echo EXITED $?; sleep 60"
    )
    _tmux("new-session", "-d", "-s", session, "-x", "80", "-y", "24", command)
    _wait_for(session, "canimucal · connection", "none (nominal)")
    _tmux("send-keys", "-t", session, "Enter")
    _wait_for(session, "canimucal · plan", "Start")
    _tmux("send-keys", "-t", session, "Enter")  # the position screen starts streaming
    frames.wait_count(TPDO1, 50, timeout=60.0)
    assert frames.frames(HEARTBEAT)[-1].data[0] == OPERATIONAL


def _node_left_as_found(frames: FrameRecorder, stopped: float) -> None:
    """No TPDO after ``stopped``; the heartbeat says PRE-OPERATIONAL again."""
    time.sleep(0.5)
    assert not [f for f in frames.frames(TPDO1) if f.timestamp > stopped], "still streaming"
    beats = [f.data[0] for f in frames.frames(HEARTBEAT) if f.timestamp > stopped]
    assert beats and set(beats) == {PRE_OPERATIONAL}, beats


@pytest.mark.parametrize(
    ("signum", "code", "word"),
    [(signal.SIGTERM, 143, "terminated"), (signal.SIGHUP, 129, "hung up")],
)
def test_a_signal_on_the_position_screen_exits_and_restores_all(
    hub_node: tuple[tcpbus.TcpHub, FrameRecorder],
    tmp_path: Path,
    signum: int,
    code: int,
    word: str,
) -> None:
    hub, frames = hub_node
    session = f"canimucal-term-{os.getpid()}-{time.monotonic_ns() % 10**6}"
    try:
        _to_the_position_screen(hub, frames, tmp_path, session)
        assert _tmux("display-message", "-p", "-t", session, "#{alternate_on}").strip() == "1"
        os.kill(_tui_pid(session), signum)
        screen = _wait_for(session, f"EXITED {code}", timeout_s=30.0)
        stopped = time.time()
        assert word in screen and "Traceback" not in screen, screen
        modes = "#{alternate_on} #{mouse_any_flag} #{cursor_flag}"
        assert _tmux("display-message", "-p", "-t", session, modes).split() == ["0", "0", "1"]
        _node_left_as_found(frames, stopped)
        out = tmp_path / "out"
        assert (out / "recording.csv").exists() and not (out / "recording.csv.partial").exists()
    finally:
        _tmux("kill-session", "-t", session)


def test_the_terminal_going_away_stops_the_session_and_restores_the_node(
    hub_node: tuple[tcpbus.TcpHub, FrameRecorder], tmp_path: Path
) -> None:
    """Issue 25, item 5: the terminal itself closes (tmux kills the pane: a real hang-up)."""
    hub, frames = hub_node
    session = f"canimucal-hup-{os.getpid()}-{time.monotonic_ns() % 10**6}"
    killed = False
    try:
        _to_the_position_screen(hub, frames, tmp_path, session)
        pid = _tui_pid(session)
        _tmux("kill-session", "-t", session)  # the kernel sends SIGHUP; stdout is gone
        killed = True
        deadline = time.monotonic() + 30.0
        while Path(f"/proc/{pid}").exists() and time.monotonic() < deadline:
            time.sleep(0.05)
        stopped = time.time()
        assert not Path(f"/proc/{pid}").exists(), "the TUI outlived its terminal"
        _node_left_as_found(frames, stopped)
        out = tmp_path / "out"
        assert (out / "recording.csv").exists() and not (out / "recording.csv.partial").exists()
    finally:
        if not killed:
            _tmux("kill-session", "-t", session)
