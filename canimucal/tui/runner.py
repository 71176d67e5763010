"""The session runner of the TUI: one I/O thread owns the session, the UI sends it commands.

The screen's worker thread calls :meth:`SessionRunner.run`; it polls the session, runs the
commands the UI queued (a :class:`~canimucal.runtime.session.SessionCommand`, or the
:class:`~canimucal.runtime.session.WriteOptions` of a write) on the same thread (the
session is not thread-safe, and SDO writes block), and hands the events to the UI in
batches no more often than every ``batch_period_s`` (10–25 Hz). Within a batch only the
latest live readout per node and the latest progress event are kept: the UI shows the
newest value, so older ones are dropped before they cost a repaint.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from collections.abc import Callable

from canimucal.errors import CanimucalError
from canimucal.flag_words import worded_for_flags
from canimucal.procedure import events as ev
from canimucal.procedure.machine import Phase
from canimucal.runtime.session import Session, SessionCommand, WriteOptions

logger = logging.getLogger(__name__)

BATCH_PERIOD_S = 0.05
POLL_TIMEOUT_S = 0.02

Command = SessionCommand | WriteOptions
"""What the UI can queue: a session command, or the options of a write."""


def coalesce(events: list[ev.Event]) -> list[ev.Event]:
    """Drop live readouts and progress events superseded later in the same batch."""
    latest_live: dict[int, int] = {}
    latest_progress = -1
    for i, event in enumerate(events):
        if isinstance(event, ev.SamplesReceived):
            latest_live[event.node_id] = i
        elif isinstance(event, ev.AveragingProgressed):
            latest_progress = i
    keep = set(latest_live.values()) | {latest_progress}
    return [
        e
        for i, e in enumerate(events)
        if i in keep or not isinstance(e, ev.SamplesReceived | ev.AveragingProgressed)
    ]


class SessionRunner:
    """Runs a :class:`Session` on one thread; see the module doc."""

    def __init__(self, session: Session, *, batch_period_s: float = BATCH_PERIOD_S) -> None:
        self.session = session
        self.batch_period_s = batch_period_s
        self.commands: queue.Queue[Command] = queue.Queue()
        self.stopped = threading.Event()
        self.finished = threading.Event()

    def send(self, command: Command) -> None:
        """Queue a command for the I/O thread (returns at once)."""
        self.commands.put(command)

    def stop(self) -> None:
        """Ask the loop to end (what was recorded is kept)."""
        self.stopped.set()

    @property
    def phase(self) -> Phase:
        """The procedure's phase (read without locking: a display hint only)."""
        return self.session.procedure.phase

    def run(self, deliver: Callable[[list[ev.Event]], None]) -> None:
        """Start the session and loop until done, cancelled, stopped or failed."""
        pending: list[ev.Event] = []
        last = time.monotonic()
        try:
            pending += self.session.start()
            while not self.stopped.is_set():
                pending += self._run_commands()
                if self.phase in (Phase.DONE, Phase.CANCELLED):
                    break
                pending += self.session.poll(POLL_TIMEOUT_S)
                now = time.monotonic()
                if pending and now - last >= self.batch_period_s:
                    deliver(coalesce(pending))
                    pending, last = [], now
        except CanimucalError as exc:
            pending.append(ev.ProcedureFailed(" ".join(worded_for_flags(exc).split()), exc.title))
        except Exception as exc:  # a bug: shown in the modal, logged with its traceback
            logger.exception("session runner failed")
            pending.append(ev.ProcedureFailed(f"internal error: {exc}", "Internal error"))
        finally:
            pending += self._finish()
            deliver(coalesce(pending))

    def _finish(self) -> list[ev.Event]:
        try:
            self.session.finish()
        except CanimucalError as exc:
            return [ev.ProcedureFailed(worded_for_flags(exc), exc.title)]
        finally:
            self.finished.set()
        return []

    def _run_commands(self) -> list[ev.Event]:
        out: list[ev.Event] = []
        while True:
            try:
                command = self.commands.get_nowait()
            except queue.Empty:
                return out
            out += self._run(command)

    def _run(self, command: Command) -> list[ev.Event]:
        logger.debug("command %s in phase %s", command, self.phase)
        if isinstance(command, WriteOptions):
            return self.session.write(command)
        return self.session.command(command)
