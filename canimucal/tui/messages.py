"""Messages of the TUI: worker threads tell their screens, screens tell the app.

``post_message`` is thread-safe, and a message a screen does not handle bubbles to the app:
the app owns the screen flow, so a screen that is done asks for the next one with a message
instead of importing it.
"""

from __future__ import annotations

from collections.abc import Callable

from textual.message import Message

from canimucal.model.mounting import MountingMap
from canimucal.procedure import events as ev
from canimucal.tui.runner import Command
from canimucal.tui.source import NodeStatus


class EventsArrived(Message, bubble=False):
    """A batch of procedure events (10–25 batches a second at most)."""

    def __init__(self, events: list[ev.Event]) -> None:
        super().__init__()
        self.events = events


class NodesFound(Message, bubble=False):
    """The source connected and read every node."""

    def __init__(self, statuses: list[NodeStatus]) -> None:
        super().__init__()
        self.statuses = statuses


class ConnectFailed(Message, bubble=False):
    """Connecting failed; ``title`` is the error's short title."""

    def __init__(self, title: str, message: str) -> None:
        super().__init__()
        self.title = title
        self.message = message


class PlanWanted(Message):
    """The connection screen is done: choose the plan for these nodes."""

    def __init__(self, statuses: list[NodeStatus]) -> None:
        super().__init__()
        self.statuses = statuses


class StartWanted(Message):
    """The plan screen is done: start the procedure with this plan, gyro grade and mount.

    ``mount_chosen``: the operator chose ``mount`` on the plan screen (it is saved for the
    unit's serial, replacing a saved map).
    """

    def __init__(
        self,
        plan_name: str,
        gyro: str,
        statuses: list[NodeStatus],
        mount: MountingMap | str | None = None,
        mount_chosen: bool = False,
    ) -> None:
        super().__init__()
        self.plan_name = plan_name
        self.gyro = gyro
        self.statuses = statuses
        self.mount = mount
        self.mount_chosen = mount_chosen


class ResultsReady(Message):
    """The procedure solved every node: show the results; ``answer`` takes the decision.

    The decision is what the results screen is dismissed with: a session command, the
    options of a write, or None.
    """

    def __init__(
        self,
        solved: ev.Solved,
        statuses: list[NodeStatus],
        answer: Callable[[Command | None], None],
    ) -> None:
        super().__init__()
        self.solved = solved
        self.statuses = statuses
        self.answer = answer


class ProcedureEnded(Message):
    """The procedure finished (or was cancelled): show the verification and the files."""

    def __init__(
        self,
        checks: list[ev.LevelChecked],
        saved: list[ev.RecordSaved],
        writes: list[ev.WriteFinished],
        finished: ev.ProcedureFinished,
        verified: list[ev.PoseVerified] | None = None,
        verdicts: dict[int, str] | None = None,
    ) -> None:
        super().__init__()
        self.checks = checks
        self.saved = saved
        self.writes = writes
        self.finished = finished
        self.verified = verified or []
        """The verification poses re-read after the write."""
        self.verdicts = verdicts or {}
        """Per node, the certificate's verification line."""
