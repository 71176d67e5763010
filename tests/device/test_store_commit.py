"""The store as the commit point, restarts around it, a twin node, EMCY and heartbeat loss.

Issue 25, items 1–3 and "heartbeat loss and an EMCY during write-params". The simulated node
and the client are on python-can's virtual bus (real receive threads); a third bus on the
channel watches the SDO requests and acts at the k-th (a signal to this process, a fault
armed on the node). After each write, RAM is read by SDO and flash is the node's
non-volatile memory; both are held to what the tool said (``tests.support.claims``).
"""

from __future__ import annotations

import os
import signal
import threading
import time
import uuid
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import can
import pytest

from canimucal.device import od
from canimucal.device.client import ImuClient
from canimucal.device.transaction import WriteReport, write_calibration_transaction
from canimucal.errors import CanimucalError, DeviceError, DuplicateNodeError
from canimucal.io.calibration import Calibration
from canimucal.signals import HungUp, Terminated, handle_signals
from canimucal.sim.truth import Truth
from canimucal.simnode.node import SimulatedImuNode
from tests.support.calibrations import NODE_ID, SERIAL, calibration
from tests.support.claims import claimed

Raw = dict[tuple[int, int], bytes]
REQUEST = 0x600 + NODE_ID
STORE_HEAD = bytes([0x23, 0x10, 0x10, od.STORE_CALIBRATION_SUB])
OLD, NEW = calibration(1.05, 40.0), calibration(0.97, -12.0)
STORE_DELAY_S = 0.5
"""The node takes this long to answer a store (flash erase), so a signal sent when the store
request passes lands while the store is in flight."""


Trigger = Callable[[list[bytes]], bool]
"""Whether the requests so far (the latest last) call for the action."""


class RequestTap(can.Listener):
    """Records SDO requests to the node (on its own bus); runs an action at a trigger.

    Triggers look at the requests' bytes, not their count: a retried request under load
    must not move the action to another step.
    """

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.requests: list[bytes] = []
        self.armed: list[tuple[Trigger, Callable[[], None]]] = []

    def arm(self, *armed: tuple[Trigger, Callable[[], None]]) -> None:
        with self.lock:
            self.requests, self.armed = [], list(armed)

    def on_message_received(self, msg: can.Message) -> None:
        if msg.arbitration_id != REQUEST:
            return
        with self.lock:
            self.requests.append(bytes(msg.data))
            due = [a for a in self.armed if a[0](self.requests)]
            self.armed = [a for a in self.armed if a not in due]
        for _, action in due:
            action()


def is_(head: bytes) -> Trigger:
    """The latest request starts with ``head``."""
    return lambda requests: requests[-1].startswith(head)


def after_store(requests: list[bytes]) -> bool:
    """The request right after the store (the read-back of the serial)."""
    return len(requests) > 1 and requests[-2].startswith(STORE_HEAD)


def nth_write(n: int) -> Trigger:
    """The ``n``-th SDO download of the transaction (1: clear valid)."""
    return lambda requests: (
        requests[-1][0] & 0xE0 == 0x20 and sum(r[0] & 0xE0 == 0x20 for r in requests) == n
    )


@dataclass
class Rig:
    """Node (serial 4242, heartbeat 50 ms, slow store), client, request tap, backups."""

    node: SimulatedImuNode
    client: ImuClient
    tap: RequestTap
    backups: Path
    buses: list[can.BusABC] = field(default_factory=list)
    notifier: can.Notifier | None = None

    def ram(self, node: SimulatedImuNode | None = None) -> Raw:
        get = (node or self.node).local_node.get_data
        return {(i, s): bytes(get(i, s)) for i, s, _ in od.CALIBRATION_OBJECTS}

    def flash(self, node: SimulatedImuNode | None = None) -> Raw:
        stored = (node or self.node).stored_objects()
        return {(i, s): stored.get((i, s), b"") for i, s, _ in od.CALIBRATION_OBJECTS}


def _rig(tmp_path: Path, faults: dict[str, object] | None = None) -> Iterator[Rig]:
    channel = f"store-commit-{uuid.uuid4().hex[:8]}"
    buses = [can.Bus(interface="virtual", channel=channel) for _ in range(3)]
    truth = Truth.from_dict(
        {
            "serial": SERIAL,
            "sample_rate_hz": 50,
            "heartbeat_ms": 50,
            "store_delay_s": STORE_DELAY_S,
            "faults": faults or {},
        }
    )
    node = SimulatedImuNode(buses[0], NODE_ID, truth, state_file=tmp_path / "flash.json", seed=1)
    tap = RequestTap()
    notifier = can.Notifier(buses[2], [tap], timeout=0.02)
    node.start()
    client = ImuClient(buses[1], NODE_ID, sdo_timeout_s=0.5)
    assert client.heartbeat.seen.wait(2.0)
    rig = Rig(node, client, tap, tmp_path / "backups", buses, notifier)
    try:
        yield rig
    finally:
        client.close()
        node.stop()
        notifier.stop()
        for bus in buses:
            bus.shutdown()


@pytest.fixture
def rig(tmp_path: Path) -> Iterator[Rig]:
    yield from _rig(tmp_path)


@pytest.fixture(autouse=True)
def _default_handlers() -> None:
    """Pytest may run with SIGINT ignored (a background job): give it Python's default."""
    signal.signal(signal.SIGINT, signal.default_int_handler)


def write(rig: Rig, doc: dict[str, object]) -> WriteReport | BaseException:
    """One transaction with the tool's signal handling; what it returned or raised."""
    restore = handle_signals()
    try:
        return write_calibration_transaction(
            rig.client, Calibration.from_dict(doc), backup_dir=rig.backups
        )
    except (KeyboardInterrupt, CanimucalError) as exc:
        return exc
    finally:
        restore()


def _message(outcome: WriteReport | BaseException) -> str:
    if isinstance(outcome, KeyboardInterrupt):
        return "; ".join(getattr(outcome, "__notes__", []))
    return str(outcome)


def prepared(rig: Rig) -> tuple[Raw, Raw]:
    """Write NEW then OLD cleanly (both stored); return both sets."""
    assert isinstance(write(rig, NEW), WriteReport)
    new = rig.ram()
    assert isinstance(write(rig, OLD), WriteReport)
    old = rig.ram()
    assert rig.flash() == old and old != new
    rig.tap.arm()
    return old, new


def kill_me(signum: int) -> Callable[[], None]:
    """Send ``signum`` to this process, only while the tool's handler holds it.

    The tap runs on its own bus's thread, beside the node's answer: on a loaded machine the
    transaction may have ended (its handlers restored) before the tap acts, and the signal
    would then kill the test process (an xdist worker died so). Late, it is not sent: the
    test then fails on its outcome, saying so.
    """

    def send() -> None:
        if signal.getsignal(signum) in (signal.SIG_DFL, signal.default_int_handler):
            return
        os.kill(os.getpid(), signum)

    return send


def reboot_before(rig: Rig, later: int) -> Callable[[], None]:
    """Arm the node to power-cycle just before serving its ``later``-th request from now."""
    return lambda: rig.node.faults.set(reboot_before_sdo_request=later)


CRC_READ = bytes([0x40, 0x21, 0x21, od.CAL_CRC_SUB])
SET_VALID = bytes([0x2F, 0x21, 0x21, od.CAL_VALID_SUB, 1])


def verifying(requests: list[bytes]) -> bool:
    """The first read of step 9 (CRC, then valid, then the store): after valid = 1."""
    return requests[-1].startswith(CRC_READ) and any(r.startswith(SET_VALID) for r in requests)


# ------------------------------------------------------------------------- item 1


@pytest.mark.parametrize(
    ("signum", "kind"),
    [(signal.SIGINT, KeyboardInterrupt), (signal.SIGTERM, Terminated), (signal.SIGHUP, HungUp)],
)
def test_a_signal_while_the_store_is_in_flight_completes_it_and_says_so(
    rig: Rig, signum: int, kind: type[KeyboardInterrupt]
) -> None:
    old, new = prepared(rig)
    rig.tap.arm((is_(STORE_HEAD), kill_me(signum)))
    outcome = write(rig, NEW)
    assert type(outcome) is kind, outcome
    text = _message(outcome)
    assert "previous calibration restored" not in text, text  # flash holds the new set
    assert claimed(text) == ("new", "new"), text
    assert rig.ram() == new and rig.flash() == new
    assert str(sorted(rig.backups.iterdir())[-1]) in text  # the backup of the old set


def test_a_signal_after_the_store_answered_waits_for_the_read_back(rig: Rig) -> None:
    _, new = prepared(rig)
    rig.tap.arm((after_store, kill_me(signal.SIGTERM)))  # the serial read after the store
    outcome = write(rig, NEW)
    assert isinstance(outcome, Terminated), outcome
    assert claimed(_message(outcome)) == ("new", "new")
    assert rig.ram() == new and rig.flash() == new


def test_a_signal_before_the_store_rolls_back_and_flash_keeps_the_old_set(rig: Rig) -> None:
    old, _ = prepared(rig)
    rig.tap.arm((verifying, kill_me(signal.SIGINT)))  # verifying, before the store
    outcome = write(rig, NEW)
    assert type(outcome) is KeyboardInterrupt, outcome
    text = _message(outcome)
    assert "previous calibration restored from" in text and claimed(text) == ("old", "old")
    assert rig.ram() == old and rig.flash() == old
    assert len(rig.node.store_log) == 2  # the two stores of ``prepared``, none since


# ------------------------------------------------------------------------- item 2


def test_a_reboot_just_before_the_store_fails_with_what_the_node_holds(rig: Rig) -> None:
    old, _ = prepared(rig)
    # CRC read, valid read, then the store: it lands on a freshly booted node (had the node
    # counted the CRC read after the count restarted, the valid read would: the step fails
    # and is rolled back, as the message then says)
    rig.tap.arm((verifying, reboot_before(rig, 2)))
    outcome = write(rig, NEW)
    assert isinstance(outcome, DeviceError) and outcome.exit_code == 3, outcome
    text = str(outcome)
    assert "boot-up" in text and claimed(text) == ("old", "old"), text
    assert rig.ram() == old and rig.flash() == old


def test_a_reboot_right_after_the_store_fails_and_says_the_new_set_is_held(rig: Rig) -> None:
    _, new = prepared(rig)
    # armed while the node is busy storing (its 0.5 s flash erase): whether the node counted
    # the store before the count restarted or not, the power cycle comes after the store
    # and before one of the three reads after it
    rig.tap.arm((is_(STORE_HEAD), reboot_before(rig, 2)))
    outcome = write(rig, NEW)
    assert isinstance(outcome, DeviceError) and outcome.exit_code == 3, outcome
    assert claimed(str(outcome)) == ("new", "new"), outcome
    assert rig.ram() == new and rig.flash() == new


# ------------------------------------------------------- heartbeat loss, EMCY (not yet covered)


def test_heartbeat_loss_while_writing_fails_the_step_and_rolls_back(rig: Rig) -> None:
    old, _ = prepared(rig)
    rig.client.node.sdo.PAUSE_BEFORE_SEND = 0.01  # ~1 s of writing: longer than the gap limit
    rig.tap.arm((nth_write(1), lambda: rig.node.faults.set(heartbeat_loss={"from_s": 0.0})))
    outcome = write(rig, NEW)
    assert isinstance(outcome, DeviceError) and outcome.exit_code == 3, outcome
    text = str(outcome)
    assert "no heartbeat from node 16 for" in text and "previous calibration restored" in text
    assert rig.ram() == old and rig.flash() == old


def test_an_emergency_while_writing_rolls_back(rig: Rig) -> None:
    old, _ = prepared(rig)
    rig.tap.arm((nth_write(10), lambda: rig.node.send_emergency(0x5000, 0x01)))
    outcome = write(rig, NEW)
    assert isinstance(outcome, DeviceError) and outcome.exit_code == 3, outcome
    text = str(outcome)
    assert "node 16 sent an emergency: 0x5000 device hardware (error register 0x01)" in text
    assert "previous calibration restored from" in text, text
    assert rig.ram() == old and rig.flash() == old


def test_a_communication_emergency_does_not_stop_the_write(rig: Rig) -> None:
    _, new = prepared(rig)
    rig.tap.arm((nth_write(10), lambda: rig.node.send_emergency(0x8130, 0x11)))  # heartbeat
    assert isinstance(write(rig, NEW), WriteReport)
    assert rig.ram() == new and rig.flash() == new


def _operational(rig: Rig) -> None:
    rig.client.node.nmt.send_command(0x01)  # start: heartbeats say OPERATIONAL
    deadline = time.monotonic() + 5.0
    while rig.client.node_state != "OPERATIONAL" and time.monotonic() < deadline:
        time.sleep(0.01)
    assert rig.client.node_state == "OPERATIONAL"


def test_a_reset_to_pre_operational_with_no_nmt_on_the_bus_fails_the_step(rig: Rig) -> None:
    old, _ = prepared(rig)
    _operational(rig)
    rig.client.node.sdo.PAUSE_BEFORE_SEND = 0.005  # heartbeats (50 ms) arrive meanwhile
    reset = lambda: rig.node.local_node.nmt.send_command(0x80)  # noqa: E731  (no frame sent)
    rig.tap.arm((nth_write(5), reset))
    outcome = write(rig, NEW)
    assert isinstance(outcome, DeviceError) and outcome.exit_code == 3, outcome
    text = str(outcome)
    assert "went from OPERATIONAL to PRE-OPERATIONAL with no NMT command on the bus" in text
    assert "previous calibration restored from" in text
    assert rig.ram() == old and rig.flash() == old


def test_another_masters_nmt_command_does_not_stop_the_write(rig: Rig) -> None:
    _, new = prepared(rig)
    _operational(rig)
    rig.client.node.sdo.PAUSE_BEFORE_SEND = 0.005
    stop = can.Message(arbitration_id=0x000, data=[0x80, NODE_ID], is_extended_id=False)
    rig.tap.arm((nth_write(5), lambda: rig.buses[2].send(stop)))  # "enter pre-operational"
    assert isinstance(write(rig, NEW), WriteReport)
    assert rig.ram() == new and rig.flash() == new


# ------------------------------------------------------------------------- item 3


@pytest.fixture
def twin_rig(tmp_path: Path) -> Iterator[Rig]:
    yield from _rig(tmp_path, {"twin_serial": 5555})


def test_a_second_device_as_node_16_is_refused_before_anything_is_written(
    twin_rig: Rig,
) -> None:
    rig = twin_rig
    twin = rig.node.twin
    assert twin is not None
    before = {n: (rig.ram(n), rig.flash(n)) for n in (rig.node, twin)}
    outcome = write(rig, NEW)
    assert isinstance(outcome, DuplicateNodeError) and outcome.exit_code == 4, outcome
    assert str(outcome) == "two devices answer as node 16 (serials 4242 and 5555): nothing written"
    downloads = [r for r in rig.tap.requests if r[0] & 0xE0 == 0x20]
    assert downloads == []  # not one SDO download reached either unit
    assert {n: (rig.ram(n), rig.flash(n)) for n in (rig.node, twin)} == before
