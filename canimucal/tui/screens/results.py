"""The results screen: each parameter ± σ beside the device's current value.

Every value carries its unit (the units registry's): the file's, the operator's (mg, ppm,
°, °/s) and the device's; the residual per position in mg and °/s. Also the acceptance
checks; w writes (after the confirmation modal), f finishes.
"""

from __future__ import annotations

import numpy as np
from textual.app import ComposeResult
from textual.binding import Binding
from textual.containers import VerticalScroll
from textual.screen import Screen
from textual.widgets import DataTable, Footer, Static

from canimucal.analysis.calibrate import SiteConditions, Solution
from canimucal.model.sensor import STANDARD_GRAVITY
from canimucal.model.vocabulary.units import Scales, operator_value, quantity_of, with_unit
from canimucal.procedure import events as ev
from canimucal.runtime.session import SessionCommand, WriteOptions
from canimucal.tui.modals import ConfirmWrite
from canimucal.tui.runner import Command
from canimucal.tui.source import NodeStatus
from canimucal.tui.text import device_values
from canimucal.tui.widgets import passive_table

RESIDUAL_AXES = ("ax", "ay", "az", "gx", "gy", "gz")


def scales_of(solution: Solution, status: NodeStatus | None) -> Scales:
    """Return the node's nominal LSBs (its own, else the defaults) and the record's g."""
    site = SiteConditions(g=STANDARD_GRAVITY)
    conditions = solution.record.conditions
    g = conditions.g if conditions is not None and conditions.g is not None else site.g
    if status is None:
        return Scales(site.accel_lsb, site.gyro_lsb, g)
    return Scales(status.accel_lsb, status.gyro_lsb, g)


def _is_diagonal(name: str) -> bool:
    indices = name.partition("[")[2].replace("]", "").split("[")
    return len(indices) == 2 and indices[0] == indices[1]


def parameter_rows(
    solution: Solution, device: dict[str, float], scales: Scales
) -> list[tuple[str, str, str, str]]:
    """Return rows: parameter, value ± σ (file's unit), in the operator's, device now.

    The operator's units are mg, ppm, °, °/s (a scale factor's diagonal as ppm from
    nominal); each cell carries its unit from the units registry (docs/design.md §2).
    """
    joint = solution.joint
    if joint is None:
        return []
    sigma = np.sqrt(np.clip(np.diag(joint.covariance), 0.0, None))
    rows = []
    for k, name in enumerate(joint.names):
        now = device.get(name)
        quantity = quantity_of(name)  # the units registry's, not guessed from the name
        unit, scale = quantity.shown_unit, quantity.file_per_unit
        now_text = "—" if now is None else with_unit(now * scale, None, unit)
        if name in joint.undetermined:
            rows.append((name, "held nominal (undetermined)", "—", now_text))
            continue
        value = with_unit(joint.values[k] * scale, sigma[k] * scale, unit)
        shown = operator_value(
            quantity.family, joint.values[k], scales, diagonal=_is_diagonal(name)
        )
        shown_sigma = abs(operator_value(quantity.family, sigma[k], scales))
        operator = with_unit(shown, shown_sigma, quantity.operator_unit, digits=4)
        rows.append((name, value, operator, now_text))
    return rows


RESIDUAL_UNITS = {"a": "mg", "g": "°/s"}
"""The residual table's units: the accelerometer's in mg, the gyro's in °/s."""


def residual_rows(solution: Solution, scales: Scales) -> list[tuple[str, ...]]:
    """Rows: position, its angles (°), the residual of each channel (mg, °/s)."""
    joint = solution.joint
    if joint is None:
        return []
    factors = [operator_value("accel.bias", 1.0, scales)] * 3 + [
        operator_value("gyro.bias", 1.0, scales)
    ] * 3
    rows = []
    for i, (summary, res) in enumerate(
        zip(solution.record.positions or (), joint.residuals, strict=False)
    ):
        angles = "/".join(
            "—" if a is None else f"{a:g}°"
            for a in (summary.alpha_deg, summary.beta_deg, summary.psi_deg)
        )
        cells = (
            f"{r * f:+.3g} {RESIDUAL_UNITS[a[0]]}"
            for r, f, a in zip(res, factors, RESIDUAL_AXES, strict=False)
        )
        rows.append((str(i + 1), angles, *cells))
    return rows


class ResultsScreen(Screen[Command]):
    """Dismissed with the operator's answer as the command to run.

    ``WriteOptions()`` to write, ``WriteOptions(override=True)`` to write although the limits
    failed (operator's choice), ``SessionCommand.FINISH_WITHOUT_WRITING`` to finish.
    """

    BINDINGS = [
        Binding("w", "write", "Write to device"),
        Binding("o", "override", "Write anyway"),
        Binding("f", "finish", "Finish, no write"),
    ]

    def __init__(self, solved: ev.Solved, statuses: list[NodeStatus]) -> None:
        super().__init__()
        self.solved = solved
        self.statuses = {s.node_id: s for s in statuses}

    def compose(self) -> ComposeResult:
        """One section per node."""
        verdict = "passed" if self.solved.acceptable else "NOT passed"
        yield Static(f"canimucal · results · acceptance limits {verdict}", classes="screen-title")
        with VerticalScroll(id="results-body"):
            for node_id, solution in self.solved.solutions.items():
                yield Static(self._header(node_id, solution), classes="node-header")
                yield passive_table(id=f"params-{node_id}", zebra_stripes=True)
                yield passive_table(id=f"residuals-{node_id}", zebra_stripes=True)
        yield Footer()

    def _header(self, node_id: int, solution: Solution) -> str:
        report = self.solved.acceptance[node_id]
        lines = [f"node {node_id} (serial {solution.record.device.serial})"]
        lines += [c.line() for c in report.checks]
        if report.held_nominal:
            lines.append("held at nominal: " + ", ".join(report.held_nominal))
        lines += [f"warning: {w}" for w in solution.warnings]
        return "\n".join(lines)

    def on_mount(self) -> None:
        """Fill the tables."""
        for node_id, solution in self.solved.solutions.items():
            status = self.statuses.get(node_id)
            device = device_values(None if status is None else status.calibration)
            scales = scales_of(solution, status)
            params = self.query_one(f"#params-{node_id}", DataTable)
            params.add_columns("parameter", "value ± σ", "operator's units", "device now")
            params.add_rows(parameter_rows(solution, device, scales))
            residuals = self.query_one(f"#residuals-{node_id}", DataTable)
            rows = residual_rows(solution, scales)
            width = len(rows[0]) - 2 if rows else 3
            residuals.add_columns("pos", "α/β/ψ", *(f"res {a}" for a in RESIDUAL_AXES[:width]))
            residuals.add_rows(rows)

    def check_action(self, action: str, parameters: tuple[object, ...]) -> bool | None:
        """Write when the limits passed; write anyway only when they did not."""
        if action == "write":
            return self.solved.acceptable
        if action == "override":
            return not self.solved.acceptable
        return True

    def _confirm_text(self) -> str:
        nodes = [
            f"node {n} (serial {s.record.device.serial})" for n, s in self.solved.solutions.items()
        ]
        return (
            "Write the new calibration to " + ", ".join(nodes) + ".\n"
            "The current values are saved as a backup first; the write is verified value by "
            "value and rolled back on any failure, then stored (0x1010:04)."
        )

    def _ask(self, write: WriteOptions) -> None:
        def answered(yes: bool | None) -> None:
            if yes:
                self.dismiss(write)

        self.app.push_screen(ConfirmWrite(self._confirm_text()), answered)

    def action_write(self) -> None:
        """Ask, then write."""
        self._ask(WriteOptions())

    def action_override(self) -> None:
        """Ask, then write although the limits failed."""
        self._ask(WriteOptions(override=True))

    def action_finish(self) -> None:
        """End without writing."""
        self.dismiss(SessionCommand.FINISH_WITHOUT_WRITING)
