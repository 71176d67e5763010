"""The position screen: the procedure's live view, and the home of its I/O worker.

The worker thread (one, exclusive) opens the session and runs
:meth:`~canimucal.tui.runner.SessionRunner.run`, which posts :class:`EventsArrived` batches
here; the handler updates the cached widgets. When the procedure solves or ends, the screen
tells the app (:class:`ResultsReady`, :class:`ProcedureEnded`), which shows the next screen.
Keys appear in the footer only in the phases where the procedure accepts them
(``check_action`` on the reactive ``phase``); skipping a position asks first.
"""

from __future__ import annotations

from collections.abc import Callable
from enum import Enum
from pathlib import Path

import numpy as np
from rich.text import Text
from textual import work
from textual.app import ComposeResult
from textual.binding import Binding
from textual.containers import Horizontal
from textual.reactive import reactive
from textual.screen import Screen
from textual.widgets import Footer, ProgressBar, Sparkline, Static

from canimucal.errors import CanimucalError
from canimucal.flag_words import worded_for_flags
from canimucal.procedure import events as ev
from canimucal.procedure.machine import Phase
from canimucal.runtime.certificate import verified_line
from canimucal.runtime.resume import resumed_message
from canimucal.runtime.session import SessionCommand, WriteOptions
from canimucal.tui.messages import EventsArrived, ProcedureEnded, ResultsReady
from canimucal.tui.modals import ConfirmSkip, ErrorModal
from canimucal.tui.runner import Command, SessionRunner
from canimucal.tui.source import NodeStatus
from canimucal.tui.text import (
    UNIT_BAR,
    UNIT_MARK,
    live_line,
    pose_drawing,
    short_live_line,
)
from canimucal.untrusted import markup_text


class SessionState(Enum):
    """What the screen shows while the procedure has no phase: before the first, after a failure."""

    STARTING = "starting"
    FAILED = "failed"


ScreenPhase = Phase | SessionState
"""The procedure's phase, or the session's state around it."""
ENDED: frozenset[ScreenPhase] = frozenset({Phase.DONE, Phase.CANCELLED, SessionState.FAILED})
"""The phases after which the session has nothing left to run."""

ACTION_PHASES: dict[str, frozenset[Phase]] = {
    "confirm": frozenset({Phase.INSTRUCT}),
    "accept": frozenset({Phase.REVIEW_POSITION}),
    "redo": frozenset({Phase.REVIEW_POSITION, Phase.AVERAGING, Phase.SETTLING}),
    "skip": frozenset({Phase.INSTRUCT, Phase.SETTLING}),
    "skip_warmup": frozenset({Phase.WARMUP}),
    "solve": frozenset({Phase.READY_TO_SOLVE}),
}
"""The phases in which each procedure key (by its action) is offered."""
PHASE_WORDS: dict[ScreenPhase, str] = {
    SessionState.STARTING: "starting",
    Phase.WARMUP: "warming up",
    Phase.INSTRUCT: "set the pose, then enter",
    Phase.SETTLING: "waiting for stillness",
    Phase.AVERAGING: "averaging",
    Phase.REVIEW_POSITION: "averaged: accept (a) or redo (r)",
    Phase.READY_TO_SOLVE: "all positions done: solve (v)",
    Phase.REVIEW: "reviewing the result",
    Phase.WRITING: "writing",
    Phase.DONE: "done",
    Phase.CANCELLED: "cancelled",
    SessionState.FAILED: "stopped on an error",
}


class PositionScreen(Screen[None]):
    """Target pose, drawing, live readout, stillness, averaging progress, sparkline."""

    BINDINGS = [
        Binding("enter", "confirm", "Confirm pose"),
        Binding("a", "accept", "Accept"),
        Binding("r", "redo", "Redo"),
        Binding("s", "skip", "Skip position"),
        Binding("w", "skip_warmup", "Skip warm-up"),
        Binding("v", "solve", "Solve"),
    ]
    phase: reactive[ScreenPhase] = reactive[ScreenPhase](SessionState.STARTING, bindings=True)
    index = reactive(0, bindings=True)

    def __init__(
        self,
        statuses: list[NodeStatus],
        open_runner: Callable[[], SessionRunner] | None = None,
        *,
        total: int = 0,
        out_dir: Path | None = None,
    ) -> None:
        super().__init__()
        self.statuses = statuses
        self.out_dir = out_dir
        self.resumed = False
        """The session goes on from an interrupted one (Ctrl+C then asks as ``q`` does)."""
        self.open_runner = open_runner
        self.runner: SessionRunner | None = None
        self.live: dict[int, ev.SamplesReceived] = {}
        self.level_checks: list[ev.LevelChecked] = []
        self.verified: list[ev.PoseVerified] = []
        self.saved: list[ev.RecordSaved] = []
        self.writes: list[ev.WriteFinished] = []
        self.solved: ev.Solved | None = None
        self.verification = False
        self.total = total
        self.target_deg = (0.0, 0.0, 0.0)
        """The target pose drawn (alpha, beta, psi in degrees); the unit's is drawn beside."""

    def compose(self) -> ComposeResult:
        """Lay the screen out (fits 80×24)."""
        yield Static("canimucal · position", classes="screen-title", id="title")
        yield Static("", id="words")
        with Horizontal(id="middle"):
            yield Static(gauge(pose_drawing(0.0, 0.0)), id="drawing")
            yield Static("waiting for samples…", id="live")
        with Horizontal(id="progress-row"):
            yield Static("○ not still", id="stillness")
            yield ProgressBar(total=100, show_eta=False, id="progress")
            yield Static("", id="seconds-left")
        yield Sparkline([], id="spark")
        yield Static("", id="notice")
        yield Footer()

    def on_mount(self) -> None:
        """Cache widgets and start the I/O worker."""
        self.title_w = self.query_one("#title", Static)
        self.words = self.query_one("#words", Static)
        self.drawing = self.query_one("#drawing", Static)
        self.live_w = self.query_one("#live", Static)
        self.stillness = self.query_one("#stillness", Static)
        self.progress = self.query_one("#progress", ProgressBar)
        self.seconds_left = self.query_one("#seconds-left", Static)
        self.spark = self.query_one("#spark", Sparkline)
        self.notice = self.query_one("#notice", Static)
        if self.open_runner is not None:
            self.io_worker()

    def on_unmount(self) -> None:
        """Stop the I/O loop (what was recorded is kept)."""
        if self.runner is not None:
            self.runner.stop()

    @work(thread=True, exclusive=True, exit_on_error=False, group="io")
    def io_worker(self) -> None:
        """Open the session and run it; every batch of events is posted to this screen."""
        assert self.open_runner is not None
        try:
            self.runner = self.open_runner()
        except CanimucalError as exc:
            self.post_message(EventsArrived([ev.ProcedureFailed(worded_for_flags(exc), exc.title)]))
            return
        config = self.runner.session.procedure.config
        notes = [config.mounting_note] if config.mounting_note else []  # how words are framed
        if config.resume_from is not None:  # say it resumed, and from which file
            self.resumed = True
            notes.insert(0, markup_text(resumed_message(config.resume_from)))
        if notes:
            self.app.call_from_thread(self.notice.update, "\n".join(notes))
        self.runner.run(self._deliver)

    def _deliver(self, batch: list[ev.Event]) -> None:
        """Hand a batch to the UI (called on the I/O thread; post_message is thread-safe)."""
        self.post_message(EventsArrived(batch))

    # -- exits ------------------------------------------------------------------------------

    @property
    def in_progress(self) -> bool:
        """Whether the session has not ended yet (quitting now interrupts it)."""
        return self.phase not in ENDED

    def what_quitting_keeps(self) -> str:
        """Say what quitting now keeps on disk and leaves on the device."""
        where = str(self.out_dir) if self.out_dir is not None else "the output folder"
        written = [str(w.node_id) for w in self.writes if w.ok]
        lines = []
        if self.phase is Phase.WRITING:
            lines.append("The write in progress ends first: verified, or rolled back.")
        if written:
            lines.append(
                f"Node {', '.join(written)} keeps the new calibration (written, read back and "
                "stored). The verification poses are NOT re-read: calibration.json and the "
                f"certificate in {where} record it as not done."
            )
        elif self.saved:
            lines.append(
                "Nothing was written to the device. Kept: the recording, calibration.json and "
                f"the certificate, in {where}."
            )
        else:
            lines.append(
                f"Nothing was written to the device. Kept: the recording so far, in {where}; "
                f"--resume {where} goes on from the last accepted position."
            )
        return "\n".join(lines)

    # -- keys -------------------------------------------------------------------------------

    def check_action(self, action: str, parameters: tuple[object, ...]) -> bool | None:
        """Show a procedure key only in the phases that take it."""
        phases = ACTION_PHASES.get(action)
        if phases is None:
            return True
        if action == "skip" and (self.index == 0 or self.verification):
            return False
        return self.phase in phases

    def _send(self, command: Command) -> None:
        if self.runner is not None:
            self.runner.send(command)

    def action_confirm(self) -> None:
        """Confirm that the pose is set."""
        self.notice.update("moving / waiting for stillness…")
        self._send(SessionCommand.CONFIRM_POSE)

    def action_accept(self) -> None:
        """Accept the averaged position."""
        self._send(SessionCommand.ACCEPT)

    def action_redo(self) -> None:
        """Discard this attempt and instruct the pose again."""
        self._send(SessionCommand.REDO)

    def action_skip(self) -> None:
        """Ask, then leave this position out."""

        def answered(yes: bool | None) -> None:
            if yes:
                self._send(SessionCommand.SKIP)

        text = (
            f"Position {self.index + 1}/{self.total} is left out of the fit; its samples stay "
            "in the recording. The parameters it would separate may end up less certain or "
            "held at nominal."
        )
        self.app.push_screen(ConfirmSkip(text), answered)

    def action_skip_warmup(self) -> None:
        """Stop waiting for warm-up."""
        self._send(SessionCommand.SKIP_WARMUP)

    def action_solve(self) -> None:
        """Solve every node."""
        self.notice.update("solving…")
        self._send(SessionCommand.SOLVE)

    # -- events -----------------------------------------------------------------------------

    def on_events_arrived(self, message: EventsArrived) -> None:
        """Show a batch of events; push results or verification when they arrive."""
        for event in message.events:
            self.show(event)
        self._tell_app(message.events)

    def show(self, event: ev.Event) -> None:  # noqa: C901 - one branch per event kind
        """Update the widgets for one event."""
        if isinstance(event, ev.PhaseChanged):
            self.phase = event.phase
            self._title()
            if self.phase is Phase.WARMUP:
                self.words.update("waiting for the temperature to settle (w skips)")
        elif isinstance(event, ev.SamplesReceived):
            self._samples(event)
        elif isinstance(event, ev.PoseInstructed):
            self._instructed(event)
        elif isinstance(event, ev.StillnessChanged):
            mark = "● still" if event.still else "○ moving"
            self.stillness.update(f"{mark} ({event.needed_s:g} s needed)")
        elif isinstance(event, ev.AveragingStarted):
            self.progress.update(total=event.seconds, progress=0.0)
            self.seconds_left.update(f"{event.seconds:.0f} s left")
            self.notice.update(f"pose checked: tilt − target {_pair(event.tilt_error_deg)}")
        elif isinstance(event, ev.AveragingProgressed):
            self.progress.update(total=event.total_s, progress=event.elapsed_s)
            self.seconds_left.update(f"{event.seconds_left:.0f} s left")
        else:
            self._note(event)

    def _note(self, event: ev.Event) -> None:
        """Events told in the notice line (and kept for the later screens)."""
        text = notice_text(event)
        if text:
            self.notice.update(text)
        if isinstance(event, ev.PositionAveraged):
            self.progress.update(progress=self.progress.total or 0.0)
            self.seconds_left.update("done")
        elif isinstance(event, ev.LevelChecked):
            self.level_checks.append(event)
        elif isinstance(event, ev.PoseVerified):
            self.verified.append(event)
        elif isinstance(event, ev.RecordSaved):
            self.saved.append(event)
        elif isinstance(event, ev.WriteFinished):
            self.writes.append(event)
            if not event.ok:
                self.app.push_screen(ErrorModal("Write failed", event.message))
        elif isinstance(event, ev.Solved):
            self.solved = event
        elif isinstance(event, ev.ProcedureFailed):
            self.phase = SessionState.FAILED  # the loop has ended: no procedure key applies
            self._title()
            stopped = markup_text(event.message)
            self.notice.update(f"stopped: {stopped} — the recording so far is kept; q quits")
            self.app.push_screen(ErrorModal(event.title, event.message))

    def _title(self) -> None:
        what = "verification" if self.verification else "position"
        what += f" {self.index + 1}/{self.total}"
        words = PHASE_WORDS[self.phase]
        self.title_w.update(f"canimucal · {what} · {words}")

    def _instructed(self, event: ev.PoseInstructed) -> None:
        self.index, self.total, self.verification = event.index, event.total, event.verification
        self.phase = Phase.INSTRUCT  # the first instruction comes without a PhaseChanged
        alpha, beta, psi = (float(np.rad2deg(x)) for x in event.position.angles)
        self.words.update(f"{event.words}\naverage {event.seconds:g} s once still")
        self.target_deg = (alpha, beta, psi)
        self.drawing.update(gauge(pose_drawing(alpha, beta, psi)))
        self.progress.update(total=event.seconds, progress=0.0)
        self.seconds_left.update(f"{event.seconds:.0f} s")
        self.stillness.update("○ set the pose")
        self._title()

    def _samples(self, event: ev.SamplesReceived) -> None:
        self.live[event.node_id] = event
        if not self.is_current:
            return
        readouts = list(self.live.values())
        lines = [live_line(readouts[0])] + [short_live_line(e) for e in readouts[1:]]
        self.live_w.update("\n".join(lines))
        first = next(iter(self.live))
        if event.node_id == first and event.sparkline:
            self.spark.data = list(event.sparkline)
        if event.node_id == first and event.tilt_error_deg is not None:
            alpha, beta, psi = self.target_deg
            measured = (alpha + event.tilt_error_deg[0], beta + event.tilt_error_deg[1])
            self.drawing.update(gauge(pose_drawing(alpha, beta, psi, measured)))

    def _tell_app(self, events: list[ev.Event]) -> None:
        if any(isinstance(e, ev.Solved) for e in events) and self.solved is not None:
            self.post_message(ResultsReady(self.solved, self.statuses, self.decided))
        finished = [e for e in events if isinstance(e, ev.ProcedureFinished)]
        if finished:
            session = None if self.runner is None else self.runner.session
            verdicts = (
                {}
                if session is None
                else {s.node_id: session.verification_verdict(s.node_id) for s in self.statuses}
            )
            self.post_message(
                ProcedureEnded(
                    self.level_checks,
                    self.saved,
                    self.writes,
                    finished[-1],
                    self.verified,
                    {n: v for n, v in verdicts.items() if v},
                )
            )

    def decided(self, command: Command | None) -> None:
        """Send the results screen's answer: a write, or finishing without one."""
        if self.runner is None or command is None:
            return
        if isinstance(command, WriteOptions):
            self.notice.update("writing (backup first, then verify)…")
        self.runner.send(command)


def _pair(values: tuple[float, float]) -> str:
    return f"alpha {values[0]:+.2f}°, beta {values[1]:+.2f}°"


def notice_text(event: ev.Event) -> str:
    """Return the notice line for an event ('' when it has none)."""
    if isinstance(event, ev.WarmupProgressed):
        slope = "—" if event.slope_c_per_min is None else f"{event.slope_c_per_min:+.3f}"
        state = "warm" if event.warm else ("skipped" if event.skipped else "warming up")
        return (
            f"{state}: {event.temp_c:.2f} °C, slope {slope} °C/min "
            f"(threshold {event.threshold_c_per_min:g}) over {event.elapsed_s:.0f}"
            f"/{event.window_s:g} s"
        )
    if isinstance(event, ev.PoseRefused):
        return f"[b]pose refused[/b] (node {event.node_id}): {markup_text(event.message)}"
    if isinstance(event, ev.PositionRejected):
        reason = markup_text(event.reason)
        return f"[b]position {event.index + 1} rejected[/b]: {reason}; settling again"
    if isinstance(event, ev.PositionAveraged):
        parts = [
            f"node {n}: n={a.n} lost={a.lost} σ {a.std_accel.max():.1f} cnt"
            for n, a in event.averages.items()
        ]
        return "averaged " + "; ".join(parts) + " — a: accept, r: redo"
    if isinstance(event, ev.PositionAccepted):
        return f"position {event.index + 1} accepted"
    if isinstance(event, ev.AveragingTimeChosen):
        return f"averaging time of the next positions: {event.describe()}"
    if isinstance(event, ev.WriteFinished):
        return f"write node {event.node_id}: {markup_text(event.message)}"
    if isinstance(event, ev.PoseVerified):
        return markup_text(verified_line(event))
    if isinstance(event, ev.RecordSaved):
        return f"saved {markup_text(str(event.record_path))}"
    if isinstance(event, ev.DeviceEventReported):
        return f"[b]{event.kind.replace('_', ' ')}[/b]: {markup_text(event.message)}"
    return ""


def gauge(drawing: str) -> Text:
    """Colour the side views: the unit's measured attitude stands out from the target."""
    text = Text(drawing)
    text.highlight_regex(f"[{UNIT_MARK}{UNIT_BAR}]", "bold cyan")
    return text
