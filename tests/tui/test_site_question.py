"""The TUI asks who calibrates where before the first position (issue 22 item 4).

No ``--site``, ``--latitude-deg`` or ``--g``: after the plan, a question offers the last
answer (the user's state file), refuses an answer with neither latitude nor g (g is never
assumed), and the session then runs at the normal gravity of the latitude and height given;
the certificate names the operator, the site and the latitude, and the answer is kept for the
next session. Two positions of the simulated node through Pilot at 80×24.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from textual.widgets import Input

from canimucal.io.site_memory import LastSite, read_last_site, save_last_site
from canimucal.model.gravity import normal_gravity
from canimucal.procedure.machine import Phase
from canimucal.sim.truth import Truth
from canimucal.tui.app import make_app
from canimucal.tui.modals import SiteModal
from canimucal.tui.screens.plan import PlanScreen
from canimucal.tui.screens.position import PositionScreen
from canimucal.tui.source import demo_source
from canimucal.tui.widgets import PlainStatic
from tests.support.pilot_steps import measure_positions, press, until, write_and_verify

SEED = 20261129
pytestmark = pytest.mark.asyncio


def asked(screen: object) -> bool:
    """The site question is shown, its fields composed."""
    return isinstance(screen, SiteModal) and bool(screen.query("#site-g"))


async def test_the_tui_asks_the_site_and_operator_before_the_first_position(
    tmp_path: Path,
) -> None:
    truth = Truth.random(np.random.default_rng(SEED), cross_axis_max=0.0)
    out = tmp_path / "out"
    source = demo_source([truth], out, time_scale=20.0, seed=SEED, seconds=2.0)
    source.verify_seconds = 2.0
    memory = tmp_path / "state" / "last-site.json"
    save_last_site(memory, LastSite("Ann Tester", "Bay 3", 48.1, 520.0, None))
    source.ask_site, source.last_site_file = True, memory
    app = make_app(source, plan_name="two")
    async with app.run_test(size=(80, 24)) as pilot:
        await until(pilot, lambda: app.screen.check_action("next", ()) is True, "the node")
        await press(pilot, "enter")  # connection -> plan
        await until(pilot, lambda: isinstance(app.screen, PlanScreen), "the plan")
        await press(pilot, "enter")  # plan two -> the question, not the position
        await until(pilot, lambda: asked(app.screen), "the site question")
        question = app.screen
        assert isinstance(question, SiteModal)
        offered = question.values()  # the last answer, offered
        assert offered == {
            "operator": "Ann Tester", "site": "Bay 3", "latitude": "48.1", "height": "520",
            "g": "",
        }  # fmt: skip
        question.query_one("#site-latitude", Input).value = ""  # neither latitude nor g
        question.query_one("#site-operator", Input).focus()
        await pilot.pause()
        await press(pilot, "enter")
        error = question.query_one("#site-error", PlainStatic)
        await until(pilot, lambda: "latitude" in str(error.render()), "the reason")
        assert app.screen is question  # refused, with the reason
        assert str(error.render()) == "give the latitude (and height), or the local g"
        question.query_one("#site-latitude", Input).value = "-33.9"
        question.query_one("#site-height", Input).value = "12"
        question.query_one("#site-operator", Input).value = "Bo Field"
        await press(pilot, "enter")
        await until(pilot, lambda: isinstance(app.screen, PositionScreen), "the position")
        screen = app.screen
        assert isinstance(screen, PositionScreen)
        assert source.site is not None
        assert source.site.g == normal_gravity(float(np.deg2rad(-33.9)), 12.0)
        await until(pilot, lambda: screen.phase is Phase.WARMUP, "warm-up")
        await press(pilot, "w")
        await measure_positions(pilot, screen, range(2))
        await write_and_verify(pilot, screen)
    certificate = (out / "certificate.md").read_text()
    assert "- Operator: Bo Field" in certificate and "- Site: Bay 3" in certificate
    assert "latitude -33.9°" in certificate and "None" not in certificate
    record = json.loads((out / "calibration.json").read_text())
    assert record["conditions"]["g"] == pytest.approx(normal_gravity(np.deg2rad(-33.9), 12.0))
    assert read_last_site(memory) == LastSite("Bo Field", "Bay 3", -33.9, 12.0, None)


async def test_escape_goes_back_to_the_plan_and_flags_skip_the_question(tmp_path: Path) -> None:
    truth = Truth.random(np.random.default_rng(SEED), cross_axis_max=0.0)
    source = demo_source([truth], tmp_path, time_scale=20.0, seed=SEED, seconds=2.0)
    source.ask_site, source.last_site_file = True, tmp_path / "none.json"
    app = make_app(source, plan_name="two")
    async with app.run_test(size=(80, 24)) as pilot:
        await until(pilot, lambda: app.screen.check_action("next", ()) is True, "the node")
        await press(pilot, "enter")
        await until(pilot, lambda: isinstance(app.screen, PlanScreen), "the plan")
        await press(pilot, "enter")
        await until(pilot, lambda: asked(app.screen), "the site question")
        assert set(app.screen.values().values()) == {""}  # type: ignore[attr-defined]
        await press(pilot, "escape")
        await until(pilot, lambda: isinstance(app.screen, PlanScreen), "back on the plan")
        assert source.site is None and not (tmp_path / "none.json").exists()
