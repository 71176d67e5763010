"""Interrupted and overlapping ``write-params`` across processes (issue 13, 1–3).

A :class:`ProcessRig` is a :class:`~tests.support.tcpbus.TcpHub`, ``canimucal sim`` in its own
process, and this process's own client on the hub (it reads the device back from outside).
:meth:`ProcessRig.interrupted_write` forks a ``canimucal write-params`` and, when that
process puts its k-th SDO request on the bus, sends it SIGTERM, SIGINT, or SIGINT twice
5–20 ms apart; :func:`check_interrupted` then holds the outcome to the contract: exit 0, 130,
143 or 3 only; never valid = 1 over a mixed set; 130/143 leave the old set (rolled back,
the backup named on stderr); never a traceback. :meth:`ProcessRig.two_writers` starts two
writers of different sets, the second when the first has sent its k-th request.

The rig alternates between two calibration sets (A, B): each run writes the one the device
does not hold, so no reset is needed between runs unless a run leaves valid = 0.
"""

from __future__ import annotations

import json
import signal
import threading
import time
from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import can
import numpy as np

from canimucal.device import od
from canimucal.device.client import ImuClient
from canimucal.device.transaction import write_calibration_transaction
from canimucal.io.calibration import Calibration
from tests.support import tcpbus
from tests.support.calibrations import NODE_ID, SERIAL, calibration
from tests.support.processes import CliProcess, bus_flags, fork_cli, start_sim_node

SDO_REQUEST = 0x600 + NODE_ID
EXIT_CODES = {0, 3, 130, 143}
Raw = dict[tuple[int, int], bytes]
KINDS = ("term", "int", "double")


@dataclass
class Outcome:
    """What one interrupted write did: the signals, exit status, device state, stderr."""

    kind: str
    step: int
    code: int
    state: str  # "old", "new", "invalid"
    stderr: str
    backups: list[Path]  # written by this run

    @property
    def label(self) -> str:
        return f"{self.kind}:{self.code}:{self.state}"


class RequestCounter:
    """A hub tap counting SDO requests to the node; runs ``actions[k]`` at the k-th."""

    def __init__(self) -> None:
        self.count = 0
        self.actions: dict[int, Any] = {}
        self.senders: list[int] = []
        """The hub connection number of each request since :meth:`arm`, in bus order."""
        self.times: list[float] = []
        """The hub's ``time.monotonic()`` at each of those requests."""
        self.lock = threading.Lock()

    def arm(self, actions: dict[int, Any]) -> None:
        with self.lock:
            self.count, self.actions, self.senders, self.times = 0, dict(actions), [], []

    def __call__(self, number: int, msg: can.Message) -> None:
        if msg.arbitration_id != SDO_REQUEST:
            return
        with self.lock:
            self.count += 1
            self.senders.append(number)
            self.times.append(time.monotonic())
            action = self.actions.pop(self.count, None)
        if action is not None:
            action()


class ProcessRig:
    """Hub, simulated node process and this process's own client (see the module doc)."""

    def __init__(self, workdir: Path, *, sdo_timeout_s: float = 0.5) -> None:
        tcpbus.register()
        self.workdir = workdir
        self.backups = workdir / "backups"
        self.hub = tcpbus.TcpHub()
        self.counter = RequestCounter()
        self.hub.taps.append(self.counter)
        truth = {"serial": SERIAL, "sample_rate_hz": 50, "heartbeat_ms": 50}
        self.node = start_sim_node(self.hub, workdir, truth, node_id=NODE_ID)
        self.bus = tcpbus.TcpBus(self.hub.channel)
        self.client = ImuClient(self.bus, NODE_ID, sdo_timeout_s=sdo_timeout_s)
        self.sdo_timeout_s = sdo_timeout_s
        self.files: dict[str, Path] = {}
        self.sets: dict[str, Raw] = {}
        for name, (scale, bias) in {"A": (1.05, 40.0), "B": (0.97, -12.0)}.items():
            self.add_set(name, scale, bias)
        self.holds = "B"
        self.requests_per_write = self._count_requests("A")

    def add_set(self, name: str, scale: float, bias: float) -> None:
        """Learn the device bytes of a further set (written, then the held set put back)."""
        if name in self.sets:
            return
        held = getattr(self, "holds", None)
        path = self.workdir / f"cal-{name}.json"
        path.write_text(json.dumps(calibration(scale, bias)))
        self.files[name] = path
        self.put(name)
        self.sets[name] = self.raw()
        if held is not None:
            self.put(held)

    def close(self) -> None:
        self.client.close()
        self.bus.shutdown()
        self.node.stop()
        self.hub.close()

    # ------------------------------------------------------------------ the device
    def raw(self) -> Raw:
        """The calibration objects as the node answers them now (through our own client)."""
        return {(i, s): self.client.read_raw(i, s, c) for i, s, c in od.CALIBRATION_OBJECTS}

    def put(self, name: str) -> None:
        """Write and store set ``name`` with our own client (no interruption)."""
        record = Calibration.from_json(self.files[name])
        write_calibration_transaction(self.client, record, backup_dir=self.workdir / "own")
        self.holds = name

    def state_of(self, raw: Raw) -> str:
        """``old``/``new``/``invalid`` against the set held before; mixed valid = 1 raises."""
        old, new = self.sets[self.holds], self.sets[self.other]
        if raw == old:
            return "old"
        if raw == new:
            return "new"
        if raw[(od.CAL_INFO, od.CAL_VALID_SUB)] == b"\x00":
            return "invalid"
        raise AssertionError("valid = 1 over a mixed set")

    @property
    def other(self) -> str:
        return "A" if self.holds == "B" else "B"

    # ------------------------------------------------------------------ writers
    def writer(self, name: str, tag: str, *extra: str) -> CliProcess:
        """Fork ``canimucal write-params`` of set ``name``."""
        argv = ["write-params", str(self.files[name]), *bus_flags(self.hub, NODE_ID)]
        argv += ["--backup-dir", str(self.backups), "--sdo-timeout", str(self.sdo_timeout_s)]
        return fork_cli([*argv, *extra], self.workdir, tag)

    def _count_requests(self, name: str) -> int:
        self.counter.arm({})
        proc = self.writer(name, "count")
        code = proc.wait(60.0)
        assert code == 0, proc.stderr
        self.holds = name
        return self.counter.count

    def interrupted_write(self, kind: str, step: int, gap_s: float) -> Outcome:
        """One write of the other set, signalled at its ``step``-th SDO request."""
        holder: list[CliProcess] = []
        timers: list[threading.Timer] = []
        first = signal.SIGTERM if kind == "term" else signal.SIGINT

        fired = threading.Event()

        def fire() -> None:
            try:
                holder[0].signal(first)
                if kind == "double":
                    timers.append(threading.Timer(gap_s, holder[0].signal, (signal.SIGINT,)))
                    timers[0].start()
            finally:
                fired.set()

        self.counter.arm({step: fire})
        target = self.other
        before = set(self.backups.glob("*")) if self.backups.exists() else set()
        proc = self.writer(target, "storm")
        holder.append(proc)
        proc.wait_ended(60.0)  # not reaped yet: a second signal still due cannot hit another pid
        with self.counter.lock:
            reached = step not in self.counter.actions
        if reached:
            fired.wait(10.0)
        self.counter.arm({})
        for timer in timers:
            timer.join()
        code = proc.wait(60.0)
        state = self.state_of(self.raw())
        taken = sorted(set(self.backups.glob("*")) - before) if self.backups.exists() else []
        outcome = Outcome(kind, step, code, state, proc.stderr, taken)
        if state == "new":
            self.holds = target
        elif state == "invalid":
            self.put(self.holds)
        return outcome


def check_interrupted(outcome: Outcome, backups: Path) -> None:
    """The contract for one interrupted write (see the module doc)."""
    err = outcome.stderr
    where = f"{outcome.kind} at request {outcome.step}: exit {outcome.code}, stderr {err!r}"
    assert outcome.code in EXIT_CODES, where
    assert "Traceback" not in err and "internal error" not in err, where
    if outcome.code == 0:
        assert outcome.state == "new", where
        return
    for backup in outcome.backups:  # a backup taken by an unfinished write is named to the user
        assert str(backup) in err, where
    if outcome.code in (130, 143):
        word = "terminated" if outcome.code == 143 else "interrupted"
        assert err.strip().splitlines()[-1].startswith(word), where
        assert outcome.state == "old", where
        if "restored" in err:
            assert f"previous calibration restored from {backups}" in err, where
        return
    assert outcome.state in ("old", "invalid"), where  # exit 3: said why, backup named
    assert "\nerror: " in f"\n{err}", where
    if outcome.state == "invalid":
        assert f"restore with canimucal write-params {backups}" in err, where


def storm(rig: ProcessRig, runs: int, seed: int) -> Counter[str]:
    """``runs`` interrupted writes at seeded random steps; every outcome checked."""
    rng = np.random.default_rng(seed)
    tally: Counter[str] = Counter()
    for _ in range(runs):
        kind = str(rng.choice(KINDS))
        step = int(rng.integers(1, rig.requests_per_write + 1))
        gap_s = float(rng.uniform(0.005, 0.020))
        outcome = rig.interrupted_write(kind, step, gap_s)
        check_interrupted(outcome, rig.backups)
        named = "restored" in outcome.stderr
        tally[outcome.label + (":backup named" if named else "")] += 1
    return tally
