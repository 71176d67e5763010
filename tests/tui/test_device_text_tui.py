"""Device text and bus names with markup in them are shown literally (issue 13, failure 6)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import pytest

from canimucal.tui.app import make_app
from canimucal.tui.screens.connection import ConnectionScreen
from tests.support.tui_fakes import FakeSource, node_status, screen_text

pytestmark = pytest.mark.asyncio


async def test_markup_in_device_name_and_channel_is_shown_not_parsed(tmp_path: Path) -> None:
    status = node_status()
    status = replace(status, identity=status.identity._replace(device_name="evil [/] [b]x[/b]"))
    source = FakeSource(tmp_path, statuses=[status], description="socketcan [/]can0")
    app = make_app(source)
    async with app.run_test(size=(100, 24)) as pilot:
        screen = app.screen
        assert isinstance(screen, ConnectionScreen)
        for _ in range(100):
            if screen.state == "connected":
                break
            await pilot.pause(0.05)
        await pilot.pause()
        text = screen_text(app)
        assert "evil [/] [b]x[/b]" in text and "socketcan [/]can0" in text


async def test_notices_show_bracketed_words_literally() -> None:
    """Messages and paths put into the position screen's marked-up notices are escaped."""
    from textual.content import Content

    from canimucal.procedure import events as ev
    from canimucal.tui.screens.position import notice_text

    evil = "restored from /tmp/run [/]/[b]x[/b].json"
    for event in (
        ev.WriteFinished(16, False, evil),
        ev.DeviceEventReported(16, "emergency", evil),
    ):
        shown = Content.from_markup(notice_text(event)).plain  # raised MarkupError before
        assert shown.endswith(evil)
