"""The connection screen shows the bus load its clients see, next to the heartbeats."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import pytest

from canimucal.device.busload import BusLoad
from canimucal.tui.app import make_app
from canimucal.tui.screens.connection import ConnectionScreen, LinkState
from canimucal.tui.source import Heartbeat
from tests.support.tui_fakes import FakeSource, screen_text

pytestmark = pytest.mark.asyncio


@dataclass
class LoadedSource(FakeSource):
    """A fake source whose heartbeats carry a bus load."""

    def heartbeat(self, node_id: int) -> Heartbeat:
        load = BusLoad(0.032, 412.0, 0, 0, 1.0, 500_000, True)
        return Heartbeat("OPERATIONAL", 0.25, load)


async def test_connection_screen_shows_the_bus_load(tmp_path: Path) -> None:
    app = make_app(LoadedSource(tmp_path))
    async with app.run_test(size=(120, 24)) as pilot:
        screen = app.screen
        assert isinstance(screen, ConnectionScreen)
        for _ in range(100):
            if screen.state is LinkState.CONNECTED:
                break
            await pilot.pause(0.05)
        await pilot.pause()
        text = screen_text(app)
        assert "bus load: 3.2 % of 500 kbit/s (assumed) (412 frames/s, 0 error frames)" in text
        assert "op 0.2 s ago" in text
