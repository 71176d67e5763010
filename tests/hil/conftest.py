"""HIL fixtures: the simulated node and the tool in separate processes over SocketCAN vcan.

Every test module here sets ``pytestmark = pytest.mark.vcan`` (``make test-vcan`` runs them,
natively where ``vcan0`` exists, else inside ``../shared/tools/canvm``). They skip when the
interface cannot be opened;
``scripts/test_vcan.sh`` makes a skip fail under ``CI=true``.

- ``vcan_channel``: ``$CANIMUCAL_VCAN`` or ``vcan0``, checked by opening a socketcan bus.
- ``run_cli(*argv)``: ``python -m canimucal ARGV`` in a subprocess (``PYTHONPATH`` = the
  project, as inside the VM where the package is not installed); returns the completed run.
- ``start_sim(*argv)``: ``python -m canimucal sim --channel vcan0 ARGV`` in the background,
  waits for its ``ready:`` line; stopped with SIGTERM at teardown.
- ``start_node(node_id, serial, **behaviour)``: a node of kind ``device_kind``
  (tests/support/nodes.py): the simulated one as ``start_sim`` runs it (behaviour in its
  truth JSON, flash in a ``--state`` file), or the independent durand node in this process
  on its own socketcan bus (:class:`InProcessNode`); both have ``wait_ready``, ``stop`` and
  ``stored_valid``. A behaviour the simulated node does not have skips the test for it.

Inside the VM (``IN_CAN_VM=1``) Python is about 12× slower: timeouts scale with ``SLOW``.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from canimucal.io.truth import write_truth
from canimucal.sim.truth import Truth
from tests.support.nodes import SIM_TRUTH_KEYS
from tests.support.user_dirs import UserDirs

PROJECT = Path(__file__).resolve().parents[2]
IN_VM = os.environ.get("IN_CAN_VM", "").strip() == "1"
SLOW = 12.0 if IN_VM else 1.0
"""Factor on wall-clock timeouts inside the emulated VM."""
READY_TIMEOUT_S = 30.0 * SLOW
CLI_TIMEOUT_S = 120.0 * SLOW


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(PROJECT) + os.pathsep + env.get("PYTHONPATH", "")
    env.setdefault("PYTHONUNBUFFERED", "1")
    return env


@pytest.fixture(autouse=True)
def _own_user_dirs(own_user_dirs: UserDirs) -> UserDirs:
    """The tool in these processes reads the user's config: they inherit one of their own."""
    return own_user_dirs


@pytest.fixture(scope="session")
def vcan_channel() -> str:
    """The vcan interface, or skip with the reason it cannot be opened."""
    channel = os.environ.get("CANIMUCAL_VCAN", "vcan0")
    try:
        import can

        bus = can.Bus(interface="socketcan", channel=channel)
    except Exception as exc:  # no SocketCAN kernel, no such interface
        pytest.skip(f"SocketCAN {channel} not available: {exc}")
    bus.shutdown()
    return channel


@pytest.fixture
def run_cli() -> Callable[..., subprocess.CompletedProcess[str]]:
    """Run ``python -m canimucal ARGV``; return the completed process (text output)."""

    def run(*argv: object, stdin: str = "") -> subprocess.CompletedProcess[str]:
        cmd = [sys.executable, "-m", "canimucal", *map(str, argv)]
        return subprocess.run(
            cmd,
            input=stdin,
            capture_output=True,
            text=True,
            env=_env(),
            cwd=PROJECT,
            timeout=CLI_TIMEOUT_S,
            check=False,
        )

    return run


class SimProcess:
    """A background ``canimucal sim``: its process and the output it printed."""

    kind = "simulated"

    def __init__(self, argv: list[str]) -> None:
        self.argv = argv
        self.proc = subprocess.Popen(
            argv,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            env=_env(),
            cwd=PROJECT,
        )
        self.lines: list[str] = []
        self.state_file: Path | None = None
        """The node's non-volatile memory (``--state``), when given."""
        self.ready = threading.Event()
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self.lines.append(line.rstrip("\n"))
            if line.startswith("ready:"):
                self.ready.set()

    def wait_ready(self, timeout_s: float = READY_TIMEOUT_S) -> None:
        """Block until the node printed its ready line (fail with its output otherwise)."""
        deadline = time.monotonic() + timeout_s
        while not self.ready.wait(0.1):
            if self.proc.poll() is not None or time.monotonic() > deadline:
                self.stop()
                raise AssertionError("simulated node did not start:\n" + "\n".join(self.lines))

    def stored_valid(self) -> bool:
        """Whether the node's flash (its ``--state`` file) holds valid = 1 (0x2121:05)."""
        if self.state_file is None or not self.state_file.exists():
            return False
        objects = json.loads(self.state_file.read_text())["objects"]
        return bool(objects.get("0x2121:05") == "01")

    def stop(self) -> int:
        """SIGTERM, wait, kill if needed; return the exit status."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout=10.0 * SLOW)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self._reader.join(timeout=5.0)
        return int(self.proc.returncode)


@pytest.fixture
def start_sim(vcan_channel: str) -> Iterator[Callable[..., SimProcess]]:
    """Factory: ``start_sim(*argv, wait=True)`` runs ``canimucal sim --channel vcan0 ARGV``."""
    started: list[SimProcess] = []

    def start(*argv: object, wait: bool = True) -> SimProcess:
        cmd = [sys.executable, "-m", "canimucal", "sim", "--channel", vcan_channel]
        sim = SimProcess(cmd + [str(a) for a in argv])
        started.append(sim)
        if wait:
            sim.wait_ready()
        return sim

    yield start
    for sim in started:
        sim.stop()


class InProcessNode:
    """The independent (durand) node in this process on its own socketcan bus.

    Seen as a :class:`SimProcess` is: ``wait_ready()`` and ``stop()`` (exit status 0).
    """

    kind = "independent"

    def __init__(self, channel: str, node_id: int, **behaviour: Any) -> None:
        import can

        from tests.support.independent_node import Behaviour, IndependentImuNode

        self.bus = can.Bus(interface="socketcan", channel=channel)
        self.node = IndependentImuNode(self.bus, node_id, Behaviour(**behaviour))
        self._running = False

    def start(self) -> InProcessNode:
        """Send the boot-up and start sampling."""
        self.node.start()
        self._running = True
        return self

    def wait_ready(self, timeout_s: float = READY_TIMEOUT_S) -> None:
        """Nothing to wait for: ``start()`` returned with the node up."""

    def stored_valid(self) -> bool:
        """Whether the node's flash holds valid = 1 (0x2121:05)."""
        with self.node.lock:
            return bool(self.node.flash.get((0x2121, 5)) == 1)

    def stop(self) -> int:
        """Stop the node and close its bus (once); return 0 as a clean exit."""
        if self._running:
            self._running = False
            self.node.stop()
            self.bus.shutdown()
        return 0


@pytest.fixture
def start_node(
    device_kind: str,
    vcan_channel: str,
    start_sim: Callable[..., SimProcess],
    tmp_path: Path,
) -> Iterator[Callable[..., SimProcess | InProcessNode]]:
    """Factory: ``start_node(node_id, serial=0, wait=True, **behaviour)`` of ``device_kind``."""
    started: list[InProcessNode] = []

    def start(
        node_id: int, serial: int = 0, *, wait: bool = True, **behaviour: Any
    ) -> SimProcess | InProcessNode:
        if device_kind == "simulated":
            unknown = sorted(set(behaviour) - set(SIM_TRUTH_KEYS))
            if unknown:
                pytest.skip(f"the simulated node has no {', '.join(unknown)}")
            doc = {k: list(v) if isinstance(v, tuple) else v for k, v in behaviour.items()}
            truth = write_truth(
                tmp_path / f"truth-{node_id}.json",
                Truth.from_dict(doc | {"serial": serial}),
                overwrite=False,
            )
            state = tmp_path / f"state-{node_id}.json"
            argv = ["--node-id", node_id, "--truth", truth, "--state", state]
            sim = start_sim(*argv, wait=False)
            sim.state_file = state
            if wait:
                sim.wait_ready()
            return sim
        node = InProcessNode(vcan_channel, node_id, serial=serial, seed=1, **behaviour)
        started.append(node)
        return node.start()

    yield start
    for node in started:
        node.stop()
