"""`canimucal tui`'s options, by parsing only: the TUI itself never starts here."""

from __future__ import annotations

import json
from pathlib import Path

from canimucal.cli.tui_cmd import plan_choice
from canimucal.io.plans import plan_to_dict
from canimucal.model.plan import builtin_plan


def test_a_built_in_plan_keeps_its_name_and_a_file_is_custom(tmp_path: Path) -> None:
    plan, name = plan_choice("vehicle")
    assert name == "vehicle" and plan == builtin_plan("vehicle")
    assert plan_choice("two")[1] == "two"
    path = tmp_path / "mine.json"
    path.write_text(json.dumps(plan_to_dict(builtin_plan("five"))))
    assert plan_choice(str(path))[1] == "custom"
