"""Safe exits at 80×24: q asks during a session and says what is kept; Ctrl+C and interrupted
sessions exit 130; skipping a position asks; a session interrupted after its write records
the verification as not done.

The screens get their procedure events injected (no CAN), except the last test, which runs a
two-position calibration of the simulated node and quits at the verification pose.
"""

from __future__ import annotations

import json
import threading
from pathlib import Path

import numpy as np
import pytest

from canimucal.io.calibration import Calibration
from canimucal.procedure import events as ev
from canimucal.procedure.machine import Phase
from canimucal.runtime.session import SessionCommand
from canimucal.signals import EXIT_INTERRUPTED
from canimucal.sim.truth import Truth
from canimucal.tui.app import EXIT_OK, CalibrationApp, make_app
from canimucal.tui.messages import EventsArrived
from canimucal.tui.modals import ConfirmQuit, ConfirmSkip
from canimucal.tui.runner import Command
from canimucal.tui.screens.connection import ConnectionScreen
from canimucal.tui.screens.position import PositionScreen
from canimucal.tui.screens.verification import VerificationScreen
from canimucal.tui.source import demo_source
from tests.support.pilot_steps import measure_positions, press, until, write
from tests.support.tui_fakes import FakeSource, node_status, screen_text

SIZE = (80, 24)
SEED = 20261124


class RecordingRunner:
    """Stands in for the session runner: keeps what the screen sends."""

    def __init__(self) -> None:
        self.sent: list[Command] = []

    def send(self, command: Command) -> None:
        self.sent.append(command)

    def stop(self) -> None:
        pass


def lines_fit(app: CalibrationApp) -> bool:
    lines = screen_text(app).splitlines()
    return len(lines) <= SIZE[1] and all(len(line) <= SIZE[0] for line in lines)


async def session_at(app: CalibrationApp, pilot, tmp_path: Path, *events: ev.Event):  # type: ignore[no-untyped-def]
    """Push a position screen (no CAN) and show it ``events``."""
    screen = PositionScreen([node_status()], None, total=5, out_dir=tmp_path)
    await app.push_screen(screen)
    screen.post_message(EventsArrived(list(events)))
    await pilot.pause()
    return screen


@pytest.mark.asyncio
async def test_q_quits_at_once_with_0_when_no_session_is_in_progress(tmp_path: Path) -> None:
    app = make_app(FakeSource(tmp_path))
    async with app.run_test(size=SIZE) as pilot:
        assert isinstance(app.screen, ConnectionScreen)
        await pilot.press("q")
        await pilot.pause()
    assert app.return_code == EXIT_OK


@pytest.mark.asyncio
async def test_ctrl_c_interrupts_at_once_with_130(tmp_path: Path) -> None:
    app = make_app(FakeSource(tmp_path), autoconnect=False)
    async with app.run_test(size=SIZE) as pilot:
        await session_at(app, pilot, tmp_path, ev.PhaseChanged(Phase.AVERAGING, Phase.SETTLING))
        await pilot.press("ctrl+c")
        await pilot.pause()
        assert not isinstance(app.screen, ConfirmQuit)
    assert app.return_code == EXIT_INTERRUPTED


@pytest.mark.asyncio
async def test_q_during_a_session_asks_says_what_is_kept_and_exits_130(tmp_path: Path) -> None:
    app = make_app(FakeSource(tmp_path), autoconnect=False)
    async with app.run_test(size=SIZE) as pilot:
        screen = await session_at(
            app, pilot, tmp_path, ev.PhaseChanged(Phase.AVERAGING, Phase.SETTLING)
        )
        await pilot.press("q")
        await pilot.pause()
        question = app.screen
        assert isinstance(question, ConfirmQuit)
        assert "Nothing was written to the device" in question.text
        assert "recording so far" in question.text and f"--resume {tmp_path}" in question.text
        shown = screen_text(app)  # all of it, even with a long folder name
        assert "Quit the session in progress?" in shown and "accepted position." in shown
        assert lines_fit(app)
        await pilot.press("n")  # stay: the session goes on
        await pilot.pause()
        assert app.screen is screen and app.return_code is None
        await pilot.press("q")
        await pilot.pause()
        await pilot.press("y")
        await pilot.pause()
    assert app.return_code == EXIT_INTERRUPTED


@pytest.mark.asyncio
async def test_quitting_after_the_write_says_the_verification_is_not_done(tmp_path: Path) -> None:
    app = make_app(FakeSource(tmp_path), autoconnect=False)
    async with app.run_test(size=SIZE) as pilot:
        await session_at(
            app,
            pilot,
            tmp_path,
            ev.RecordSaved(16, "out/calibration.json", "out/certificate.md", "out/rec.csv"),
            ev.PhaseChanged(Phase.WRITING, Phase.REVIEW),
            ev.WriteFinished(16, True, "written and verified", "out/backups/4242-x.json"),
            ev.PhaseChanged(Phase.INSTRUCT, Phase.WRITING),
        )
        await pilot.press("q")
        await pilot.pause()
        question = app.screen
        assert isinstance(question, ConfirmQuit)
        assert "Node 16 keeps the new calibration" in question.text
        assert "verification poses are NOT re-read" in question.text
        assert "record it as not done." in screen_text(app)
        assert lines_fit(app)
        await pilot.press("y")
        await pilot.pause()
    assert app.return_code == EXIT_INTERRUPTED


@pytest.mark.asyncio
async def test_q_after_the_procedure_ended_quits_with_0(tmp_path: Path) -> None:
    app = make_app(FakeSource(tmp_path), autoconnect=False)
    async with app.run_test(size=SIZE) as pilot:
        await session_at(
            app,
            pilot,
            tmp_path,
            ev.PhaseChanged(Phase.DONE, Phase.AVERAGING),
            ev.ProcedureFinished(),
        )
        assert isinstance(app.screen, VerificationScreen)
        await pilot.press("q")
        await pilot.pause()
    assert app.return_code == EXIT_OK


@pytest.mark.asyncio
async def test_skip_asks_and_sends_only_on_yes(tmp_path: Path) -> None:
    app = make_app(FakeSource(tmp_path), autoconnect=False)
    async with app.run_test(size=SIZE) as pilot:
        screen = await session_at(app, pilot, tmp_path)
        runner = RecordingRunner()
        screen.runner = runner  # type: ignore[assignment]
        screen.index, screen.phase = 2, Phase.INSTRUCT
        await pilot.pause()
        await pilot.press("s")
        await pilot.pause()
        question = app.screen
        assert isinstance(question, ConfirmSkip)
        assert "Position 3/5 is left out of the fit" in question.text
        assert "held at nominal." in screen_text(app)
        assert lines_fit(app)
        await pilot.press("n")
        await pilot.pause()
        assert app.screen is screen and runner.sent == []
        await pilot.press("s")
        await pilot.pause()
        await pilot.press("y")
        await pilot.pause()
        assert app.screen is screen and runner.sent == [SessionCommand.SKIP]


@pytest.mark.asyncio
async def test_a_session_quit_after_its_write_records_the_verification_as_not_done(
    tmp_path: Path,
) -> None:
    truth = Truth.random(np.random.default_rng(SEED), cross_axis_max=0.0)
    source = demo_source([truth], tmp_path, time_scale=20.0, seed=SEED, seconds=5.0)
    app = make_app(source, plan_name="two")
    async with app.run_test(size=SIZE) as pilot:
        await until(pilot, lambda: app.screen.check_action("next", ()) is True, "the node")
        await press(pilot, "enter")  # connection -> plan
        await pilot.pause()
        await press(pilot, "enter")  # plan two -> position
        screen = app.screen
        assert isinstance(screen, PositionScreen)
        await until(pilot, lambda: screen.phase is Phase.WARMUP, "warm-up")
        await press(pilot, "w")
        await measure_positions(pilot, screen, range(2))
        await write(pilot, screen)  # written; the level pose of the verification is asked for
        await press(pilot, "q")
        await until(pilot, lambda: isinstance(app.screen, ConfirmQuit), "the quit question")
        await press(pilot, "y")
    assert app.return_code == EXIT_INTERRUPTED
    record = Calibration.from_json(tmp_path / "calibration.json")
    assert record.readback is not None and record.readback.valid == 1
    assert record.verification is not None
    assert (record.verification.done, record.verification.passed) == (False, False)
    verification = json.loads((tmp_path / "calibration.json").read_text())["verification"]
    assert (verification["passed"], verification["done"], verification["written"]) == (
        False,
        False,
        True,
    )
    certificate = (tmp_path / "certificate.md").read_text()
    assert "## Verification: NOT DONE" in certificate
    assert "after write (re-read)" not in certificate


class SlowWriteRunner:
    """A runner busy writing: its loop ends ``delay_s`` after it is asked to stop."""

    def __init__(self, delay_s: float) -> None:
        self.phase = Phase.WRITING
        self.finished = threading.Event()
        self.delay_s = delay_s

    def stop(self) -> None:
        threading.Timer(self.delay_s, self.finished.set).start()


def test_quitting_during_a_write_waits_for_it_before_closing_the_bus(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr("canimucal.tui.app.RUNNER_STOP_TIMEOUT_S", 0.05)
    source = FakeSource(tmp_path)
    finished_at_close: list[bool] = []
    monkeypatch.setattr(source, "close", lambda: finished_at_close.append(runner.finished.is_set()))
    app = make_app(source)
    runner = SlowWriteRunner(0.3)
    app.runner = runner  # type: ignore[assignment]
    app.stop_session()
    assert finished_at_close == [True]
