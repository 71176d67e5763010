"""Custom plans / pose schedules: JSON and TOML, strict checks, round trips, resolution."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from canimucal.errors import InputError
from canimucal.io.plans import plan_to_dict, read_plan, resolve_plan, write_plan
from canimucal.model.positions import Plan, PlannedPosition
from canimucal.model.vocabulary.plans import builtin_plan

JSON_PLAN = """{"positions": [
  {"alpha_deg": 0, "beta_deg": 0},
  {"alpha_deg": 30, "beta_deg": -5, "psi_deg": 180, "seconds": 45, "tolerance_deg": 0.05}
]}
"""
TOML_PLAN = """[[positions]]
alpha_deg = 0
beta_deg = 0

[[positions]]
alpha_deg = 30
beta_deg = -5
psi_deg = 180
seconds = 45
tolerance_deg = 0.05
"""


def _write(tmp_path: Path, name: str, text: str) -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


@pytest.mark.parametrize(
    ("name", "text"),
    [("p.json", JSON_PLAN), ("p.toml", TOML_PLAN), ("p.plan", JSON_PLAN), ("p.txt", TOML_PLAN)],
)
def test_json_and_toml_read_the_same(tmp_path: Path, name: str, text: str) -> None:
    plan = read_plan(_write(tmp_path, name, text))
    assert plan.name == "custom" and len(plan.positions) == 2
    first, second = plan.positions
    assert (first.psi, first.seconds) == (0.0, 30.0)
    assert first.tolerance == pytest.approx(np.deg2rad(0.1))
    assert second.alpha == pytest.approx(np.deg2rad(30)) and second.beta == pytest.approx(
        np.deg2rad(-5)
    )
    assert second.psi == pytest.approx(np.pi) and second.seconds == 45.0
    assert second.tolerance == pytest.approx(np.deg2rad(0.05))


def test_round_trip_plan_to_file_to_plan(tmp_path: Path) -> None:
    rng = np.random.default_rng(7)
    plan = Plan(
        "custom",
        tuple(
            PlannedPosition(
                alpha=float(np.deg2rad(rng.uniform(-80, 80))),
                beta=float(np.deg2rad(rng.uniform(-80, 80))),
                psi=float(np.deg2rad(rng.uniform(-170, 170))),
                tolerance=float(np.deg2rad(0.2)),
                seconds=float(rng.uniform(1, 100)),
            )
            for _ in range(6)
        ),
    )
    back = read_plan(write_plan(tmp_path / "s.json", plan, overwrite=False))
    for p, q in zip(plan.positions, back.positions, strict=True):
        np.testing.assert_allclose(q.angles, p.angles, atol=1e-11)
        assert q.seconds == p.seconds and q.tolerance == pytest.approx(p.tolerance, abs=1e-12)


def test_file_to_plan_to_file_keeps_round_degrees(tmp_path: Path) -> None:
    plan = read_plan(_write(tmp_path, "p.json", JSON_PLAN))
    doc = plan_to_dict(plan)
    assert doc["positions"][1] == {
        "alpha_deg": 30.0,
        "beta_deg": -5.0,
        "psi_deg": 180.0,
        "seconds": 45.0,
        "tolerance_deg": 0.05,
    }
    path = write_plan(tmp_path / "again.json", plan, overwrite=False)
    assert json.loads(path.read_text()) == doc
    with pytest.raises(InputError, match="exists; use overwrite=True"):
        write_plan(path, plan, overwrite=False)


def _json(*positions: str, extra: str = "") -> str:
    return '{"positions": [' + ", ".join(positions) + "]" + extra + "}"


OK = '{"alpha_deg": 0, "beta_deg": 0}'
MALFORMED = [
    (
        "p.json",
        _json(OK, '{"alpha_deg": 1, "beta_deg": 0, "gamma_deg": 1}'),
        "position 2: unknown key 'gamma_deg'",
    ),
    ("p.json", _json(OK, extra=', "name": "x"'), "unknown key 'name'"),
    ("p.json", _json('{"beta_deg": 0}'), "position 1: missing 'alpha_deg'"),
    ("p.json", _json(OK, '{"alpha_deg": 0}'), "position 2: missing 'beta_deg'"),
    ("p.json", _json('{"alpha_deg": 181, "beta_deg": 0}'), "position 1: alpha_deg must be within"),
    ("p.json", _json('{"alpha_deg": 0, "beta_deg": -180.5}'), "beta_deg must be within ±180"),
    ("p.json", _json('{"alpha_deg": 0, "beta_deg": 0, "psi_deg": 361}'), "psi_deg must be within"),
    ("p.json", _json('{"alpha_deg": 0, "beta_deg": 0, "seconds": -1}'), "seconds must be > 0"),
    ("p.json", _json('{"alpha_deg": 0, "beta_deg": 0, "seconds": 0}'), "seconds must be > 0"),
    ("p.json", _json('{"alpha_deg": 0, "beta_deg": 0, "tolerance_deg": -0.1}'), "tolerance_deg"),
    ("p.json", _json('{"alpha_deg": NaN, "beta_deg": 0}'), "NaN is not allowed"),
    ("p.json", _json('{"alpha_deg": 1e999, "beta_deg": 0}'), "alpha_deg: must be a finite number"),
    ("p.json", _json('{"alpha_deg": "5", "beta_deg": 0}'), "alpha_deg: must be a finite number"),
    ("p.json", _json('{"alpha_deg": true, "beta_deg": 0}'), "alpha_deg: must be a finite number"),
    ("p.json", _json("[1, 2]"), "position 1: must be an object"),
    ("p.json", _json(), "'positions' must be a non-empty list"),
    ("p.json", '{"positions": {"alpha_deg": 0}}', "'positions' must be a non-empty list"),
    ("p.json", "[]", "top level is not an object"),
    ("p.json", '{"positions": [', "invalid JSON"),
    (
        "p.toml",
        "[[positions]]\nalpha_deg = nan\nbeta_deg = 0\n",
        "alpha_deg: must be a finite number",
    ),
    (
        "p.toml",
        "[[positions]]\nalpha_deg = -inf\nbeta_deg = 0\n",
        "alpha_deg: must be a finite number",
    ),
    ("p.toml", "[[positions]]\nalpha_deg = 1979-05-27\nbeta_deg = 0\n", "must be a finite number"),
    ("p.toml", "[[positions]\nalpha_deg = 0\n", "invalid TOML"),
    ("p.toml", "title = 'x'\n", "unknown key 'title'"),
]


@pytest.mark.parametrize(("name", "text", "words"), MALFORMED)
def test_malformed_plan_is_an_input_error(tmp_path: Path, name: str, text: str, words: str) -> None:
    path = _write(tmp_path, name, text)
    with pytest.raises(InputError) as info:
        read_plan(path)
    message = str(info.value)
    assert "\n" not in message and message.startswith(str(path))
    assert words in message


def test_resolve_builtin_names_and_files(tmp_path: Path) -> None:
    assert resolve_plan("five") is builtin_plan("five")
    path = _write(tmp_path, "mine.toml", TOML_PLAN)
    assert resolve_plan(str(path)).name == "custom"
    assert resolve_plan(path).name == "custom"
    with pytest.raises(InputError, match="unknown plan 'six': not one of two, five, recommended"):
        resolve_plan("six")
