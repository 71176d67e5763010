"""The CLI in separate processes on one :mod:`tests.support.tcpbus` hub, forked cheaply.

:func:`fork_cli` forks this (already imported) test process and runs
``canimucal.cli.entry.run_main(argv)`` in the child (what the ``canimucal`` script runs), its
stdout and stderr going to files, and exits with the command's return code, so a process
costs milliseconds instead of the ~1 s of a fresh interpreter. The child starts with
Python's own SIGINT handler and the default SIGTERM and SIGHUP dispositions, as a command
started from a shell does, until ``run_main`` takes them over; anything escaping it
(which must never happen) is written to stderr as a traceback and exits 99.
:class:`CliProcess` waits for it and reads what it printed.
"""

from __future__ import annotations

import json
import os
import signal
import sys
import time
import traceback
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from tests.support import tcpbus

ESCAPED = 99
"""Exit status of a forked command from which an exception escaped ``main``."""


@dataclass
class CliProcess:
    """A forked ``canimucal`` command."""

    pid: int
    out: Path
    err: Path
    code: int | None = None

    def signal(self, signum: int) -> None:
        """Send ``signum`` unless the process is gone."""
        try:
            os.kill(self.pid, signum)
        except ProcessLookupError:
            pass

    def poll(self) -> int | None:
        """The exit status if it has ended (a signal death is ``-signum``)."""
        if self.code is None:
            pid, status = os.waitpid(self.pid, os.WNOHANG)
            if pid:
                self.code = os.waitstatus_to_exitcode(status)
        return self.code

    def wait(self, timeout_s: float = 30.0) -> int:
        """Wait for the exit status; kill the process after ``timeout_s`` (then raise)."""
        deadline = time.monotonic() + timeout_s
        while self.poll() is None:
            if time.monotonic() > deadline:
                self.signal(signal.SIGKILL)
                os.waitpid(self.pid, 0)
                raise TimeoutError(f"process {self.pid} still running after {timeout_s} s")
            time.sleep(0.002)
        assert self.code is not None
        return self.code

    def wait_ended(self, timeout_s: float = 30.0) -> None:
        """Wait until the process has ended without reaping it (its pid stays ours to signal)."""
        deadline = time.monotonic() + timeout_s
        while self.code is None:
            if os.waitid(os.P_PID, self.pid, os.WEXITED | os.WNOHANG | os.WNOWAIT) is not None:
                return
            if time.monotonic() > deadline:
                return  # wait() kills it and raises
            time.sleep(0.002)

    def stop(self) -> int:
        """SIGTERM, then wait (SIGKILL after 10 s)."""
        if self.poll() is None:
            self.signal(signal.SIGTERM)
        return self.wait(10.0)

    @property
    def stdout(self) -> str:
        return self.out.read_text(errors="replace")

    @property
    def stderr(self) -> str:
        return self.err.read_text(errors="replace")


def fork_cli(argv: list[str], workdir: Path, name: str) -> CliProcess:
    """Run ``canimucal ARGV`` in a forked child; output in ``workdir/name.out|err``."""
    out, err = workdir / f"{name}.out", workdir / f"{name}.err"
    out.write_bytes(b"")
    err.write_bytes(b"")
    sys.stdout.flush()
    sys.stderr.flush()
    pid = os.fork()
    if pid:
        return CliProcess(pid, out, err)
    code = ESCAPED
    try:  # the child: never return into the test runner
        signal.signal(signal.SIGINT, signal.default_int_handler)
        signal.signal(signal.SIGTERM, signal.SIG_DFL)
        signal.signal(signal.SIGHUP, signal.SIG_DFL)
        for fd, path in ((1, out), (2, err)):
            target = os.open(path, os.O_WRONLY | os.O_TRUNC)
            os.dup2(target, fd)
            os.close(target)
        sys.stdout = open(1, "w", closefd=False)  # noqa: SIM115 (the process ends below)
        sys.stderr = open(2, "w", closefd=False)  # noqa: SIM115
        from canimucal.cli.entry import run_main

        code = run_main(argv)
    except BaseException:  # noqa: BLE001  (reported as the test's failure, never swallowed)
        try:
            traceback.print_exc()
        except BaseException:  # noqa: BLE001
            pass
    finally:
        try:
            sys.stdout.flush()
            sys.stderr.flush()
        finally:
            os._exit(code)


def bus_flags(hub: tcpbus.TcpHub, node_id: int = 0x10) -> list[str]:
    """The CLI flags putting a command on ``hub``."""
    return ["--interface", tcpbus.INTERFACE, "--channel", hub.channel, "--node-id", str(node_id)]


def start_sim_node(
    hub: tcpbus.TcpHub,
    workdir: Path,
    truth: dict[str, Any],
    *,
    node_id: int = 0x10,
    state: Path | None = None,
) -> CliProcess:
    """``canimucal sim`` in its own process on ``hub``; returns once it printed ``ready``.

    ``state``: the node's non-volatile memory (``--state``), where its stores go.
    """
    path = workdir / f"truth-{node_id}.json"
    path.write_text(json.dumps(truth))
    argv = ["sim", *bus_flags(hub, node_id), "--truth", str(path)]
    argv += ["--state", str(state)] if state is not None else []
    proc = fork_cli(argv, workdir, f"sim-{node_id}")
    deadline = time.monotonic() + 30.0
    while not proc.stdout.startswith("ready"):
        if proc.poll() is not None or time.monotonic() > deadline:
            proc.stop()
            raise RuntimeError(f"simulated node did not start: {proc.stderr}")
        time.sleep(0.01)
    return proc
