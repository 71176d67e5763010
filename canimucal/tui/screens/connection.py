"""The connection and node screen: identity, current calibration, heartbeat of each node."""

from __future__ import annotations

from enum import Enum

from textual import work
from textual.app import ComposeResult
from textual.binding import Binding
from textual.reactive import reactive
from textual.screen import Screen
from textual.widgets import DataTable, Footer, Static

from canimucal.errors import CanimucalError
from canimucal.flag_words import worded_for_flags
from canimucal.tui.messages import ConnectFailed, NodesFound, PlanWanted
from canimucal.tui.modals import ErrorModal
from canimucal.tui.source import NodeStatus, SessionSource
from canimucal.tui.text import calibration_summary
from canimucal.tui.widgets import PlainStatic, passive_table

HEARTBEAT_REFRESH_S = 1.0
STATE_WORDS = {"PRE-OPERATIONAL": "pre-op", "OPERATIONAL": "op", "STOPPED": "stopped"}
COLUMNS = ("node", "serial", "rev", "ODR", "calibration", "heartbeat")


class LinkState(Enum):
    """Where connecting stands: enter needs CONNECTED, retry (c) needs FAILED."""

    CONNECTING = "connecting"
    CONNECTED = "connected"
    FAILED = "failed"


class ConnectionScreen(Screen[None]):
    """Connects (on a worker thread), then shows every node; enter goes to the plan."""

    BINDINGS = [
        Binding("enter", "next", "Plan"),
        Binding("c", "connect", "Retry"),
    ]
    state: reactive[LinkState] = reactive[LinkState](LinkState.CONNECTING, bindings=True)

    def __init__(self, source: SessionSource, *, autoconnect: bool = True) -> None:
        super().__init__()
        self.source = source
        self.autoconnect = autoconnect
        self.statuses: list[NodeStatus] = []

    def compose(self) -> ComposeResult:
        """Title, bus, node table, status line."""
        yield Static("canimucal · connection", classes="screen-title")
        # device text and bus names are shown as they are, never parsed as markup
        yield PlainStatic(f"bus: {self.source.description}", id="bus")
        yield passive_table(id="nodes", zebra_stripes=True)
        yield PlainStatic("connecting…", id="status")
        yield Footer()

    def on_mount(self) -> None:
        """Cache widgets, start connecting, refresh heartbeats every second."""
        self.table = self.query_one("#nodes", DataTable)
        self.status = self.query_one("#status", PlainStatic)
        self.bus = self.query_one("#bus", PlainStatic)
        for column in COLUMNS:
            self.table.add_column(column, key=column)
        self.set_interval(HEARTBEAT_REFRESH_S, self.refresh_heartbeats)
        if self.autoconnect:
            self.action_connect()

    def check_action(self, action: str, parameters: tuple[object, ...]) -> bool | None:
        """Enter only once connected; retry only after a failure."""
        if action == "next":
            return self.state is LinkState.CONNECTED
        if action == "connect":
            return self.state is LinkState.FAILED
        return True

    def action_connect(self) -> None:
        """Connect on a worker thread."""
        self.state = LinkState.CONNECTING
        self.status.update("connecting…")
        self.connect_worker()

    @work(thread=True, exclusive=True, exit_on_error=False, group="connect")
    def connect_worker(self) -> None:
        """Blocking connect: find every node and read it."""
        try:
            statuses = self.source.connect()
        except CanimucalError as exc:
            self.post_message(ConnectFailed(exc.title, " ".join(worded_for_flags(exc).split())))
            return
        except Exception as exc:  # a bug, still shown in the modal
            self.post_message(ConnectFailed("Internal error", f"internal error: {exc}"))
            return
        self.post_message(NodesFound(statuses))

    def on_nodes_found(self, message: NodesFound) -> None:
        """Fill the table."""
        self.show_nodes(message.statuses)

    def show_nodes(self, statuses: list[NodeStatus]) -> None:
        """Fill the node table (also used by tests with injected statuses)."""
        self.statuses = statuses
        self.bus.update(f"bus: {self.source.description}")
        self.table.clear()
        for s in statuses:
            i = s.identity
            self.table.add_row(
                f"{s.node_id} (0x{s.node_id:02X})",
                str(i.serial),
                f"0x{i.revision:X}",
                f"{s.rate_hz:g} Hz",
                calibration_summary(s.calibration),
                "…",
                key=str(s.node_id),
            )
        self.state = LinkState.CONNECTED
        self.refresh_heartbeats()
        lines = [
            f"node {s.node_id}: {s.identity.device_name}, vendor 0x{s.identity.vendor_id:X}, "
            f"product 0x{s.identity.product_code:X}; LSB accel {s.accel_lsb:.6g} m/s², "
            f"gyro {s.gyro_lsb:.6g} rad/s; found by {s.found_by or '—'}"
            for s in statuses
        ]
        lines.append("lost frames: counted live once streaming starts (position screen)")
        lines.append("enter: choose the plan")
        self.status.update("\n".join(lines))

    def refresh_heartbeats(self) -> None:
        """Update the heartbeat column and the bus load (no SDO: what the clients saw)."""
        load = None
        for s in self.statuses:
            beat = self.source.heartbeat(s.node_id)
            state = STATE_WORDS.get(str(beat.state), str(beat.state).lower())
            text = "none yet" if beat.age_s is None else f"{state} {beat.age_s:.1f} s ago"
            self.table.update_cell(str(s.node_id), "heartbeat", text, update_width=True)
            load = beat.bus_load if load is None else load
        if load is not None:
            self.bus.update(f"bus: {self.source.description} · {load.text()}")

    def on_connect_failed(self, message: ConnectFailed) -> None:
        """Show the error in a modal; c retries."""
        self.state = LinkState.FAILED
        self.status.update(f"{message.title}: {message.message} (c: retry, q: quit)")
        self.app.push_screen(ErrorModal(message.title, message.message))

    def action_next(self) -> None:
        """Ask the app for the plan screen."""
        self.post_message(PlanWanted(self.statuses))
