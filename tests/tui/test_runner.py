"""The TUI's session runner: batching, coalescing, commands on the I/O thread, failures."""

from __future__ import annotations

import threading
from typing import Any

import numpy as np

from canimucal.errors import DeviceError
from canimucal.procedure import events as ev
from canimucal.procedure.machine import Phase
from canimucal.runtime.session import SessionCommand, WriteOptions
from canimucal.tui.runner import SessionRunner, coalesce


def _live(node: int, t: float) -> ev.SamplesReceived:
    return ev.SamplesReceived(node, t, np.zeros(3), np.zeros(3), 25.0, None, 1.0, (), 0)


def test_coalesce_keeps_the_latest_readout_per_node_and_every_other_event() -> None:
    events: list[ev.Event] = [
        _live(16, 1.0),
        _live(17, 1.0),
        ev.AveragingProgressed(0, 1.0, 10.0, 9.0),
        ev.PositionRejected(0, "motion"),
        _live(16, 2.0),
        ev.AveragingProgressed(0, 2.0, 10.0, 8.0),
    ]
    out = coalesce(events)
    assert out == [events[1], events[3], events[4], events[5]]


class FakeProcedure:
    def __init__(self) -> None:
        self.phase = Phase.INSTRUCT


class FakeSession:
    """Polls give one live event each; ACCEPT ends the procedure; a poll may raise."""

    def __init__(self, fail_after: int | None = None) -> None:
        self.procedure = FakeProcedure()
        self.polls = 0
        self.fail_after = fail_after
        self.finished = 0
        self.threads: set[str] = set()
        self.commands: list[SessionCommand | WriteOptions] = []

    def start(self) -> list[ev.Event]:
        return [ev.PhaseChanged(Phase.INSTRUCT, None)]

    def poll(self, timeout_s: float = 0.05) -> list[ev.Event]:
        self.threads.add(threading.current_thread().name)
        self.polls += 1
        if self.fail_after is not None and self.polls > self.fail_after:
            raise DeviceError("node 16 sent no samples for 5 s; what was recorded is kept")
        return [_live(16, float(self.polls))]

    def command(self, command: SessionCommand) -> list[ev.Event]:
        self.threads.add(threading.current_thread().name)
        self.commands.append(command)
        if command is SessionCommand.ACCEPT:
            self.procedure.phase = Phase.DONE
            return [ev.PhaseChanged(Phase.DONE, Phase.INSTRUCT), ev.ProcedureFinished()]
        return []

    def write(self, options: WriteOptions) -> list[ev.Event]:
        self.threads.add(threading.current_thread().name)
        self.commands.append(options)
        return []

    def finish(self) -> None:
        self.finished += 1


def _run(session: Any, runner: SessionRunner) -> tuple[list[list[ev.Event]], threading.Thread]:
    batches: list[list[ev.Event]] = []
    thread = threading.Thread(target=runner.run, args=(batches.append,), name="io")
    thread.start()
    return batches, thread


def test_commands_run_on_the_io_thread_and_events_come_in_few_batches() -> None:
    session = FakeSession()
    runner = SessionRunner(session, batch_period_s=0.05)  # type: ignore[arg-type]
    batches, thread = _run(session, runner)
    threading.Event().wait(0.3)
    runner.send(SessionCommand.CONFIRM_POSE)
    runner.send(WriteOptions(override=True))
    runner.send(SessionCommand.ACCEPT)
    thread.join(5.0)
    assert not thread.is_alive() and runner.finished.is_set()
    expected = [SessionCommand.CONFIRM_POSE, WriteOptions(override=True), SessionCommand.ACCEPT]
    assert session.commands == expected and session.threads == {"io"}
    assert session.finished == 1
    flat = [e for b in batches for e in b]
    assert isinstance(flat[-1], ev.ProcedureFinished)
    # hundreds of polls, but at most one batch per 50 ms (plus the last one)
    assert session.polls > len(batches) and len(batches) <= 0.5 / 0.05 + 2
    assert all(sum(isinstance(e, ev.SamplesReceived) for e in b) <= 1 for b in batches)


def test_a_device_error_ends_the_loop_with_a_failure_event_and_closes_the_files() -> None:
    session = FakeSession(fail_after=3)
    runner = SessionRunner(session, batch_period_s=0.0)  # type: ignore[arg-type]
    batches, thread = _run(session, runner)
    thread.join(5.0)
    failures = [e for b in batches for e in b if isinstance(e, ev.ProcedureFailed)]
    assert len(failures) == 1 and failures[0].title == "Device error"
    assert "no samples" in failures[0].message and session.finished == 1


def test_stop_ends_the_loop() -> None:
    session = FakeSession()
    runner = SessionRunner(session)  # type: ignore[arg-type]
    _, thread = _run(session, runner)
    runner.stop()
    thread.join(5.0)
    assert not thread.is_alive() and session.finished == 1
