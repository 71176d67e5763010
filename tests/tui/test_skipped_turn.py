"""Real time: a turn about the vertical the unit never made is refused in the TUI.

The demo's simulated unit is left where it stands (level, psi 90°) when the recommended plan
asks for its first 90° turn about the vertical on the level stand (pose 4 to pose 5). The
accelerometer cannot see that; the gyro can: the position screen tells the operator the
integrated angle and the pose is not averaged. Placed as asked, the next attempt is
averaged.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from canimucal.model.positions import Pose
from canimucal.procedure import events as ev
from canimucal.procedure.machine import Phase
from canimucal.runtime.session import Session
from canimucal.sim.truth import Truth
from canimucal.tui.app import make_app
from canimucal.tui.screens.position import PositionScreen
from canimucal.tui.source import demo_source
from tests.support.pilot_steps import press, until

SEED = 20261124
pytestmark = pytest.mark.asyncio


async def test_the_tui_refuses_a_turn_about_the_vertical_that_was_not_made(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    placed = Session._placed
    skipped: list[Pose] = []

    def lazy_operator(self: Session, target: Pose) -> tuple[float, float, float]:
        level = target.alpha == 0.0 and target.beta == 0.0
        if level and np.isclose(target.psi, np.pi) and not skipped:  # the level 90° → 180°
            skipped.append(target)
            return 0.0, 0.0, float(np.deg2rad(90.0))
        return placed(self, target)

    monkeypatch.setattr(Session, "_placed", lazy_operator)
    truth = Truth.random(np.random.default_rng(SEED), cross_axis_max=0.01)
    source = demo_source([truth], tmp_path, time_scale=20.0, seed=SEED, seconds=3.0)
    app = make_app(source, plan_name="recommended")
    async with app.run_test(size=(100, 30)) as pilot:
        await until(pilot, lambda: app.screen.check_action("next", ()) is True, "the node")
        await press(pilot, "enter")  # connection -> plan
        await pilot.pause()
        await press(pilot, "enter")  # plan -> position
        screen = app.screen
        assert isinstance(screen, PositionScreen)
        shown: list[ev.Event] = []
        show = screen.show

        def keep(event: ev.Event) -> None:
            shown.append(event)
            show(event)

        monkeypatch.setattr(screen, "show", keep)
        await until(pilot, lambda: screen.phase is Phase.WARMUP, "warm-up")
        await press(pilot, "w")
        for index in range(4):  # level psi 0, tilted psi 0 and 90, level psi 90: as asked
            await until(
                pilot,
                lambda i=index: screen.phase is Phase.INSTRUCT and screen.index == i,
                f"pose {index + 1}",
            )
            await press(pilot, "enter")
            await until(pilot, lambda: screen.phase is Phase.REVIEW_POSITION, "the average")
            await press(pilot, "a")
        await until(pilot, lambda: screen.phase is Phase.INSTRUCT and screen.index == 4, "pose 5")
        await press(pilot, "enter")  # the unit was not turned
        await until(pilot, lambda: any(isinstance(e, ev.MoveRefused) for e in shown), "refusal")
        refused = next(e for e in shown if isinstance(e, ev.MoveRefused))
        assert skipped and np.rad2deg(skipped[0].psi) == pytest.approx(180.0)
        assert "the turn was not made" in refused.message and "90°" in refused.message
        await until(pilot, lambda: screen.phase is Phase.INSTRUCT, "the pose asked again")
        notice = str(screen.notice.render())
        assert "pose refused" in notice and "the turn was not made" in notice, notice
        assert not any(isinstance(e, ev.AveragingStarted) and e.index == 4 for e in shown)
        await press(pilot, "enter")  # now turned as asked
        await until(pilot, lambda: screen.phase is Phase.REVIEW_POSITION, "the turned average")
        assert screen.index == 4
