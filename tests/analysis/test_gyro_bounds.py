"""Which of a plan's moves identify which entries of the gyro's S, and how well."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from canimucal.analysis.gyro_bounds import gyro_move_bounds
from canimucal.cli.main import main
from canimucal.model.positions import Plan
from canimucal.model.vocabulary.plans import builtin_plan
from tests.support.moves import turns_plan


def test_builtin_plans_identify_what_their_moves_turn_about() -> None:
    two = gyro_move_bounds(builtin_plan("two"))  # one tilt of 45° about z
    assert two.identifiable.tolist() == [False, False, True]
    assert two.seen_by == ((), (), ("1→2",))
    recommended = gyro_move_bounds(builtin_plan("recommended"))  # stands alternating: full S
    assert recommended.identifiable.all() and not recommended.notes
    assert np.all(recommended.relative_sigma < 0.0025)
    stand_changes = ("1→2", "3→4", "5→6", "7→8")
    assert recommended.seen_by == (stand_changes, ("2→3", "4→5", "6→7"), stand_changes)
    positions = builtin_plan("recommended").positions
    by_stand = Plan("custom", tuple(positions[i] for i in (0, 3, 4, 7, 1, 2, 5, 6)))
    bounds = gyro_move_bounds(by_stand)  # same poses, each stand's turns in a row: y only
    assert bounds.identifiable.tolist() == [False, True, False]
    assert np.all(np.isnan(bounds.relative_sigma[:, [0, 2]]))
    assert any("column z not identifiable" in n for n in bounds.notes)


def test_a_turn_about_each_axis_identifies_all_of_s() -> None:
    bounds = gyro_move_bounds(turns_plan())
    assert bounds.identifiable.all() and not bounds.notes
    assert np.all(bounds.relative_sigma < 0.005)
    # the bound matches the scatter of the simulated fits (test_gyro_moves: σ below 0.2 %)
    assert np.all(bounds.relative_sigma > 1e-4)


def test_plan_command_prints_and_writes_the_gyro_bounds(tmp_path: Path) -> None:
    out = tmp_path / "plan.json"
    assert main(["plan", "--plan", "two", "--gyro", "moves", "--json", str(out)]) == 0
    doc = json.loads(out.read_text())["gyro_moves"]
    assert doc["identifiable_columns"] == {"x": False, "y": False, "z": True}
    assert doc["S_relative_sigma"][0][0] is None and doc["S_relative_sigma"][2][2] > 0
    assert doc["seen_by"]["z"] == ["1→2"]
