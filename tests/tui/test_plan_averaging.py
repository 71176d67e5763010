"""The plan screen shows the procedure's averaging rule; it does not choose one."""

from __future__ import annotations

from pathlib import Path

import pytest

from canimucal.procedure.averaging import AveragingPolicy, describe_rule
from canimucal.tui.app import make_app
from canimucal.tui.messages import PlanWanted
from tests.support.tui_fakes import FakeSource, node_status, screen_text

pytestmark = pytest.mark.asyncio


class _FixedSource(FakeSource):
    averaging = AveragingPolicy(fixed_s=7.0)


async def test_plan_screen_shows_the_sessions_averaging_rule(tmp_path: Path) -> None:
    for source, rule in (
        (FakeSource(tmp_path), describe_rule(AveragingPolicy())),
        (_FixedSource(tmp_path), "every position 7 s (fixed)"),
    ):
        app = make_app(source, autoconnect=False)
        async with app.run_test(size=(160, 40)) as pilot:
            app.on_plan_wanted(PlanWanted([node_status()]))
            await pilot.pause()
            text = " ".join(screen_text(app).split())
            assert f"averaging: {rule}" in text, text[:600]
