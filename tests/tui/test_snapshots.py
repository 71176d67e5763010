"""Snapshot tests (pytest-textual-snapshot) of the static states of each screen at 80×24.

Regenerate after an intended change with ``pytest tests/tui/test_snapshots.py
--snapshot-update`` and look at the SVGs under ``__snapshots__``. Only static states: no
session runs (statuses and events are injected; the heartbeat of the fake source is fixed).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from canimucal.model.positions import PlannedPosition
from canimucal.procedure import events as ev
from canimucal.procedure.events import Phase
from canimucal.tui.app import make_app
from canimucal.tui.messages import EventsArrived
from canimucal.tui.modals import ConfirmWrite, ErrorModal
from canimucal.tui.screens.connection import ConnectionScreen
from canimucal.tui.screens.plan import PlanScreen
from canimucal.tui.screens.position import PositionScreen
from canimucal.tui.screens.results import ResultsScreen
from tests.support.tui_fakes import FakeSource, live, node_status, solved_event

TILTED = PlannedPosition(float(np.deg2rad(10.0)), 0.0, 0.0)
TURNED = PlannedPosition(0.0, 0.0, float(np.deg2rad(90.0)))
"""The vehicle plan's verification poses (procedure/verification.py)."""

SIZE = (80, 24)


def _app(tmp_path: Path) -> Any:
    return make_app(FakeSource(tmp_path), autoconnect=False)


def test_connection_screen(snap_compare: Any, tmp_path: Path) -> None:
    async def run_before(pilot: Any) -> None:
        screen = pilot.app.screen
        assert isinstance(screen, ConnectionScreen)
        screen.show_nodes([node_status(0x10, 4242), node_status(0x11, 4243)])
        await pilot.pause()

    assert snap_compare(_app(tmp_path), terminal_size=SIZE, run_before=run_before)


def test_plan_screen_five(snap_compare: Any, tmp_path: Path) -> None:
    async def run_before(pilot: Any) -> None:
        await pilot.app.push_screen(PlanScreen([node_status()], pilot.app.plans))
        await pilot.press("5")

    assert snap_compare(_app(tmp_path), terminal_size=SIZE, run_before=run_before)


def test_position_screen_averaging(snap_compare: Any, tmp_path: Path) -> None:
    async def run_before(pilot: Any) -> None:
        screen = PositionScreen([node_status()], None, total=5)
        await pilot.app.push_screen(screen)
        pose = PlannedPosition(np.deg2rad(45.0), np.deg2rad(2.5), 0.0)
        words = "tilt 45° about z (lower the +x end), then tilt 2.5° about the new x"
        spark = tuple(0.01 * np.sin(np.arange(50) / 3.0))
        screen.post_message(
            EventsArrived(
                [
                    ev.PoseInstructed(3, 5, pose, words, 30.0),
                    ev.PhaseChanged(Phase.AVERAGING, Phase.SETTLING),
                    ev.StillnessChanged(True, 2.0, 2.0),
                    ev.AveragingStarted(3, 30.0, (0.2, -0.1)),
                    live(spark=spark),
                    ev.AveragingProgressed(3, 12.0, 30.0, 18.0),
                ]
            )
        )
        await pilot.pause()

    assert snap_compare(_app(tmp_path), terminal_size=SIZE, run_before=run_before)


def test_results_screen(snap_compare: Any, tmp_path: Path) -> None:
    async def run_before(pilot: Any) -> None:
        await pilot.app.push_screen(ResultsScreen(solved_event("five"), [node_status()]))
        await pilot.pause()

    assert snap_compare(_app(tmp_path), terminal_size=SIZE, run_before=run_before)


def test_write_confirmation(snap_compare: Any, tmp_path: Path) -> None:
    async def run_before(pilot: Any) -> None:
        await pilot.app.push_screen(ResultsScreen(solved_event("five"), [node_status()]))
        await pilot.app.push_screen(ConfirmWrite("Write the new calibration to node 16."))
        await pilot.pause()

    assert snap_compare(_app(tmp_path), terminal_size=SIZE, run_before=run_before)


def test_error_modal(snap_compare: Any, tmp_path: Path) -> None:
    async def run_before(pilot: Any) -> None:
        message = "node 16 sent no samples for 5 s; what was recorded is kept"
        await pilot.app.push_screen(ErrorModal("Device error", message))
        await pilot.pause()

    assert snap_compare(_app(tmp_path), terminal_size=SIZE, run_before=run_before)


def test_verification_screen(snap_compare: Any, tmp_path: Path) -> None:
    async def run_before(pilot: Any) -> None:
        screen = PositionScreen([node_status()], None, total=5)
        await pilot.app.push_screen(screen)
        events: list[ev.Event] = [
            ev.LevelChecked(16, "before", 0.0412, (-0.28, 1.19), -0.00003, (-0.6, 0.16)),
            ev.RecordSaved(16, "out/calibration.json", "out/certificate.md", "out/rec.csv"),
            ev.WriteFinished(16, True, "written and verified", "out/backups/4242-x.json"),
            ev.PoseVerified(16, 0, 2, TILTED, "raise the rear wheels 10°", 0.05, 0.002, 0.8, 0.2),
            ev.PoseVerified(16, 1, 2, TURNED, "turn 90° right", 0.04, -0.001, 0.7, 0.1),
            ev.ProcedureFinished(),
        ]
        screen.post_message(EventsArrived(events))
        await pilot.pause()

    assert snap_compare(_app(tmp_path), terminal_size=SIZE, run_before=run_before)
