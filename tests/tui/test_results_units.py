"""The results screen's units come from the units registry, and no value is a bare number."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from textual.widgets import DataTable

from canimucal.model.vocabulary.units import QUANTITIES, Scales
from canimucal.tui.app import make_app
from canimucal.tui.screens.results import ResultsScreen, parameter_rows, residual_rows
from tests.support.tui_fakes import FakeSource, node_status, screen_text, solved_event

G = 9.80665
SCALES = Scales(G / 2048.0, float(np.deg2rad(1.0 / 16.4)), G)
NUMBER = re.compile(r"[-+]?\d[\d.]*(?:e[-+]?\d+)?(?: ± [\d.]+(?:e[-+]?\d+)?)?(°?)(?: (\S+))?")
UNITS = (
    {q.shown_unit for q in QUANTITIES.values()}
    | {q.operator_unit for q in QUANTITIES.values()}
    | {"mg", "°/s"}
)


def bare_numbers(cell: str) -> list[str]:
    """The numbers of ``cell`` followed by no unit of the registry (nor a degree sign)."""
    return [m.group(0) for m in NUMBER.finditer(cell) if not m.group(1) and m.group(2) not in UNITS]


def test_the_check_finds_a_bare_number() -> None:
    assert bare_numbers("12.5 ± 0.1") == ["12.5 ± 0.1"]
    assert bare_numbers("12.5 ± 0.1 mg") == [] and bare_numbers("0/90°/—") == ["0"]
    assert bare_numbers("0°/90°/—") == []


def test_a_navigation_gyro_shows_its_scale_in_counts_per_rad_s() -> None:
    solution = solved_event("recommended", gyro="nav").solutions[0x10]
    rows = {name: value for name, value, _, _ in parameter_rows(solution, {}, SCALES)}
    assert {n for n in rows if n.startswith("gyro.S")} == {f"gyro.S[{i}][{i}]" for i in range(3)}
    for name, value in rows.items():
        family = name.split("[")[0] if "[" in name else "base_tilt"
        assert value.endswith(" " + QUANTITIES[family].shown_unit), name
    assert rows["gyro.S[0][0]"].endswith(" counts/(rad/s)")  # was counts/(m/s²), from "S"
    assert rows["gyro.bias[0]"].endswith(" counts")


def test_the_base_tilt_is_shown_in_the_files_degrees_and_the_operators() -> None:
    solution = solved_event("recommended").solutions[0x10]
    joint = solution.joint
    assert joint is not None
    k = joint.names.index("base_tilt.alpha0")
    rows = {name: (value, shown) for name, value, shown, _ in parameter_rows(solution, {}, SCALES)}
    value, shown = rows["base_tilt.alpha0"]
    assert value.endswith(" deg") and shown.endswith(" °")
    assert float(value.split(" ± ")[0]) == float(f"{np.rad2deg(joint.values[k]):.6g}")
    bias = joint.names.index("accel.bias[0]")
    mg = joint.values[bias] * SCALES.accel_lsb / G * 1e3
    assert float(rows["accel.bias[0]"][1].split(" ± ")[0]) == float(f"{mg:.4g}")
    first = residual_rows(solution, SCALES)[0]
    res_ax = joint.residuals[0][0] * SCALES.accel_lsb / G * 1e3
    assert first[2] == f"{res_ax:+.3g} mg" and first[5].endswith(" °/s")


@pytest.mark.asyncio
async def test_every_value_on_the_results_screen_carries_a_unit(tmp_path: Path) -> None:
    """Issue 22 item 6: read every cell of both tables; a bare number fails."""
    app = make_app(FakeSource(tmp_path), autoconnect=False)
    async with app.run_test(size=(80, 24)) as pilot:
        await app.push_screen(ResultsScreen(solved_event("recommended"), [node_status()]))
        await pilot.pause()
        checked = 0
        for table_id in ("#params-16", "#residuals-16"):
            table = app.screen.query_one(table_id, DataTable)
            assert table.row_count > 0
            for r in range(table.row_count):
                for c, cell in enumerate(table.get_row_at(r)[1:], start=1):
                    assert not bare_numbers(str(cell)), (table_id, r, c, cell)
                    checked += bool(NUMBER.search(str(cell)))
        assert checked > 50
        text = screen_text(app)  # the acceptance lines: each limit in its value's unit
        assert "(limit 5 mg) ok" in text and "(limit 0.05 m/s²) ok" in text
