"""Messages the TUI's worker threads post to their screens (``post_message`` is thread-safe)."""

from __future__ import annotations

from textual.message import Message

from canimucal.procedure import events as ev
from canimucal.tui.source import NodeStatus


class EventsArrived(Message):
    """A batch of procedure events (10–25 batches a second at most)."""

    def __init__(self, events: list[ev.Event]) -> None:
        super().__init__()
        self.events = events


class NodesFound(Message):
    """The source connected and read every node."""

    def __init__(self, statuses: list[NodeStatus]) -> None:
        super().__init__()
        self.statuses = statuses


class ConnectFailed(Message):
    """Connecting failed; ``title`` is the error's short title."""

    def __init__(self, title: str, message: str) -> None:
        super().__init__()
        self.title = title
        self.message = message
