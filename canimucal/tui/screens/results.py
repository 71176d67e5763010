"""The results screen: each parameter ± σ beside the device's current value.

Also the residual per position and the acceptance checks; w writes (after the confirmation
modal), f finishes.
"""

from __future__ import annotations

import numpy as np
from textual.app import ComposeResult
from textual.binding import Binding
from textual.containers import VerticalScroll
from textual.screen import Screen
from textual.widgets import DataTable, Footer, Static

from canimucal.analysis.calibrate import Solution
from canimucal.model.vocabulary.units import quantity_of
from canimucal.procedure import events as ev
from canimucal.runtime.session import SessionCommand, WriteOptions
from canimucal.tui.modals import ConfirmWrite
from canimucal.tui.runner import Command
from canimucal.tui.source import NodeStatus
from canimucal.tui.text import device_values
from canimucal.tui.widgets import passive_table

RESIDUAL_AXES = ("ax", "ay", "az", "gx", "gy", "gz")


def parameter_rows(solution: Solution, device: dict[str, float]) -> list[tuple[str, str, str, str]]:
    """Rows: parameter, value ± σ, unit, the device's current value (the file's units)."""
    joint = solution.joint
    if joint is None:
        return []
    sigma = np.sqrt(np.clip(np.diag(joint.covariance), 0.0, None))
    rows = []
    for k, name in enumerate(joint.names):
        now = device.get(name)
        quantity = quantity_of(name)  # the units registry's, not guessed from the name
        unit, scale = quantity.shown_unit, quantity.file_per_unit
        now_text = "—" if now is None else f"{now * scale:.6g}"
        if name in joint.undetermined:
            rows.append((name, "held nominal (undetermined)", unit, now_text))
            continue
        value = f"{joint.values[k] * scale:.6g} ± {sigma[k] * scale:.2g}"
        rows.append((name, value, unit, now_text))
    return rows


def residual_rows(solution: Solution) -> list[tuple[str, ...]]:
    """Rows: position, its angles (deg), the residual of each channel (counts)."""
    joint = solution.joint
    if joint is None:
        return []
    rows = []
    for i, (summary, res) in enumerate(
        zip(solution.record.positions or (), joint.residuals, strict=False)
    ):
        angles = "/".join(
            "—" if a is None else f"{a:g}"
            for a in (summary.alpha_deg, summary.beta_deg, summary.psi_deg)
        )
        rows.append((str(i + 1), angles, *(f"{r:+.2f}" for r in res)))
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
            params = self.query_one(f"#params-{node_id}", DataTable)
            params.add_columns("parameter", "value ± σ", "unit", "device now")
            params.add_rows(parameter_rows(solution, device))
            residuals = self.query_one(f"#residuals-{node_id}", DataTable)
            rows = residual_rows(solution)
            width = len(rows[0]) - 2 if rows else 3
            residuals.add_columns("pos", "α/β/ψ deg", *(f"res {a}" for a in RESIDUAL_AXES[:width]))
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
