"""The results screen's units come from the units registry, not from parameter names."""

from __future__ import annotations

import numpy as np

from canimucal.model.vocabulary.units import QUANTITIES
from canimucal.tui.screens.results import parameter_rows
from tests.support.tui_fakes import solved_event


def test_a_navigation_gyro_shows_its_scale_in_counts_per_rad_s() -> None:
    solution = solved_event("recommended", gyro="nav").solutions[0x10]
    rows = {name: (value, unit) for name, value, unit, _ in parameter_rows(solution, {})}
    assert {n for n in rows if n.startswith("gyro.S")} == {f"gyro.S[{i}][{i}]" for i in range(3)}
    for name, (_, unit) in rows.items():
        family = name.split("[")[0] if "[" in name else "base_tilt"
        assert unit == QUANTITIES[family].shown_unit, name
    assert rows["gyro.S[0][0]"][1] == "counts/(rad/s)"  # was counts/(m/s²), guessed from "S"
    assert rows["gyro.bias[0]"][1] == "counts"


def test_the_base_tilt_is_shown_in_the_files_degrees() -> None:
    solution = solved_event("recommended").solutions[0x10]
    joint = solution.joint
    assert joint is not None
    k = joint.names.index("base_tilt.alpha0")
    rows = {name: (value, unit) for name, value, unit, _ in parameter_rows(solution, {})}
    value, unit = rows["base_tilt.alpha0"]
    assert unit == "deg"
    assert float(value.split(" ± ")[0]) == float(f"{np.rad2deg(joint.values[k]):.6g}")
