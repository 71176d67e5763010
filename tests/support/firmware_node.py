"""The reference firmware's Linux node (``firmware/build/imu_node``) as a process on vcan.

CANopenNode v4 with CANopenLinux's stock ``CO_main_basic.c``, the project's ``imu_cal``
module and a synthetic sensor (``firmware/linux``). ``make -C firmware node`` builds it
statically on the host (``scripts/test_vcan.sh`` does), so it runs inside the canvm VM too.

:class:`FirmwareNode` keeps the node's storage directory across restarts (its flash); with
``respawn`` a node that ends on an NMT reset node is started again, as an MCU resets.
"""

from __future__ import annotations

import os
import signal
import subprocess
import threading
import time
from collections.abc import Mapping
from pathlib import Path

PROJECT = Path(__file__).resolve().parents[2]
NODE_BINARY = Path(os.environ.get("IMU_NODE_BIN") or PROJECT / "firmware" / "build" / "imu_node")
READY = ", running ..."
"""CANopenLinux's log line once CAN is in normal mode (after the module's "imu_node: ready")."""


class FirmwareNode:
    """One reference node: ``start``, ``wait_ready``, ``restart`` (power cycle), ``stop``.

    ``env`` are the node's ``IMU_NODE_*`` settings (see ``firmware/linux/imu_node.c``).
    """

    kind = "canopennode"

    def __init__(
        self,
        channel: str,
        node_id: int,
        storage: Path,
        env: Mapping[str, object] | None = None,
        *,
        respawn: bool = False,
    ) -> None:
        self.channel = channel
        self.node_id = node_id
        self.storage = storage
        self.env = {key: str(value) for key, value in (env or {}).items()}
        self.respawn = respawn
        self.lines: list[str] = []
        self.starts = 0
        self.proc: subprocess.Popen[str] | None = None
        self._ready = threading.Condition()
        self._readies = 0
        self._output_ended = threading.Event()  # the current process's output read to its end
        self._stopping = False
        self._lock = threading.Lock()  # start and the respawn's check-and-spawn, one at a time
        storage.mkdir(parents=True, exist_ok=True)

    def start(self) -> FirmwareNode:
        """Start the process (its storage as left by the last run)."""
        with self._lock:
            self._stopping = False
            self._spawn()
        return self

    def _spawn(self) -> None:
        argv = [str(NODE_BINARY), self.channel, "-i", str(self.node_id), "-s", f"{self.storage}/"]
        self.proc = subprocess.Popen(
            argv,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            env={**os.environ, **self.env},
        )
        self.starts += 1
        self._output_ended.clear()
        threading.Thread(target=self._read, args=(self.proc,), daemon=True).start()

    def _read(self, proc: subprocess.Popen[str]) -> None:
        assert proc.stdout is not None
        for line in proc.stdout:
            self.lines.append(line.rstrip("\n"))
            if READY in line:
                with self._ready:
                    self._readies += 1
                    self._ready.notify_all()
        if proc is self.proc:
            self._output_ended.set()
        code = proc.wait()
        with self._lock:  # only the current process is respawned: after a restart (stop,
            # then start) the old one's reader must not start a second node beside the new
            if self.respawn and not self._stopping and code == 0 and proc is self.proc:
                self.lines.append("(reset: started again)")
                self._spawn()

    def wait_ready(self, timeout_s: float, count: int | None = None) -> None:
        """Wait until the node printed its ready line ``count`` times (default: each start)."""
        wanted = self.starts if count is None else count
        deadline = time.monotonic() + timeout_s
        with self._ready:
            while self._readies < wanted:
                left = deadline - time.monotonic()
                if left <= 0 or (self.proc is not None and self.proc.poll() not in (None, 0)):
                    self._ready.release()  # let the reader take what the node printed last
                    try:
                        self._output_ended.wait(5.0)
                    finally:
                        self._ready.acquire()
                    code = None if self.proc is None else self.proc.poll()
                    raise AssertionError(
                        f"reference node did not start (exit status {code}):\n"
                        + "\n".join(self.lines)
                    )
                self._ready.wait(min(left, 0.2))

    @property
    def readies(self) -> int:
        """How many times the node came up (communication resets included)."""
        return self._readies

    def stop(self, timeout_s: float = 20.0) -> int:
        """SIGTERM (the node ends cleanly), kill if it does not; return its exit status."""
        self._stopping = True
        proc = self.proc
        if proc is None:
            return 0
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
            try:
                proc.wait(timeout=timeout_s)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        return int(proc.returncode)

    def restart(self, timeout_s: float) -> None:
        """Stop the process and start it again on the same storage (a power cycle)."""
        assert self.stop() == 0, "\n".join(self.lines)
        self.start()
        self.wait_ready(timeout_s)
