"""The side-view gauges draw the unit's measured attitude beside the target (issue 12)."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from rich.text import Text

from canimucal.procedure.machine import Phase
from canimucal.sim.truth import Truth
from canimucal.tui.app import make_app
from canimucal.tui.screens.position import PositionScreen
from canimucal.tui.source import demo_source
from canimucal.tui.text import DRAW_COLS, TARGET_MARK, UNIT_MARK, pose_drawing
from tests.support.pilot_steps import press, until
from tests.support.tui_fakes import screen_text

WIDTH = 2 * DRAW_COLS + 3
LEGEND = re.compile(r"● unit α ([-+]\d+\.\d)° β ([-+]\d+\.\d)°")


def _marks(rows: list[str]) -> dict[str, set[tuple[int, int]]]:
    """Cells of the target's and the unit's markers in the drawing's five bar rows."""
    found: dict[str, set[tuple[int, int]]] = {TARGET_MARK: set(), UNIT_MARK: set()}
    for r, line in enumerate(rows):
        for c, char in enumerate(line):
            if char in found:
                found[char].add((r, c))
    return found


def _bar_rows(drawing: str) -> list[str]:
    return drawing.splitlines()[1:6]


@pytest.mark.parametrize(
    ("alpha", "beta", "psi"), [(0, 0, 0), (10, 0, 0), (0, -10, 90), (45, 45, 0)]
)
def test_the_unit_coincides_with_the_target_at_the_target_and_differs_off_it(
    alpha: float, beta: float, psi: float
) -> None:
    target = _marks(_bar_rows(pose_drawing(alpha, beta, psi)))
    assert len(target[TARGET_MARK]) == 2 and not target[UNIT_MARK]
    at = _marks(_bar_rows(pose_drawing(alpha, beta, psi, (alpha + 0.3, beta - 0.3))))
    assert at[UNIT_MARK] == target[TARGET_MARK] and not at[TARGET_MARK]
    off = _marks(_bar_rows(pose_drawing(alpha, beta, psi, (alpha - 25.0, beta + 25.0))))
    assert off[TARGET_MARK] == target[TARGET_MARK]  # the target stays where it was
    assert len(off[UNIT_MARK]) == 2 and not off[UNIT_MARK] & target[TARGET_MARK]


def test_the_gauge_has_a_legend_and_fits_its_column() -> None:
    drawing = pose_drawing(10.0, -10.0, 270.0, (7.25, -10.5))
    lines = drawing.splitlines()
    assert len(lines) <= 9 and max(len(line) for line in lines) <= WIDTH
    assert lines[-1] == f"{TARGET_MARK} target   {UNIT_MARK} unit α +7.2° β -10.5°"


def _drawn(app: object) -> list[str]:
    """The drawing's bar rows as the 80×24 terminal shows them."""
    lines = screen_text(app).splitlines()  # type: ignore[arg-type]
    head = next(i for i, line in enumerate(lines) if "alpha " in line and "beta " in line)
    return [line[1 : 1 + WIDTH] for line in lines[head + 1 : head + 6]]


@pytest.mark.asyncio
async def test_the_position_screen_draws_the_live_unit_beside_the_target(tmp_path: Path) -> None:
    truth = Truth.random(np.random.default_rng(12), cross_axis_max=0.0, tilt_max_deg=0.2)
    source = demo_source([truth], tmp_path, time_scale=5.0, seed=12, seconds=5.0)
    app = make_app(source, plan_name="vehicle")
    async with app.run_test(size=(80, 24)) as pilot:
        await until(pilot, lambda: app.screen.check_action("next", ()) is True, "the node")
        await press(pilot, "enter")  # connection -> plan
        await pilot.pause()
        await press(pilot, "enter")  # plan vehicle -> position
        screen = app.screen
        assert isinstance(screen, PositionScreen)
        await until(pilot, lambda: screen.phase is Phase.WARMUP, "warm-up")
        await press(pilot, "w")
        await until(pilot, lambda: screen.phase is Phase.INSTRUCT, "the first pose")
        assert screen.target_deg == (0.0, 0.0, 0.0)  # level, not turned; the unit is level

        def unit_at_target() -> bool:
            marks = _marks(_drawn(app))
            return len(marks[UNIT_MARK]) == 2 and not marks[TARGET_MARK]

        await until(pilot, unit_at_target, "the unit drawn on the target")
        assert "○ target   ● unit α" in screen_text(app)  # the legend, whole at 80×24
        content = screen.drawing.content
        assert isinstance(content, Text)
        assert any(str(span.style) == "bold cyan" for span in content.spans)
        target_cells = _marks(_bar_rows(pose_drawing(0.0, 0.0)))[TARGET_MARK]

        assert source.devices is not None
        source.devices.sim_nodes[0x10].set_pose(0.0, float(np.deg2rad(-30.0)), 0.0)

        def unit_off_target() -> bool:  # the right view (beta) moves; the target stays
            marks = _marks(_drawn(app))
            shown = marks[TARGET_MARK]
            legend = LEGEND.search(screen_text(app))
            settled = legend is not None and abs(float(legend[2]) + 30.0) < 1.0  # β measured
            return (
                settled
                and bool(shown)
                and shown <= target_cells
                and marks[UNIT_MARK] != target_cells
            )

        await until(pilot, unit_off_target, "the unit drawn off the target", timeout_s=15.0)
        marks = _marks(_drawn(app))
        right = {cell for cell in target_cells if cell[1] > DRAW_COLS}
        assert marks[TARGET_MARK] == right and len(marks[UNIT_MARK]) == 2
