"""Every instruction of every built-in plan shows in full on the position screen at 80×24."""

from __future__ import annotations

from pathlib import Path

import pytest
from textual.geometry import Region
from textual.widgets import Static

from canimucal.model.mounting import DEFAULT_MOUNTING, MountingMap
from canimucal.model.vocabulary.plans import builtin_plan
from canimucal.procedure import events as ev
from canimucal.procedure.posecheck import describe_pose
from canimucal.tui.app import make_app
from canimucal.tui.messages import EventsArrived
from canimucal.tui.screens.position import PositionScreen
from tests.support.tui_fakes import FakeSource, node_status

pytestmark = pytest.mark.asyncio

SIZE = (80, 24)
PLANS = ("two", "five", "recommended", "vehicle")
MOUNTS: tuple[MountingMap | None, ...] = (
    None,  # body axes (bench)
    DEFAULT_MOUNTING,
    MountingMap.parse("x=left,y=down,z=back"),
    MountingMap.parse("x=forward,y=left,z=up"),  # large vehicle angles: the longest words
)


def rendered_text(widget: Static) -> list[str]:
    """The widget's lines as the screen draws them (cropped to its region)."""
    width, height = widget.size.width, widget.size.height
    strips = widget.render_lines(Region(0, 0, width, height))
    return [strip.text.strip() for strip in strips]


def every_instruction() -> list[str]:
    """The distinct instructions of every pose of every built-in plan under each mount."""
    words = {
        describe_pose(pose, mounting)
        for plan in PLANS
        for pose in builtin_plan(plan).positions
        for mounting in MOUNTS
    }
    return sorted(words, key=lambda w: (-len(w.splitlines()), -len(w), w))


async def test_every_instruction_line_is_shown_whole(tmp_path: Path) -> None:
    app = make_app(FakeSource(tmp_path), autoconnect=False)
    pose = builtin_plan("two").positions[0]  # the drawing is not under test here
    async with app.run_test(size=SIZE) as pilot:
        screen = PositionScreen([node_status()], None, total=8)
        await pilot.app.push_screen(screen)
        words_w = screen.query_one("#words", Static)
        footer_top = screen.query_one("Footer").region.y
        for words in every_instruction():
            screen.post_message(EventsArrived([ev.PoseInstructed(0, 8, pose, words, 60.0)]))
            await pilot.pause()
            shown = rendered_text(words_w)
            assert shown == [*words.splitlines(), "average 60 s once still"], shown
            assert words_w.region.bottom <= footer_top  # nothing pushed off the screen
            assert screen.query_one("#notice").region.height >= 1
