"""SIGTERM, Ctrl-C and a second interrupt at random steps of a write (issue 13, 2 and 3).

The signal is sent to this process by a tap on the client's side of the loopback link when
the k-th SDO request goes out, so it lands wherever the transaction is (backup, block,
verification, rollback). Checks: never valid = 1 over a mixed set; an interrupt after the
backup always rolls back to the old set (a second interrupt is held back until the
rollback is done) and names the backup; SIGTERM surfaces as ``Terminated``.
A larger sample (≥ 200 runs) is in ``benchmarks/soak.py --signals``. Both nodes
(``either_loop_rig``): the simulated one and the independent durand one.
"""

from __future__ import annotations

import os
import signal
from collections import Counter
from collections.abc import Callable

import can
import numpy as np
import pytest

from canimucal.device import od
from canimucal.device.transaction import write_calibration_transaction
from canimucal.errors import DeviceError
from canimucal.io.calibration import Calibration
from canimucal.signals import Terminated, handle_sigterm
from tests.device.test_write_faults import (
    NODE_ID,
    LoopRig,
    Raw,
    _old_and_new,
    calibration,
    either_loop_rig,  # noqa: F401  (a fixture)
)
from tests.support.claims import claimed

SEED = 20261124
RUNS = 40


def signal_tap(plan: dict[int, int]) -> tuple[Callable[[can.Message], None], list[int]]:
    """A tap sending ``plan[k]`` to this process when the k-th SDO request goes out."""
    count = [0]

    def tap(msg: can.Message) -> None:
        if msg.arbitration_id != 0x600 + NODE_ID:
            return
        count[0] += 1
        if count[0] in plan:
            os.kill(os.getpid(), plan[count[0]])

    return tap, count


def interrupted_write(rig: LoopRig, plan: dict[int, int]) -> tuple[BaseException | None, int]:
    """Run one transaction with signals sent per ``plan``; return what it raised."""
    tap, count = signal_tap(plan)
    taps = rig.faulty._inner.taps  # type: ignore[attr-defined]
    taps.append(tap)
    restore = handle_sigterm()
    try:
        write_calibration_transaction(
            rig.client, Calibration.from_dict(calibration(0.97, -12.0)), backup_dir=rig.backups
        )
    except (KeyboardInterrupt, DeviceError) as exc:
        return exc, count[0]
    finally:
        restore()
        taps.remove(tap)
    return None, count[0]


def check_outcome(rig: LoopRig, old: Raw, new: Raw, plan: dict[int, int], raised: object) -> str:
    """Assert the device state against what the transaction reported; name the outcome."""
    state = rig.raw()
    valid = state[(od.CAL_INFO, od.CAL_VALID_SUB)]
    assert valid == b"\x00" or state in (old, new), f"{plan}: valid = 1 over a mixed set"
    if raised is None:
        assert state == new
        return "new"
    assert isinstance(raised, KeyboardInterrupt), raised
    first = plan[min(plan)]
    assert isinstance(raised, Terminated) == (first == signal.SIGTERM), raised
    notes = getattr(raised, "__notes__", [])
    if notes and "the store had begun" in notes[0]:  # the commit point passed: completed
        assert claimed(notes[0]) == ("new", "new") and state == new, f"{plan}: {notes}"
        if rig.device.kind == "simulated":  # its non-volatile memory is readable in process
            assert rig.stored() == new, f"{plan}: the store was said to be done"
        return "stored"
    if notes and notes[0].startswith("nothing written"):  # between the backup and writing
        assert state == old and str(rig.backups) in notes[0], f"{plan}: {notes}"
        return "before writing"
    if notes:  # interrupted after the backup: rolled back to the old set, backup named
        assert state == old, f"{plan}: interrupt reported a rollback, device does not hold old"
        assert notes[0].startswith(f"previous calibration restored from {rig.backups}")
        return "rolled back"
    assert state == old, f"{plan}: interrupted before writing, yet the device changed"
    return "before backup"


def test_interrupts_at_random_write_steps_always_roll_back(
    either_loop_rig: LoopRig,  # noqa: F811
) -> None:
    rig = either_loop_rig
    old, new, n_requests = _old_and_new(rig)
    rng = np.random.default_rng(SEED)
    tally: Counter[str] = Counter()
    for _ in range(RUNS):
        rig.load(old)
        kind = str(rng.choice(["term", "int", "double"]))
        k = int(rng.integers(1, n_requests + 1))
        if kind == "double":
            plan = {k: signal.SIGINT, k + int(rng.integers(1, 6)): signal.SIGTERM}
        else:
            plan = {k: signal.SIGTERM if kind == "term" else signal.SIGINT}
        raised, _ = interrupted_write(rig, plan)
        tally[f"{kind}:{check_outcome(rig, old, new, plan, raised)}"] += 1
    print(f"\n{RUNS} interrupted writes: {sorted(tally.items())}")
    assert sum(v for k, v in tally.items() if k.endswith("rolled back")) >= RUNS // 2


def test_second_interrupt_during_the_rollback_is_held_back(
    either_loop_rig: LoopRig,  # noqa: F811
) -> None:
    rig = either_loop_rig
    old, _, _ = _old_and_new(rig)
    rig.load(old)
    # request 64 is inside "write block" (after the 57–59 requests of identity, layout and
    # backup); 66 is the rollback's first few downloads
    raised, count = interrupted_write(rig, {64: signal.SIGTERM, 66: signal.SIGINT})
    assert isinstance(raised, Terminated)
    assert rig.raw() == old and count > 66
    assert "previous calibration restored from" in raised.__notes__[0]


def test_an_interrupt_at_the_store_completes_it_and_says_so(
    either_loop_rig: LoopRig,  # noqa: F811
) -> None:
    rig = either_loop_rig
    old, new, n_requests = _old_and_new(rig)
    rig.load(old)
    k_store = n_requests - 3  # the store, then serial, valid and CRC read back
    raised, _ = interrupted_write(rig, {k_store: signal.SIGINT, k_store + 1: signal.SIGTERM})
    assert type(raised) is KeyboardInterrupt  # the first signal's, the second dropped
    assert check_outcome(rig, old, new, {k_store: signal.SIGINT}, raised) == "stored"


@pytest.fixture(autouse=True)
def _default_handlers() -> None:
    """Pytest may run with SIGINT ignored (a background job): give it Python's default."""
    signal.signal(signal.SIGINT, signal.default_int_handler)
