"""The operator's name and the site given to the TUI's source reach the certificate.

A two-position calibration of the simulated node through Pilot at 80×24 (2 s a position,
the simulated clock 20× the wall clock); the certificate written after the verified write
must name them.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from canimucal.procedure.machine import Phase
from canimucal.sim.truth import Truth
from canimucal.tui.app import make_app
from canimucal.tui.screens.position import PositionScreen
from canimucal.tui.source import demo_source
from tests.support.pilot_steps import measure_positions, press, until, write_and_verify

SEED = 20261124
pytestmark = pytest.mark.asyncio


async def test_the_certificate_names_the_operator_and_site_given_to_the_tui(
    tmp_path: Path,
) -> None:
    truth = Truth.random(np.random.default_rng(SEED), cross_axis_max=0.0)
    source = demo_source([truth], tmp_path, time_scale=20.0, seed=SEED, seconds=2.0)
    source.verify_seconds = 2.0
    source.operator, source.site_name = "Ann Tester", "Bay 3 north wall"
    app = make_app(source, plan_name="two")
    async with app.run_test(size=(80, 24)) as pilot:
        await until(pilot, lambda: app.screen.check_action("next", ()) is True, "the node")
        await press(pilot, "enter")  # connection -> plan
        await pilot.pause()
        await press(pilot, "enter")  # plan two -> position
        screen = app.screen
        assert isinstance(screen, PositionScreen)
        await until(pilot, lambda: screen.phase is Phase.WARMUP, "warm-up")
        await press(pilot, "w")
        await measure_positions(pilot, screen, range(2))
        await write_and_verify(pilot, screen)
    certificate = (tmp_path / "certificate.md").read_text()
    assert "- Operator: Ann Tester" in certificate
    assert "- Site: Bay 3 north wall" in certificate
