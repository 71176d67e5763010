"""The Textual app and its factory :func:`make_app` (the entry point and the tests use it).

The app owns the screen flow: connection → plan → (the site question, when no flag gave the
site) → position (the procedure, with its I/O
worker) → results → write confirmation (modal) → position (the verification poses) →
verification. A screen that is done posts a message (:mod:`canimucal.tui.messages`) and the
app pushes the next screen, so no screen imports another. Errors are shown in
:class:`~canimucal.tui.modals.ErrorModal`, never as a traceback.

Exits (docs/design.md §7): ``q`` quits at once when no session is in progress (exit 0); during a
session it first asks, saying what is kept, and a confirmed quit is an interrupted session
(exit 130). Ctrl+C is the interrupt: it quits at once with exit 130, except in a resumed
session, where it asks as ``q`` does (a second Ctrl+C quits at once). Either way the I/O
loop is stopped, the recording so far is kept, and the bus is released.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from pathlib import Path

from textual.app import App
from textual.binding import Binding

from canimucal.io.site_memory import LastSite
from canimucal.model.positions import Plan
from canimucal.model.vocabulary.plans import CUSTOM, DEFAULT_PLAN, builtin_names, builtin_plan
from canimucal.procedure.machine import Phase
from canimucal.signals import EXIT_INTERRUPTED
from canimucal.tui.messages import PlanWanted, ProcedureEnded, ResultsReady, StartWanted
from canimucal.tui.modals import ConfirmQuit, SiteModal
from canimucal.tui.runner import SessionRunner
from canimucal.tui.screens.connection import ConnectionScreen
from canimucal.tui.screens.plan import PlanScreen
from canimucal.tui.screens.position import PositionScreen
from canimucal.tui.screens.results import ResultsScreen
from canimucal.tui.screens.verification import VerificationScreen
from canimucal.tui.source import DeviceSource, SessionSource

logger = logging.getLogger(__name__)

RUNNER_STOP_TIMEOUT_S = 10.0
WRITE_STOP_TIMEOUT_S = 60.0
"""How long quitting waits for a write in progress: it ends (verified, or rolled back) within
its SDO and store timeouts, and the bus must not be closed under it."""
EXIT_OK = 0


class CalibrationApp(App[int]):
    """The canimucal TUI; build it with :func:`make_app`."""

    CSS_PATH = Path(__file__).with_name("app.tcss")  # absolute: subclasses live elsewhere
    TITLE = "canimucal"
    BINDINGS = [
        Binding("q", "quit", "Quit"),
        Binding("ctrl+c", "interrupt", "Interrupt", show=False, priority=True),
    ]
    ENABLE_COMMAND_PALETTE = False

    def __init__(
        self,
        source: SessionSource,
        plans: Mapping[str, Plan],
        *,
        plan_name: str = DEFAULT_PLAN,
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

    # -- the screen flow --------------------------------------------------------------------

    def on_plan_wanted(self, message: PlanWanted) -> None:
        """Show the plan screen once the connection screen is done."""
        plan_screen = PlanScreen(
            message.statuses,
            self.plans,
            plan_name=self.plan_name,
            gyro=self.gyro,
            mount=self.source.mount,
            acceptance=getattr(self.source, "acceptance", None),
            averaging=getattr(self.source, "averaging", None),
            prior_k_sigma=getattr(self.source, "prior_k_sigma", None),
            vehicle_size=getattr(self.source, "vehicle_size", None),
        )
        self.push_screen(plan_screen)

    def on_start_wanted(self, message: StartWanted) -> None:
        """Ask the site first when no flag gave it, then open the session of the plan."""
        source = self.source
        if not getattr(source, "ask_site", False) or not isinstance(source, DeviceSource):
            self.start(message)
            return
        if isinstance(self.screen, SiteModal):
            return

        def answered(answer: LastSite | None) -> None:
            if answer is not None:  # escape: back on the plan screen
                source.take_site(answer)
                self.start(message)

        needs_latitude = message.gyro == "nav"
        self.push_screen(SiteModal(source.last_site(), needs_latitude=needs_latitude), answered)

    def start(self, message: StartWanted) -> None:
        """Open the session of the chosen plan on the position screen's worker."""
        self.plan_name, self.gyro = message.plan_name, message.gyro
        if message.mount_chosen:  # chosen on the plan screen: saved for the unit
            self.source.mount, self.source.replace_mount = message.mount, True
        plan = self.plans[message.plan_name]

        def open_runner() -> SessionRunner:  # on the worker thread: opening blocks
            session = self.source.open(plan, message.plan_name, message.gyro)
            self.runner = SessionRunner(session)
            return self.runner

        position = PositionScreen(
            message.statuses, open_runner, total=len(plan.positions), out_dir=self.source.out_dir
        )
        self.push_screen(position)

    def on_results_ready(self, message: ResultsReady) -> None:
        """Show the results; the operator's answer goes back to the session."""
        self.push_screen(ResultsScreen(message.solved, message.statuses), message.answer)

    def on_procedure_ended(self, message: ProcedureEnded) -> None:
        """Show the verification and the files once the procedure finished or was cancelled."""
        self.push_screen(
            VerificationScreen(
                message.checks,
                message.saved,
                message.writes,
                message.finished,
                verified=message.verified,
                verdicts=message.verdicts,
            )
        )

    # -- exits ------------------------------------------------------------------------------

    @property
    def session_in_progress(self) -> PositionScreen | None:
        """The position screen of a session that has not ended (quitting now interrupts it)."""
        for screen in self.screen_stack:
            if isinstance(screen, PositionScreen) and screen.in_progress:
                return screen
        return None

    async def action_quit(self) -> None:
        """Quit; during a session, first ask (saying what is kept) and exit 130."""
        position = self.session_in_progress
        if position is None:
            self.exit(EXIT_OK, return_code=EXIT_OK)
            return
        if isinstance(self.screen, ConfirmQuit):
            return

        def answered(yes: bool | None) -> None:
            if yes:
                self.exit(EXIT_INTERRUPTED, return_code=EXIT_INTERRUPTED)

        self.push_screen(ConfirmQuit(position.what_quitting_keeps()), answered)

    async def action_interrupt(self) -> None:
        """Ctrl+C: quit at once (exit 130); a resumed session first asks, as ``q`` does.

        A second Ctrl+C while the question is shown quits at once: Ctrl+C always gets out.
        """
        position = self.session_in_progress
        if position is not None and position.resumed and not isinstance(self.screen, ConfirmQuit):
            await self.action_quit()
            return
        self.exit(EXIT_INTERRUPTED, return_code=EXIT_INTERRUPTED)

    def stop_session(self) -> None:
        """Stop the I/O loop, wait for it to close the files, release the source."""
        runner, self.runner = self.runner, None
        if runner is not None:
            runner.stop()
            writing = runner.phase is Phase.WRITING
            timeout_s = WRITE_STOP_TIMEOUT_S if writing else RUNNER_STOP_TIMEOUT_S
            if not runner.finished.wait(timeout_s):
                logger.warning("the session loop did not stop within %g s", timeout_s)
        self.source.close()

    def on_unmount(self) -> None:
        """Release everything when the app closes (also after a test)."""
        self.stop_session()


def make_app(
    source: SessionSource,
    *,
    plan_name: str = DEFAULT_PLAN,
    gyro: str = "mems",
    custom_plan: Plan | None = None,
    autoconnect: bool = True,
) -> CalibrationApp:
    """Build the TUI over ``source`` (a :class:`~canimucal.tui.source.DeviceSource`).

    ``custom_plan`` (from ``--plan FILE``) is offered as ``custom`` beside the built-in plans;
    ``plan_name`` is the plan selected first. ``autoconnect=False`` leaves the connection
    screen waiting (tests inject the node statuses).
    """
    plans: dict[str, Plan] = {name: builtin_plan(name) for name in builtin_names()}
    if custom_plan is not None:
        plans[CUSTOM] = custom_plan
    if plan_name not in plans:
        plan_name = CUSTOM if custom_plan is not None else DEFAULT_PLAN
    return CalibrationApp(source, plans, plan_name=plan_name, gyro=gyro, autoconnect=autoconnect)
