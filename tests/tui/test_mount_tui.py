"""Choosing the mounting map on the plan screen: checked as typed, shown, saved at start."""

from __future__ import annotations

from pathlib import Path

import pytest

from canimucal.io.mounting import save_mounting
from canimucal.model.mounting import MountingMap
from canimucal.tui.app import make_app
from canimucal.tui.modals import MountModal
from canimucal.tui.plan_screen import PlanScreen
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
