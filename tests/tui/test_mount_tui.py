"""Choosing the mounting map on the plan screen: checked as typed, shown, saved at start."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from canimucal.io.mounting import load_mounting, save_mounting
from canimucal.model.mounting import MountingMap
from canimucal.model.vehicle_size import VehicleSize
from canimucal.procedure.machine import Phase
from canimucal.sim.truth import Truth
from canimucal.tui.app import make_app
from canimucal.tui.modals import MountModal
from canimucal.tui.screens.plan import PlanScreen
from canimucal.tui.screens.position import PositionScreen
from canimucal.tui.source import demo_source
from tests.support.pilot_steps import press, until
from tests.support.tui_fakes import SERIAL, FakeSource, node_status, screen_text

pytestmark = pytest.mark.asyncio

SIZE = (80, 24)


async def test_the_mount_is_chosen_once_on_the_plan_screen_and_goes_to_the_source(
    tmp_path: Path,
) -> None:
    source = FakeSource(tmp_path)
    app = make_app(source, plan_name="vehicle", autoconnect=False)
    async with app.run_test(size=SIZE) as pilot:
        await app.push_screen(PlanScreen([node_status()], app.plans, plan_name="vehicle"))
        await pilot.pause()
        text = screen_text(app)
        assert "vehicle wording: mount x=forward,y=down,z=left, the default · m" in text
        assert "Quit" in text.splitlines()[-1]
        await pilot.press("m")
        await pilot.pause()
        assert isinstance(app.screen, MountModal)
        await pilot.press("ctrl+a", "ctrl+k", *"x=forward,y=left,z=down", "enter")
        await pilot.pause()
        assert isinstance(app.screen, MountModal)  # refused, with the reason
        assert "mirror image" in screen_text(app)
        await pilot.press("ctrl+a", "ctrl+k", *"x=left,y=down,z=back", "enter")
        await pilot.pause()
        assert isinstance(app.screen, PlanScreen)
        assert "vehicle wording: mount x=left,y=down,z=back · m changes it" in screen_text(app)
        await pilot.press("enter")  # start: the fake source then fails to open, which is fine
        await pilot.pause()
    assert source.mount == MountingMap("left", "down", "back") and source.replace_mount


async def test_a_saved_map_is_shown_and_a_bench_plan_keeps_body_axes(tmp_path: Path) -> None:
    save_mounting(SERIAL, MountingMap("back", "down", "right"))
    app = make_app(FakeSource(tmp_path), autoconnect=False)
    async with app.run_test(size=SIZE) as pilot:
        await app.push_screen(PlanScreen([node_status()], app.plans, plan_name="recommended"))
        await pilot.pause()
        assert "instructions in the unit's own axes" in screen_text(app)
        await pilot.press("v")
        await pilot.pause()
        assert "mount x=back,y=down,z=right, as saved" in screen_text(app)
        await pilot.press("m", "escape")  # escape keeps the map
        await pilot.pause()
        assert isinstance(app.screen, PlanScreen)
        assert ", as saved" in screen_text(app)


async def test_a_vehicle_session_words_its_first_pose_for_the_vehicle_and_says_which_mount(
    tmp_path: Path,
) -> None:
    truth = Truth.random(np.random.default_rng(5), cross_axis_max=0.0)
    source = demo_source([truth], tmp_path, time_scale=20.0, seed=5, seconds=5.0)
    source.warmup = False
    source.mount = MountingMap("left", "down", "back")
    app = make_app(source, plan_name="vehicle")
    async with app.run_test(size=SIZE) as pilot:
        await until(pilot, lambda: app.screen.check_action("next", ()) is True, "the node")
        await press(pilot, "enter")  # connection -> plan
        await pilot.pause()
        assert "vehicle wording: mount x=left,y=down,z=back" in screen_text(app)
        await press(pilot, "enter")  # plan vehicle -> position
        screen = app.screen
        assert isinstance(screen, PositionScreen)
        await until(pilot, lambda: screen.phase is Phase.INSTRUCT, "the first instruction")
        await pilot.pause()
        text = screen_text(app)
        assert "park the vehicle level at the start heading" in text
        assert "mounting x=left,y=down,z=back saved for serial" in text
    serial = next(iter(source.statuses.values())).identity.serial
    assert load_mounting(serial) == MountingMap("left", "down", "back")


async def test_the_plan_screen_says_whether_tilts_are_worded_as_heights(tmp_path: Path) -> None:
    """--wheelbase/--track (or a size saved for the unit) word the tilts as heights."""
    app = make_app(FakeSource(tmp_path), plan_name="vehicle", autoconnect=False)
    async with app.run_test(size=SIZE) as pilot:
        await app.push_screen(PlanScreen([node_status()], app.plans, plan_name="vehicle"))
        await pilot.pause()
        assert "tilts as angles (--wheelbase M and --track M word them as heights)" in (
            screen_text(app)
        )
        sized = PlanScreen(
            [node_status()], app.plans, plan_name="vehicle", vehicle_size=VehicleSize(3.5, 1.8)
        )
        await app.push_screen(sized)
        await pilot.pause()
        assert "tilts as heights: wheelbase 3.5 m, track 1.8 m" in screen_text(app)
    save_mounting(SERIAL, None, size=VehicleSize(wheelbase_m=4.0))  # saved for the unit
    app = make_app(FakeSource(tmp_path), plan_name="vehicle", autoconnect=False)
    async with app.run_test(size=SIZE) as pilot:
        await app.push_screen(PlanScreen([node_status()], app.plans, plan_name="vehicle"))
        await pilot.pause()
        assert "tilts as heights: wheelbase 4 m" in screen_text(app)
