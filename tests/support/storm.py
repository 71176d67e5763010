"""Interrupted and overlapping ``write-params`` across processes (issue 13; issue 25's storm).

A :class:`ProcessRig` is a :class:`~tests.support.tcpbus.TcpHub`, ``canimucal sim`` in its own
process (its flash a state file, its store taking :data:`STORE_DELAY_S`, heartbeat 50 ms),
and this process's own client on the hub (it reads the device back from outside).
:meth:`ProcessRig.interrupted_write` forks a ``canimucal write-params`` and signals it per a
:class:`SignalPlan`: SIGINT, SIGTERM, SIGHUP or a pair of them (the second 5–300 ms after
the first), at the k-th SDO request the process puts on the bus or in the store window (the
store request plus a delay within the node's flash erase, or just after it, while the tool
reads back). :func:`check_interrupted` holds the outcome to the contract (docs/design.md
§9): exit 0, 3, 129, 130 or 143 only, never a traceback, every backup taken named; RAM and
flash each hold one whole set (the old or the new) or RAM holds valid = 0, and the message
says which (``tests.support.claims``): a run whose device holds other than what its message
says is *silent*, and one where RAM and flash differ without the message saying so is an
*unreported disagreement*. :meth:`ProcessRig.two_writers` starts two writers of different
sets, the second when the first has sent its k-th request.

The rig alternates between two calibration sets (A, B): each run writes the one the device
does not hold, so no reset is needed between runs unless a run leaves valid = 0 or RAM and
flash holding different sets.
"""

from __future__ import annotations

import json
import math
import signal
import threading
import time
from collections import Counter
from collections.abc import Callable
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
from tests.support.claims import claimed
from tests.support.processes import CliProcess, bus_flags, fork_cli, start_sim_node

SDO_REQUEST = 0x600 + NODE_ID
EXIT_CODES = {0, 3, 129, 130, 143}
INTERRUPT_WORDS = {129: "hung up", 130: "interrupted", 143: "terminated"}
Raw = dict[tuple[int, int], bytes]
SIGNALS = {"int": signal.SIGINT, "term": signal.SIGTERM, "hup": signal.SIGHUP}
KINDS = ("int", "term", "hup", "int+int", "int+term", "term+hup", "hup+int")
"""One signal, or a pair (the second 5–300 ms after the first)."""
STORE_HEAD = bytes([0x23, 0x10, 0x10, od.STORE_CALIBRATION_SUB])
STORE_DELAY_S = 0.2
"""How long the simulated node takes to answer a store (its flash erase)."""
STORE_SHARE = 0.4
"""Share of the runs that aim at the store window (the brief asks for at least a third)."""


@dataclass(frozen=True)
class SignalPlan:
    """What one run sends and when: ``window`` ``step`` (at request ``step``) or ``store``
    (``delay_s`` after the store request); a pair's second signal ``gap_s`` after the first.
    """

    kind: str
    window: str
    step: int = 0
    delay_s: float = 0.0
    gap_s: float = 0.0

    @property
    def signals(self) -> tuple[int, ...]:
        return tuple(SIGNALS[name] for name in self.kind.split("+"))


def draw_plan(rng: np.random.Generator, requests: int) -> SignalPlan:
    """A seeded plan: any kind, the store window in :data:`STORE_SHARE` of runs."""
    kind = str(rng.choice(KINDS))
    gap_s = float(math.exp(rng.uniform(math.log(0.005), math.log(0.3))))
    if rng.random() < STORE_SHARE:
        delay = float(rng.uniform(0.0, STORE_DELAY_S + 0.05))  # in the erase, or just after
        return SignalPlan(kind, "store", delay_s=delay, gap_s=gap_s)
    return SignalPlan(kind, "step", step=int(rng.integers(1, requests + 1)), gap_s=gap_s)


@dataclass
class Outcome:
    """What one interrupted write did: the plan, exit status, RAM, flash, stderr, backups."""

    plan: SignalPlan
    code: int
    ram: str  # "old", "new", "invalid"
    flash: str  # "old", "new"
    stderr: str
    backups: list[Path]  # written by this run

    @property
    def label(self) -> str:
        return f"{self.plan.kind}:{self.code}:{self.ram}/{self.flash}"


class RequestCounter:
    """A hub tap counting SDO requests to the node; runs an action at a trigger.

    ``actions[k]`` runs at the k-th request; ``on_store`` at the first store request.
    """

    def __init__(self) -> None:
        self.count = 0
        self.actions: dict[int, Any] = {}
        self.on_store: Callable[[], None] | None = None
        self.senders: list[int] = []
        """The hub connection number of each request since :meth:`arm`, in bus order."""
        self.times: list[float] = []
        """The hub's ``time.monotonic()`` at each of those requests."""
        self.lock = threading.Lock()

    def arm(self, actions: dict[int, Any], on_store: Callable[[], None] | None = None) -> None:
        with self.lock:
            self.count, self.actions, self.senders, self.times = 0, dict(actions), [], []
            self.on_store = on_store

    @property
    def pending(self) -> bool:
        """Whether an armed action has not run yet."""
        with self.lock:
            return bool(self.actions) or self.on_store is not None

    def __call__(self, number: int, msg: can.Message) -> None:
        if msg.arbitration_id != SDO_REQUEST:
            return
        with self.lock:
            self.count += 1
            self.senders.append(number)
            self.times.append(time.monotonic())
            action = self.actions.pop(self.count, None)
            if bytes(msg.data[:4]) == STORE_HEAD and self.on_store is not None:
                action, self.on_store = self.on_store, None
        if action is not None:
            action()


class ProcessRig:
    """Hub, simulated node process and this process's own client (see the module doc)."""

    def __init__(self, workdir: Path, *, sdo_timeout_s: float = 0.5) -> None:
        tcpbus.register()
        self.workdir = workdir
        self.backups = workdir / "backups"
        self.flash_file = workdir / "flash.json"
        self.hub = tcpbus.TcpHub()
        self.counter = RequestCounter()
        self.hub.taps.append(self.counter)
        truth = {
            "serial": SERIAL,
            "sample_rate_hz": 50,
            "heartbeat_ms": 50,
            "store_delay_s": STORE_DELAY_S,
        }
        self.node = start_sim_node(self.hub, workdir, truth, node_id=NODE_ID, state=self.flash_file)
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

    def flash(self) -> Raw:
        """The calibration objects in the node's non-volatile memory (its state file)."""
        objects = json.loads(self.flash_file.read_text())["objects"]
        return {
            (i, s): bytes.fromhex(objects.get(od.format_key(i, s), ""))
            for i, s, _ in od.CALIBRATION_OBJECTS
        }

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

    def interrupted_write(self, plan: SignalPlan) -> Outcome:
        """One write of the other set, signalled per ``plan``."""
        holder: list[CliProcess] = []
        timers: list[threading.Timer] = []
        fired = threading.Event()
        first, *rest = plan.signals

        def fire() -> None:
            try:
                holder[0].signal(first)
                for later in rest:
                    timers.append(threading.Timer(plan.gap_s, holder[0].signal, (later,)))
                    timers[-1].start()
            finally:
                fired.set()

        def fire_later() -> None:
            timers.append(threading.Timer(plan.delay_s, fire))
            timers[-1].start()

        if plan.window == "store":
            self.counter.arm({}, on_store=fire_later)
        else:
            self.counter.arm({plan.step: fire})
        target = self.other
        before = set(self.backups.glob("*")) if self.backups.exists() else set()
        proc = self.writer(target, "storm")
        holder.append(proc)
        proc.wait_ended(60.0)  # not reaped yet: a second signal still due cannot hit another pid
        reached = not self.counter.pending
        for timer in list(timers):
            timer.join()
        if reached:
            fired.wait(10.0)
        for timer in list(timers):
            timer.join()
        self.counter.arm({})
        code = proc.wait(60.0)
        ram, flash = self.state_of(self.raw()), self.state_of(self.flash())
        taken = sorted(set(self.backups.glob("*")) - before) if self.backups.exists() else []
        outcome = Outcome(plan, code, ram, flash, proc.stderr, taken)
        if (ram, flash) == ("new", "new"):
            self.holds = target
        elif (ram, flash) != ("old", "old"):
            self.put(self.holds)  # RAM and flash back to one set
        return outcome


def judge(outcome: Outcome, backups: Path) -> tuple[str, list[str]]:
    """What one interrupted write's message claimed, and how it broke the contract (if it did).

    The problems are ``exit status``, ``traceback``, ``backup not named``, ``silent`` (the
    device holds other than the message says, or something changed and nothing was said),
    ``unreported disagreement`` (RAM and flash differ and the message does not say so, nor
    that flash is unknown) and ``not restorable`` (valid = 0 without the backup to restore).
    """
    err, code = outcome.stderr, outcome.code
    held = (outcome.ram, outcome.flash)
    problems: list[str] = []
    if code not in EXIT_CODES:
        problems.append("exit status")
    if "Traceback" in err or "internal error" in err:
        problems.append("traceback")
    if code == 0:
        return "stored", problems + ([] if held == ("new", "new") else ["silent"])
    if any(str(backup) not in err for backup in outcome.backups):
        problems.append("backup not named")
    last = err.strip().splitlines()[-1] if err.strip() else ""
    if last == INTERRUPT_WORDS.get(code):  # nothing more said: nothing may have changed
        quiet_ok = held == ("old", "old") and not outcome.backups
        return "nothing written", problems + ([] if quiet_ok else ["silent"])
    if code in INTERRUPT_WORDS and not last.startswith(INTERRUPT_WORDS[code]):
        problems.append("exit status")
    ram, flash = claimed(last)
    unknown_said = "known only after a power cycle" in last
    pairs = zip((ram, flash), held, strict=True)
    agrees = all(c == h or (c == "unknown" and unknown_said) for c, h in pairs)
    if not agrees:
        problems.append("unreported disagreement" if held[0] != held[1] else "silent")
    if outcome.ram == "invalid" and f"restore with canimucal write-params {backups}" not in err:
        problems.append("not restorable")
    return f"said RAM {ram}, flash {flash}", problems


def check_interrupted(outcome: Outcome, backups: Path) -> str:
    """Assert the contract for one interrupted write (:func:`judge`); return its label."""
    said, problems = judge(outcome, backups)
    where = f"{outcome.plan}: exit {outcome.code}, RAM {outcome.ram}, flash {outcome.flash}"
    assert not problems, f"{problems}: {where}, stderr {outcome.stderr!r}"
    return said


def storm(rig: ProcessRig, runs: int, seed: int) -> Counter[str]:
    """``runs`` interrupted writes per seeded :func:`draw_plan`; every outcome checked."""
    rng = np.random.default_rng(seed)
    tally: Counter[str] = Counter()
    for _ in range(runs):
        outcome = rig.interrupted_write(draw_plan(rng, rig.requests_per_write))
        said = check_interrupted(outcome, rig.backups)
        tally[f"{outcome.plan.window}:{outcome.label}:{said}"] += 1
    return tally
