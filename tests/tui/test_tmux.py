"""`python -m canimucal demo` starts and renders at 80×24 in a real terminal (tmux).

Timeouts are generous (90 s): the imports alone take 3-7 s on a loaded 2-core machine.
Skipped with a reason when tmux is missing outside CI; in CI (``CI`` set) a missing tmux is a
failure (``.ci/run`` installs it).
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import time
import uuid
from collections.abc import Iterator
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
TMUX = shutil.which("tmux")

if TMUX is None and not os.environ.get("CI"):
    pytest.skip("tmux is not installed (CI installs it)", allow_module_level=True)


def _tmux(*args: str) -> str:
    assert TMUX is not None, "tmux is required in CI"
    done = subprocess.run([TMUX, *args], capture_output=True, text=True, timeout=10)
    return done.stdout


def _pane(name: str) -> str:
    return _tmux("capture-pane", "-p", "-t", name)


def _wait_for(name: str, *texts: str, timeout_s: float = 90.0) -> str:
    deadline = time.monotonic() + timeout_s
    screen = ""
    while time.monotonic() < deadline:
        screen = _pane(name)
        if all(t in screen for t in texts):
            return screen
        time.sleep(0.2)
    raise AssertionError(f"{texts} not on the screen within {timeout_s} s:\n{screen}")


@pytest.fixture
def demo(tmp_path: Path) -> Iterator[str]:
    """A tmux session of 80×24 running the demo TUI; killed at teardown."""
    name = f"canimucal-test-{uuid.uuid4().hex[:8]}"
    command = (
        f"cd {ROOT} && {sys.executable} -m canimucal demo --out {tmp_path / 'out'} "
        f"--seconds 3; echo EXITED $?; sleep 60"
    )
    _tmux("new-session", "-d", "-s", name, "-x", "80", "-y", "24", command)
    try:
        yield name
    finally:
        _tmux("kill-session", "-t", name)


def test_the_demo_starts_renders_at_80x24_and_quits_with_q(demo: str) -> None:
    size = _tmux("display-message", "-p", "-t", demo, "#{pane_width}x#{pane_height}")
    assert size.strip() == "80x24"
    screen = _wait_for(demo, "canimucal · connection", "none (nominal)", "Plan")
    assert "Traceback" not in screen
    lines = screen.splitlines()
    assert len(lines) <= 24 and all(len(line) <= 80 for line in lines)
    _tmux("send-keys", "-t", demo, "Enter")
    screen = _wait_for(demo, "canimucal · plan", "worst-case bound", "Start")
    _tmux("send-keys", "-t", demo, "q")
    screen = _wait_for(demo, "EXITED 0", "demo files in")


def test_ctrl_c_interrupts_the_demo_with_130(demo: str) -> None:
    _wait_for(demo, "canimucal · connection", "none (nominal)")
    _tmux("send-keys", "-t", demo, "C-c")
    screen = _wait_for(demo, "EXITED 130")
    assert "Traceback" not in screen
