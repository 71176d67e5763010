"""Signals and two writers across processes (issue 13, items 1, 2, 3 and 10; issue 25).

Every command here is a separate process (forked, running ``canimucal.cli.main.main``) on
one cross-process bus (:mod:`tests.support.tcpbus`); the simulated node is ``canimucal sim``
in its own process; this process reads the device back through its own client on the bus,
as an outside observer would. See :mod:`tests.support.storm` for the contract checked.
"""

from __future__ import annotations

import signal
import threading
import time
from collections import Counter
from collections.abc import Iterator
from pathlib import Path

import can
import numpy as np
import pytest

from canimucal.device import od
from canimucal.runtime.inputs import read_recording
from tests.support import tcpbus
from tests.support.canbus import FrameRecorder
from tests.support.processes import bus_flags, fork_cli
from tests.support.storm import NODE_ID, ProcessRig, SignalPlan, check_interrupted, storm

SEED = 20261127
RUNS = 30  # issue 25: a seeded 30 in the suite (300+: benchmarks/soak.py --processes N)
TPDO1 = 0x180 + NODE_ID
HEARTBEAT = 0x700 + NODE_ID
PRE_OPERATIONAL, OPERATIONAL = 0x7F, 0x05
IN_FLIGHT_S = 0.5
"""Longest hub gap between writer one's last request and writer two's first for which two may
still see one's request after its transaction began: the frame was in flight to two's
listener thread (socket, scheduling) when two sent its first request. A real CAN bus has the
same window. Two aborting after a longer quiet gap would be a spurious abort."""


@pytest.fixture(scope="module")
def rig(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ProcessRig]:
    # the commands' modules are imported once here, so each forked command starts at once
    import canimucal.cli.record_cmd  # noqa: F401
    import canimucal.cli.sim_cmd  # noqa: F401
    import canimucal.cli.write_params_cmd  # noqa: F401
    import canimucal.runtime.wiring  # noqa: F401
    import canimucal.simnode.node  # noqa: F401

    rig = ProcessRig(tmp_path_factory.mktemp("processes"))
    yield rig
    rig.close()


@pytest.fixture(autouse=True)
def _default_handlers() -> None:
    """Pytest may run with SIGINT ignored (a background job): give it Python's default."""
    signal.signal(signal.SIGINT, signal.default_int_handler)


def test_signal_storm_across_processes(rig: ProcessRig) -> None:
    """30 seeded runs of the storm (300+: ``benchmarks/soak.py --processes 300``)."""
    started = time.monotonic()
    tally = storm(rig, RUNS, SEED)
    took = time.monotonic() - started
    print(f"\n{RUNS} interrupted write-params processes in {took:.1f} s: {sorted(tally.items())}")
    windows = Counter(label.split(":")[0] for label in tally.elements())
    kinds = {label.split(":")[1] for label in tally}
    assert windows["store"] >= RUNS // 3, windows  # the store window, aimed at
    assert {"int", "term", "hup"} <= {k.split("+")[0] for k in kinds}, kinds
    assert any("+" in k for k in kinds), kinds  # pairs too
    changed = sum(n for label, n in tally.items() if "said RAM" in label)
    assert changed >= RUNS // 4, tally  # a real share landed after the backup


def test_a_double_ctrl_c_names_the_backup_wherever_the_second_lands(rig: ProcessRig) -> None:
    """The flaky case of issue 25: Ctrl-C twice late in the write, the second at any moment.

    The first lands while the block is being read back; the second 5 ms to 0.3 s later, in
    the rollback or while the process closes its bus. Every run names the backup it took.
    """
    late = rig.requests_per_write - 12
    for gap_s in (0.005, 0.02, 0.06, 0.12, 0.2, 0.3):
        outcome = rig.interrupted_write(SignalPlan("int+int", "step", step=late, gap_s=gap_s))
        check_interrupted(outcome, rig.backups)
        assert outcome.code == 130 and outcome.backups, outcome
        assert str(outcome.backups[0]) in outcome.stderr.strip().splitlines()[-1]


def overlapped(senders: list[int]) -> bool:
    """Whether two clients' SDO requests interleaved on the bus (not one block, then the other)."""
    changes = sum(a != b for a, b in zip(senders, senders[1:], strict=False))
    return changes > 1


def switch_gap(senders: list[int], times: list[float]) -> float:
    """Hub seconds between the last request before the first change of sender and the next."""
    for i in range(1, len(senders)):
        if senders[i] != senders[i - 1]:
            return times[i] - times[i - 1]
    return float("inf")


def _overlapping(
    rig: ProcessRig, delay_s: float
) -> tuple[str, int, int, str, str, str, bool, float]:
    """Writer 1 (the other set), and writer 2 (set C) ``delay_s`` after writer 1's first request."""
    first_name = rig.other
    reached = threading.Event()
    rig.counter.arm({1: reached.set})
    one = rig.writer(first_name, "one")
    reached.wait(30.0)
    time.sleep(delay_s)
    two = rig.writer("C", "two")
    code_one, code_two = one.wait(60.0), two.wait(60.0)
    both = overlapped(rig.counter.senders)
    gap = switch_gap(rig.counter.senders, rig.counter.times)
    rig.counter.arm({})
    raw = rig.raw()
    held = next((name for name, s in rig.sets.items() if s == raw), "invalid")
    if held == "invalid":
        assert raw[(od.CAL_INFO, od.CAL_VALID_SUB)] == b"\x00", "valid = 1 over a mixed set"
    return first_name, code_one, code_two, held, one.stderr, two.stderr, both, gap


def test_overlapping_writers_in_two_processes_never_both_succeed(rig: ProcessRig) -> None:
    rig.add_set("C", 1.02, 7.0)
    outcomes: list[tuple[float, bool, int, int, str]] = []
    rng = np.random.default_rng(SEED)
    while sum(o[1] for o in outcomes) < 4 and len(outcomes) < 30:  # until 4 really overlapped
        delay_s = round(float(rng.uniform(0.0, 0.05)), 3)
        old = rig.holds
        first, code_one, code_two, held, err_one, err_two, both, gap = _overlapping(rig, delay_s)
        outcomes.append((delay_s, both, code_one, code_two, held))
        for code, err in ((code_one, err_one), (code_two, err_two)):
            assert code in (0, 3), (delay_s, code, err)
            assert "Traceback" not in err and "internal error" not in err, err
        if code_one != 0 and code_two != 0:
            # both told, each rolled back to the set it read before writing: two's read may
            # come after one's last write (its backup then holds one's whole set), so the
            # device keeps the old set, one's set or valid = 0, never a mix (``_overlapping``)
            assert held in (old, first, "invalid"), outcomes
            assert "another SDO client is using node 16" in err_one + err_two
        elif not both and code_two == 3:  # one's last request was still in flight to two
            assert code_one == 0 and held == first, outcomes
            assert "another SDO client" in err_two and gap < IN_FLIGHT_S, (gap, err_two)
        elif not both:  # one after the other on the bus: both succeed, the second set stays
            assert (code_one, code_two, held) == (0, 0, "C"), outcomes
        else:  # exactly one succeeded: its set is held
            assert not (code_one == 0 and code_two == 0), outcomes
            assert held == (first if code_one == 0 else "C"), outcomes
        if held == "invalid":
            rig.put(old)
        else:
            rig.holds = held
    print(f"\noverlapping writers (delay s, overlapped, exit 1, exit 2, device): {outcomes}")
    assert sum(o[1] for o in outcomes) >= 4, outcomes


def test_back_to_back_writers_in_two_processes_both_succeed(rig: ProcessRig) -> None:
    rig.add_set("C", 1.02, 7.0)
    first = rig.other
    assert rig.writer(first, "first").wait(60.0) == 0
    second = rig.writer("C", "second")
    assert second.wait(60.0) == 0, second.stderr
    assert rig.raw() == rig.sets["C"]
    rig.holds = "C"


@pytest.mark.parametrize("late", [False, True], ids=["while-writing", "while-storing"])
def test_sighup_during_write_params_is_told_and_never_leaves_valid_0(
    rig: ProcessRig, late: bool
) -> None:
    """Issue 25, item 4: the session closes mid-write; the process says what it left."""
    plan = (
        SignalPlan("hup", "store", delay_s=0.05)
        if late
        else SignalPlan("hup", "step", step=rig.requests_per_write // 2)
    )
    outcome = rig.interrupted_write(plan)
    check_interrupted(outcome, rig.backups)
    last = outcome.stderr.strip().splitlines()[-1]
    assert outcome.code == 129 and last.startswith("hung up; "), outcome
    if late:  # the store had begun: completed, and said so
        assert (outcome.ram, outcome.flash) == ("new", "new") and "RAM and flash hold" in last
    else:
        assert (outcome.ram, outcome.flash) == ("old", "old")
        assert last.startswith(f"hung up; previous calibration restored from {rig.backups}")


@pytest.mark.parametrize(
    ("signum", "code", "word"),
    [(signal.SIGTERM, 143, "terminated"), (signal.SIGHUP, 129, "hung up")],
)
def test_a_signal_during_record_leaves_the_node_as_found(
    rig: ProcessRig, tmp_path: Path, signum: int, code: int, word: str
) -> None:
    observer = tcpbus.TcpBus(rig.hub.channel)
    frames = FrameRecorder()
    notifier = can.Notifier(observer, [frames], timeout=0.05)
    try:
        out = tmp_path / "cut.csv"
        argv = ["record", str(out), "--position", "0", "--alpha-deg", "0", "--beta-deg", "0"]
        argv += ["--seconds", "60", "--no-pose-check", *bus_flags(rig.hub, NODE_ID)]
        proc = fork_cli(argv, tmp_path, "record")
        frames.wait_count(TPDO1, 20, timeout=20.0)  # streaming
        beats = frames.frames(HEARTBEAT)
        assert beats and beats[-1].data[0] == OPERATIONAL
        proc.signal(signum)
        got = proc.wait(30.0)
        stopped = time.time()
        assert got == code, proc.stderr
        assert proc.stderr.strip().splitlines()[-1] == word, proc.stderr
        assert "Traceback" not in proc.stderr
        assert read_recording(out).n_rows > 10  # closed, renamed: --append goes on with it
        assert not out.with_name(out.name + ".partial").exists()
        time.sleep(0.5)
        late = [f for f in frames.frames(TPDO1) if f.timestamp > stopped + 0.05]
        assert not late, f"{len(late)} TPDOs after the tool exited: node left streaming"
        beats = [f for f in frames.frames(HEARTBEAT) if f.timestamp > stopped + 0.05]
        assert beats and {f.data[0] for f in beats} == {PRE_OPERATIONAL}
    finally:
        notifier.stop()
        observer.shutdown()
