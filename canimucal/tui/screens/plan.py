"""The plan screen: plan, gyro grade and mount; the Cramér–Rao table shows what a plan can do.

Times, bounds and the acceptance forecast come from :mod:`canimucal.runtime.plan_forecast`
(the figures ``canimucal plan`` prints): each position's seconds as the session will average
them, the operator's minutes, the table at those seconds for the model the session fits.

The summary says how the instructions will be worded: for the vehicle (the vehicle plan, or
any plan once a mount is chosen) through the map chosen here or with ``--mount``, else the
map saved for the first node's serial, else the default; otherwise in the unit's own axes.
"""

from __future__ import annotations

from collections.abc import Mapping

from textual.app import ComposeResult
from textual.binding import Binding
from textual.containers import VerticalScroll
from textual.reactive import reactive
from textual.screen import Screen
from textual.widgets import DataTable, Footer, Static

from canimucal.analysis.acceptance import AcceptanceConfig
from canimucal.errors import InputError
from canimucal.io.mounting import BODY, load_mounting, load_vehicle_size
from canimucal.model.mounting import DEFAULT_MOUNTING, MountingMap
from canimucal.model.plan import BoundTable
from canimucal.model.positions import Plan
from canimucal.model.vehicle_size import VehicleSize
from canimucal.model.vocabulary.plans import DEFAULT_PLAN, PLANS, worded_for_vehicle
from canimucal.procedure.averaging import AveragingPolicy, averaged_sensors, describe_rule
from canimucal.runtime.plan_forecast import (
    forecast,
    forecast_lines,
    plan_bounds,
    schedule,
    session_spec,
    trim_forecast,
)
from canimucal.tui.messages import StartWanted
from canimucal.tui.modals import MountModal
from canimucal.tui.source import NodeStatus
from canimucal.tui.text import bound_rows, findings_text
from canimucal.tui.widgets import PlainStatic, passive_table


def bound_table(
    plan_name: str,
    plan: Plan,
    accel_lsb: float,
    policy: AveragingPolicy | None = None,
    prior_k_sigma: float | None = None,
) -> BoundTable:
    """Cramér–Rao bounds of a plan for the accelerometer model the procedure will fit.

    At the seconds ``policy`` gives the positions, with the plan's prior on K: the table
    ``canimucal plan`` prints (:func:`~canimucal.runtime.plan_forecast.plan_bounds`).
    """
    spec = session_spec(plan_name)
    return plan_bounds(plan, spec, policy=policy, accel_lsb=accel_lsb, prior_k_sigma=prior_k_sigma)


class PlanScreen(Screen[None]):
    """Plan choice (each plan's key in the plan registry), gyro grade (g), mount (m), start.

    ``plans`` are the plans on offer by name; ``plan_name``, ``gyro`` and ``mount`` (from
    ``--mount``) the first choice.
    """

    BINDINGS = [Binding("enter", "start", "Start")]
    OTHER_BINDINGS = (
        Binding("g", "gyro", "Gyro grade"),
        Binding("m", "mount", "Mount", show=False),  # the summary names it: the footer is full
        Binding("escape", "back", "Back"),
    )
    """Bound after the plans' keys, so that the footer lists the plans first."""
    plan_name = reactive(DEFAULT_PLAN, bindings=True)
    gyro = reactive("mems")

    def __init__(
        self,
        statuses: list[NodeStatus],
        plans: Mapping[str, Plan],
        *,
        plan_name: str = DEFAULT_PLAN,
        gyro: str = "mems",
        mount: MountingMap | str | None = None,
        acceptance: AcceptanceConfig | None = None,
        averaging: AveragingPolicy | None = None,
        prior_k_sigma: float | None = None,
        vehicle_size: VehicleSize | None = None,
    ) -> None:
        super().__init__()
        for entry in PLANS.values():  # the registry's keys, read when the screen is built
            if entry.tui_key is not None:
                name = entry.name
                self._bindings.bind(entry.tui_key, f"plan('{name}')", name.capitalize())
        for b in self.OTHER_BINDINGS:  # as App.bind does: this screen's own bindings map
            self._bindings.bind(b.key, b.action, b.description, show=b.show)
        self.averaging = averaging or AveragingPolicy()
        """The sessions' averaging rule (``--seconds``): shown, not chosen."""
        self.prior_k_sigma = prior_k_sigma
        self.vehicle_size = vehicle_size
        """``--wheelbase``/``--track`` (None: the size saved for the unit, if any)."""
        """The relative σ of the prior on K a session holds (``--prior-k-sigma``; None: the
        plan's own)."""
        self.acceptance = acceptance or AcceptanceConfig()
        """The limits sessions are judged by (per plan): shown beside the plan's σ."""
        self.statuses = statuses
        self.plans = dict(plans)
        self.first_choice = (plan_name if plan_name in self.plans else DEFAULT_PLAN, gyro)
        self.mount_map = mount
        self.mount_chosen = False

    def compose(self) -> ComposeResult:
        """Title, plan summary, bound table, findings."""
        yield Static("canimucal · plan", classes="screen-title")
        yield Static("", id="plan-summary")
        with VerticalScroll(id="plan-body"):
            yield passive_table(id="bounds", zebra_stripes=True)
            yield Static("", id="findings")
            yield PlainStatic("", id="forecast")  # "[plan.vehicle]" is text, not markup
        yield Footer()

    def on_mount(self) -> None:
        """Cache widgets and show the initial plan."""
        self.summary = self.query_one("#plan-summary", Static)
        self.table = self.query_one("#bounds", DataTable)
        self.findings = self.query_one("#findings", Static)
        self.forecast = self.query_one("#forecast", PlainStatic)
        self.table.add_columns("parameter", "σ", "unit", "effect at 1 g (counts)")
        self.plan_name, self.gyro = self.first_choice
        self.show_plan()

    def check_action(self, action: str, parameters: tuple[object, ...]) -> bool | None:
        """Offer only the plans there are (custom needs --plan FILE)."""
        if action == "plan":
            name = str(parameters[0])
            return name in self.plans and name != self.plan_name
        return True

    def action_plan(self, name: str) -> None:
        """Switch plan."""
        self.plan_name = name
        self.show_plan()

    def action_gyro(self) -> None:
        """Toggle the gyro grade (MEMS bias, or navigation bias and scale from Earth rate)."""
        self.gyro = "nav" if self.gyro == "mems" else "mems"
        self.show_plan()

    def show_plan(self) -> None:
        """Recompute and show the bound table of the chosen plan."""
        plan = self.plans[self.plan_name]
        lsb = self.statuses[0].accel_lsb if self.statuses else 9.80665 / 2048.0
        policy, prior = self.averaging, self.prior_k_sigma
        table = bound_table(self.plan_name, plan, lsb, policy, prior)
        limits = self.acceptance.limits(self.plan_name)
        spec = session_spec(self.plan_name)
        rows = forecast(plan, limits, spec, policy=policy, accel_lsb=lsb, prior_k_sigma=prior)
        times = schedule(plan, policy)
        rule = describe_rule(policy, averaged_sensors(self.gyro))
        cannot = [r.key for r in rows if r.meets is False]
        verdict = (
            f"acceptance: this plan CANNOT meet {', '.join(cannot)} (below the table)"
            if cannot
            else "acceptance: this plan can meet the limits known before the data"
        )
        nodes = ", ".join(str(s.node_id) for s in self.statuses) or "—"
        grade = "MEMS (bias)" if self.gyro == "mems" else "navigation (bias + scale)"
        self.summary.update(
            f"plan {self.plan_name}: {len(plan.positions)} positions · gyro {grade} · "
            f"nodes {nodes}\n"
            f"times: {times.words()}\n"
            f"{self.instructions_line()}\n"
            f"averaging: {rule}\n"
            f"{verdict}\n"
            "Cramér–Rao σ at these times, K = I/LSB, 1 count/√Hz white noise, zero tilt:"
        )
        self.table.clear()
        for row in bound_rows(table):
            self.table.add_row(*row)
        self.findings.update(findings_text(table))
        trim = trim_forecast(plan, spec, policy=policy, accel_lsb=lsb, prior_k_sigma=prior)
        self.forecast.update("\n".join(forecast_lines(rows, self.plan_name, trim=trim)))

    @property
    def serial(self) -> int | None:
        """The first node's serial (the unit the mounting map is saved for)."""
        return self.statuses[0].identity.serial if self.statuses else None

    def instructions_line(self) -> str:
        """Say how the instructions will be worded (module doc), at 80 columns.

        For a vehicle, a second line gives its wheelbase and track (tilts as heights), or
        says that ``--wheelbase`` and ``--track`` would word them so.
        """
        vehicle = worded_for_vehicle(self.plan_name)
        if self.mount_map == BODY or (self.mount_map is None and not vehicle):
            return "instructions in the unit's own axes · m words them for a vehicle"
        size = self._size_line()
        if isinstance(self.mount_map, MountingMap):
            return f"vehicle wording: mount {self.mount_map.text()} · m changes it\n{size}"
        try:
            saved = None if self.serial is None else load_mounting(self.serial)
        except InputError as exc:
            return f"mounting: {exc}"
        if saved is not None:
            return f"vehicle wording: mount {saved.text()}, as saved · m changes it\n{size}"
        default = DEFAULT_MOUNTING.text()
        return f"vehicle wording: mount {default}, the default · m changes it\n{size}"

    def _size_line(self) -> str:
        """``tilts as heights: wheelbase 3.5 m, track 1.8 m`` (or how to get them)."""
        size = self.vehicle_size
        if size is None and self.serial is not None:
            try:
                size = load_vehicle_size(self.serial)
            except InputError:
                size = None
        if size is None or not size.known:
            return "tilts as angles (--wheelbase M and --track M word them as heights)"
        return f"tilts as heights: {size.text()}"

    def action_mount(self) -> None:
        """Ask how the unit is mounted; the answer words the instructions and is saved."""

        def answered(mount: MountingMap | str | None) -> None:
            if mount is not None:
                self.mount_map, self.mount_chosen = mount, True
                self.show_plan()

        current = self.mount_map.text() if isinstance(self.mount_map, MountingMap) else ""
        if self.mount_map is None and self.serial is not None:
            try:
                saved = load_mounting(self.serial)
            except InputError:
                saved = None
            current = (saved or DEFAULT_MOUNTING).text()
        self.app.push_screen(MountModal(current or DEFAULT_MOUNTING.text(), self.serial), answered)

    def action_start(self) -> None:
        """Ask the app to start the procedure with this plan."""
        self.post_message(
            StartWanted(self.plan_name, self.gyro, self.statuses, self.mount_map, self.mount_chosen)
        )

    def action_back(self) -> None:
        """Back to the connection screen."""
        self.app.pop_screen()
