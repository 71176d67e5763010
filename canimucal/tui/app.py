"""The Textual app and its factory :func:`make_app` (the entry point and the tests use it).

Screens, in order: connection → plan → position (the procedure, with its I/O worker) →
results → write confirmation (modal) → position (verification at level) → verification.
Errors are shown in :class:`~canimucal.tui.modals.ErrorModal`, never as a traceback. Quitting
stops the I/O loop (the recording so far is kept) and releases the bus.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from pathlib import Path

from textual.app import App
from textual.binding import Binding

from canimucal.model.plan import builtin_plan
from canimucal.model.positions import Plan
from canimucal.tui.connection import ConnectionScreen
from canimucal.tui.position import PositionScreen
from canimucal.tui.runner import SessionRunner
from canimucal.tui.source import NodeStatus, SessionSource

logger = logging.getLogger(__name__)

RUNNER_STOP_TIMEOUT_S = 10.0
BUILTIN = ("two", "five", "recommended")


class CalibrationApp(App[int]):
    """The canimucal TUI; build it with :func:`make_app`."""

    CSS_PATH = Path(__file__).with_name("app.tcss")  # absolute: subclasses live elsewhere
    TITLE = "canimucal"
    BINDINGS = [
        Binding("q", "quit", "Quit"),
        Binding("ctrl+c", "quit", "Quit", show=False, priority=True),
    ]
    ENABLE_COMMAND_PALETTE = False

    def __init__(
        self,
        source: SessionSource,
        plans: Mapping[str, Plan],
        *,
        plan_name: str = "recommended",
        gyro: str = "mems",
        autoconnect: bool = True,
    ) -> None:
        super().__init__()
        self.source = source
        self.plans = dict(plans)
        self.plan_name = plan_name
        self.gyro = gyro
        self.autoconnect = autoconnect
        self.runner: SessionRunner | None = None

    def on_mount(self) -> None:
        """Open on the connection screen."""
        self.push_screen(ConnectionScreen(self.source, autoconnect=self.autoconnect))

    def start_procedure(self, plan_name: str, gyro: str, statuses: list[NodeStatus]) -> None:
        """Open the session of the chosen plan on the position screen's worker."""
        self.plan_name, self.gyro = plan_name, gyro
        plan = self.plans[plan_name]

        def open_runner() -> SessionRunner:
            return SessionRunner(self.source.open(plan, plan_name, gyro))

        self.push_screen(PositionScreen(statuses, open_runner, total=len(plan.positions)))

    def stop_session(self) -> None:
        """Stop the I/O loop, wait for it to close the files, release the source."""
        runner, self.runner = self.runner, None
        if runner is not None:
            runner.stop()
            if not runner.finished.wait(RUNNER_STOP_TIMEOUT_S):
                logger.warning("the session loop did not stop within %g s", RUNNER_STOP_TIMEOUT_S)
        self.source.close()

    async def action_quit(self) -> None:
        """Stop the session (keeping what was recorded) and exit."""
        self.exit(0)

    def on_unmount(self) -> None:
        """Release everything when the app closes (also after a test)."""
        self.stop_session()


def make_app(
    source: SessionSource,
    *,
    plan_name: str = "recommended",
    gyro: str = "mems",
    custom_plan: Plan | None = None,
    autoconnect: bool = True,
) -> CalibrationApp:
    """Build the TUI over ``source`` (a :class:`DemoSource` or :class:`BusSource`).

    ``custom_plan`` (from ``--plan FILE``) is offered as ``custom`` beside the built-in plans;
    ``plan_name`` is the plan selected first. ``autoconnect=False`` leaves the connection
    screen waiting (tests inject the node statuses).
    """
    plans: dict[str, Plan] = {name: builtin_plan(name) for name in BUILTIN}
    if custom_plan is not None:
        plans["custom"] = custom_plan
    if plan_name not in plans:
        plan_name = "custom" if custom_plan is not None else "recommended"
    return CalibrationApp(source, plans, plan_name=plan_name, gyro=gyro, autoconnect=autoconnect)
