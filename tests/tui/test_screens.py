"""Pilot tests of every screen, with node statuses and procedure events injected (no CAN)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from canimucal.model.positions import PlannedPosition
from canimucal.procedure import events as ev
from canimucal.procedure.machine import Phase
from canimucal.runtime.session import WriteOptions
from canimucal.tui.app import CalibrationApp, make_app
from canimucal.tui.messages import EventsArrived
from canimucal.tui.modals import ConfirmWrite, ErrorModal
from canimucal.tui.screens.connection import ConnectionScreen, LinkState
from canimucal.tui.screens.plan import PlanScreen
from canimucal.tui.screens.position import PHASE_WORDS, PositionScreen, ScreenPhase, SessionState
from canimucal.tui.screens.results import ResultsScreen
from canimucal.tui.screens.verification import VerificationScreen
from tests.support.tui_fakes import FakeSource, live, node_status, screen_text, solved_event

TILTED = PlannedPosition(float(np.deg2rad(10.0)), 0.0, 0.0)
TURNED = PlannedPosition(0.0, 0.0, float(np.deg2rad(90.0)))
"""The vehicle plan's verification poses (procedure/verification.py)."""

SIZE = (80, 24)
pytestmark = pytest.mark.asyncio


def enabled(app: CalibrationApp) -> set[str]:
    """Actions whose keys the footer shows now."""
    return {b.binding.action for b in app.active_bindings.values() if b.enabled}


async def wait_for(pilot, condition, timeout_s: float = 5.0) -> None:  # type: ignore[no-untyped-def]
    for _ in range(int(timeout_s / 0.05)):
        if condition():
            return
        await pilot.pause(0.05)
    raise AssertionError("condition not met in time")


async def test_connection_screen_shows_identity_calibration_and_heartbeat(tmp_path: Path) -> None:
    app = make_app(FakeSource(tmp_path))
    async with app.run_test(size=SIZE) as pilot:
        screen = app.screen
        assert isinstance(screen, ConnectionScreen)
        await wait_for(pilot, lambda: screen.state is LinkState.CONNECTED)
        await pilot.pause()
        text = screen_text(app)
        assert "4242" in text and "none (nominal)" in text and "op 0.2 s ago" in text
        assert "found by sdo" in text
        assert "next" in enabled(app) and "connect" not in enabled(app)
        await pilot.press("enter")
        await pilot.pause()
        assert isinstance(app.screen, PlanScreen)


async def test_a_failed_connection_is_a_modal_with_a_title_never_a_traceback(
    tmp_path: Path,
) -> None:
    app = make_app(FakeSource(tmp_path, fail=True))
    async with app.run_test(size=SIZE) as pilot:
        await wait_for(pilot, lambda: isinstance(app.screen, ErrorModal))
        await pilot.pause()
        text = screen_text(app)
        assert "No device" in text and "can9" in text and "Traceback" not in text
        await pilot.press("enter")
        await pilot.pause()
        assert isinstance(app.screen, ConnectionScreen)
        assert "connect" in enabled(app) and "next" not in enabled(app)


async def test_plan_screen_shows_bounds_and_what_the_five_plan_cannot_separate(
    tmp_path: Path,
) -> None:
    app = make_app(FakeSource(tmp_path), autoconnect=False)
    async with app.run_test(size=SIZE) as pilot:
        await app.push_screen(PlanScreen([node_status()], app.plans))
        await pilot.pause()
        text = screen_text(app)
        assert "plan recommended: " in text and "accel.K[0][1]" in text
        await pilot.press("5")
        await pilot.pause()
        text = screen_text(app)
        assert "plan five: 5 positions" in text
        screen = app.screen
        assert isinstance(screen, PlanScreen)
        findings = str(screen.findings.render())  # below the table: scrolled at 80×24
        assert "poorly separable: accel.bias[2] and base_tilt.beta0 (correlation -0.99" in findings
        assert "accel.K[0][1]" not in text  # the five plan's model: diagonal K
        # the current plan's key is hidden, the others shown
        keys = {b.binding.key for b in app.active_bindings.values() if b.enabled}
        assert "5" not in keys and {"2", "r", "enter", "g"} <= keys
        await pilot.press("g")
        await pilot.pause()
        assert "gyro navigation" in screen_text(app)


async def test_the_plan_screen_offers_the_vehicle_plan_with_its_prior_at_80x24(
    tmp_path: Path,
) -> None:
    app = make_app(FakeSource(tmp_path), plan_name="vehicle", autoconnect=False)
    assert app.plan_name == "vehicle"  # `tui --plan vehicle`, `demo --plan vehicle`
    async with app.run_test(size=SIZE) as pilot:
        await app.push_screen(PlanScreen([node_status()], app.plans, plan_name=app.plan_name))
        await pilot.pause()
        text = screen_text(app)
        assert "plan vehicle: 8 positions" in text
        assert "times: position 1 120 s (it measures the noise), then at most 60 s each" in text
        # its K prior (1 %) bounds the K columns its level poses leave open: finite σ
        assert "accel.K[0][1]" in text and "undetermined" not in text
        footer = text.splitlines()[-1]
        assert "Recommended" in footer and "Quit" in footer and "Vehicle" not in footer
        await pilot.press("r")
        await pilot.pause()
        assert "plan recommended: " in screen_text(app)
        assert "v Vehicle" in screen_text(app).splitlines()[-1]  # whole, not cut at 80
        await pilot.press("v")
        await pilot.pause()
        assert "plan vehicle: " in screen_text(app)


def _instructed(index: int = 1, alpha_deg: float = 22.5) -> list[ev.Event]:
    pose = PlannedPosition(np.deg2rad(alpha_deg), 0.0, 0.0)
    words = f"tilt {alpha_deg:g}° about z (lower the +x end)"
    return [
        ev.PhaseChanged(Phase.INSTRUCT, Phase.REVIEW_POSITION),
        ev.PoseInstructed(index, 5, pose, words, 30.0),
    ]


async def test_position_screen_shows_pose_live_readout_progress_and_sparkline(
    tmp_path: Path,
) -> None:
    app = make_app(FakeSource(tmp_path), autoconnect=False)
    async with app.run_test(size=SIZE) as pilot:
        screen = PositionScreen([node_status()], None, total=5)
        await app.push_screen(screen)
        screen.post_message(EventsArrived(_instructed()))
        await pilot.pause()
        text = screen_text(app)
        assert "position 2/5" in text and "lower the +x end" in text and "alpha +22.5°" in text
        assert "+x" in text and "+z" in text  # the drawing
        assert enabled(app) >= {"confirm", "skip"} and "accept" not in enabled(app)
        spark = (0.01, -0.02, 0.03, 0.0)
        screen.post_message(
            EventsArrived(
                [
                    ev.PhaseChanged(Phase.AVERAGING, Phase.SETTLING),
                    ev.StillnessChanged(True, 2.0, 2.0),
                    ev.AveragingStarted(1, 30.0, (0.2, -0.1)),
                    live(spark=spark),
                    ev.AveragingProgressed(1, 12.0, 30.0, 18.0),
                ]
            )
        )
        await pilot.pause()
        assert screen.progress.total == 30.0 and screen.progress.progress == 12.0
        assert list(screen.spark.data or []) == list(spark)
        text = screen_text(app)
        assert "18 s left" in text and "● still" in text and "40%" in text
        assert "lost 7" in text and "-9.8000" in text and "α  +0.20°" in text
        assert enabled(app) & {"confirm", "accept", "skip"} == set() and "redo" in enabled(app)
        screen.post_message(
            EventsArrived([ev.PositionRejected(1, "motion or a disturbance on node 16", 16)])
        )
        await pilot.pause()
        assert "position 2 rejected" in screen_text(app)


async def test_a_refused_pose_is_explained(tmp_path: Path) -> None:
    app = make_app(FakeSource(tmp_path), autoconnect=False)
    async with app.run_test(size=SIZE) as pilot:
        screen = PositionScreen([node_status()], None, total=5)
        await app.push_screen(screen)
        message = "measured alpha -22.4° against target +22.5°: check the sign and size"
        refused = ev.PoseRefused(1, 16, (-22.4, 0.0), (22.5, 0.0), 44.9, 3.0, message)
        screen.post_message(EventsArrived([*_instructed(), refused]))
        await pilot.pause()
        text = screen_text(app)
        assert "pose refused (node 16)" in text and "check the" in text, text


@pytest.mark.parametrize(
    ("phase", "index", "expected"),
    [
        (Phase.WARMUP, 0, {"skip_warmup"}),
        (Phase.INSTRUCT, 0, {"confirm"}),
        (Phase.INSTRUCT, 2, {"confirm", "skip"}),
        (Phase.SETTLING, 2, {"redo", "skip"}),
        (Phase.AVERAGING, 2, {"redo"}),
        (Phase.REVIEW_POSITION, 2, {"accept", "redo"}),
        (Phase.READY_TO_SOLVE, 4, {"solve"}),
        (Phase.REVIEW, 4, set()),
        (Phase.DONE, 4, set()),
        (SessionState.STARTING, 0, set()),
        (SessionState.FAILED, 2, set()),
    ],
)
async def test_keys_appear_only_in_the_phases_that_take_them(
    tmp_path: Path, phase: ScreenPhase, index: int, expected: set[str]
) -> None:
    app = make_app(FakeSource(tmp_path), autoconnect=False)
    async with app.run_test(size=SIZE) as pilot:
        screen = PositionScreen([node_status()], None, total=5)
        await app.push_screen(screen)
        screen.index = index
        screen.phase = phase
        await pilot.pause()
        procedure_keys = {"confirm", "accept", "redo", "skip", "skip_warmup", "solve"}
        assert enabled(app) & procedure_keys == expected


async def test_every_phase_has_words_for_the_title() -> None:
    assert set(PHASE_WORDS) == set(Phase) | set(SessionState)


async def test_results_screen_shows_values_sigmas_residuals_and_asks_before_writing(
    tmp_path: Path,
) -> None:
    solved = solved_event("five")
    decisions: list[object] = []
    app = make_app(FakeSource(tmp_path), autoconnect=False)
    async with app.run_test(size=SIZE) as pilot:
        await app.push_screen(ResultsScreen(solved, [node_status()]), decisions.append)
        await pilot.pause()
        screen = app.screen
        params = screen.query_one("#params-16")
        residuals = screen.query_one("#residuals-16")
        assert params.row_count == 11  # 3 bias + 3 K + 2 tilt + 3 gyro bias
        assert residuals.row_count == 5
        row = params.get_row_at(3)  # accel.K[0][0] against the device's 1/LSB
        assert row[0] == "accel.K[0][0]" and " ± " in row[1] and row[3] == "208.838 counts/(m/s²)"
        text = screen_text(app)
        assert "worst bias σ" in text and "fit rms" in text
        key = "w" if solved.acceptable else "o"
        decision = WriteOptions(override=not solved.acceptable)
        assert ("write" in enabled(app)) is solved.acceptable
        await pilot.press(key)
        await pilot.pause()
        assert isinstance(app.screen, ConfirmWrite)
        assert "backup" in screen_text(app)
        await pilot.press("n")
        await pilot.pause()
        assert isinstance(app.screen, ResultsScreen) and decisions == []
        await pilot.press(key)
        await pilot.pause()
        await pilot.press("y")
        await pilot.pause()
        assert decisions == [decision]


async def test_the_confirmation_modal_returns_a_bool(tmp_path: Path) -> None:
    answers: list[bool | None] = []
    app = make_app(FakeSource(tmp_path), autoconnect=False)
    async with app.run_test(size=SIZE) as pilot:
        await app.push_screen(ConfirmWrite("write node 16?"), answers.append)
        await pilot.pause()
        await pilot.click("#yes")
        await pilot.pause()
        await app.push_screen(ConfirmWrite("write node 16?"), answers.append)
        await pilot.pause()
        await pilot.press("escape")
        await pilot.pause()
    assert answers == [True, False]


async def test_a_procedure_failure_is_a_modal_with_its_title(tmp_path: Path) -> None:
    app = make_app(FakeSource(tmp_path), autoconnect=False)
    async with app.run_test(size=SIZE) as pilot:
        screen = PositionScreen([node_status()], None, total=5)
        await app.push_screen(screen)
        failed = ev.ProcedureFailed("node 16 sent no samples for 5 s", "Device error")
        screen.post_message(
            EventsArrived([ev.PhaseChanged(Phase.AVERAGING, Phase.SETTLING), failed])
        )
        await pilot.pause()
        assert isinstance(app.screen, ErrorModal)
        text = screen_text(app)
        assert "Device error" in text and "no samples" in text and "Traceback" not in text
        await pilot.press("enter")
        await pilot.pause()
        assert app.screen is screen and "stopped on an error" in screen_text(app)
        assert "redo" not in enabled(app) and "quit" in enabled(app)


async def test_the_end_of_the_procedure_shows_the_level_check_and_the_verification_poses(
    tmp_path: Path,
) -> None:
    app = make_app(FakeSource(tmp_path), autoconnect=False)
    async with app.run_test(size=SIZE) as pilot:
        screen = PositionScreen([node_status()], None, total=5)
        await app.push_screen(screen)
        events: list[ev.Event] = [
            ev.LevelChecked(16, "before", 0.0412, (-0.28, 1.19), -0.00003, (-0.6, 0.16)),
            ev.RecordSaved(16, "out/calibration.json", "out/certificate.md", "out/rec.csv"),
            ev.WriteFinished(16, True, "written and verified", "out/backups/4242-x.json"),
            ev.PoseVerified(16, 0, 2, TILTED, "raise the rear wheels 10°", 0.05, 0.002, 0.8, 0.2),
            ev.PoseVerified(16, 1, 2, TURNED, "turn 90° right", 0.04, -0.001, 0.7, 0.1),
            ev.PhaseChanged(Phase.DONE, Phase.AVERAGING),
            ev.ProcedureFinished(),
        ]
        screen.post_message(EventsArrived(events))
        await pilot.pause()
        assert isinstance(app.screen, VerificationScreen)
        text = screen_text(app)
        assert "before |f|−g nominal +0.0412 → calibrated -0.0000" in text
        flat = " ".join(text.split())  # wrapped at 80 columns
        assert "verification 1/2: |f|−g nominal +5.10 → calibrated +0.20 mg" in flat
        assert "tilt error nominal 0.80° → calibrated 0.20°" in flat
        assert "pose: raise the rear wheels 10°" in flat
        assert "out/certificate.md" in text and "written and verified" in text


async def test_a_failed_write_is_shown_in_a_modal(tmp_path: Path) -> None:
    app = make_app(FakeSource(tmp_path), autoconnect=False)
    async with app.run_test(size=SIZE) as pilot:
        screen = PositionScreen([node_status()], None, total=5)
        await app.push_screen(screen)
        failed = ev.WriteFinished(16, False, "serial 1 on the device, 4242 in the file")
        screen.post_message(EventsArrived([failed]))
        await pilot.pause()
        assert isinstance(app.screen, ErrorModal)
        assert "Write failed" in screen_text(app)


async def test_the_plan_screen_says_which_limits_a_plan_cannot_meet(tmp_path: Path) -> None:
    """Issue 22: a plan whose σ is beyond a limit says so on the plan screen, before position 1.

    The two plan's scale σ (with its 0.1° tolerances) is beyond 3000 ppm; the vehicle plan's
    own limits (docs/design.md §3) are within its reach.
    """
    app = make_app(FakeSource(tmp_path), plan_name="vehicle", autoconnect=False)
    async with app.run_test(size=(80, 60)) as pilot:
        await app.push_screen(PlanScreen([node_status()], app.plans, plan_name=app.plan_name))
        await pilot.pause()
        text = screen_text(app)
        assert "acceptance: this plan can meet the limits known before the data" in text
        assert "worst bias σ ≤ 15 mg: plan predicts 13.9 mg, can meet it" in text
        assert "mounting trim (no limit): plan predicts σ 0.57° alpha" in text
        await pilot.press("2")
        await pilot.pause()
        text = screen_text(app)
        assert "acceptance: this plan CANNOT meet max_scale_sigma_ppm" in text
        assert "worst scale σ ≤ 3000 ppm: plan predicts 40054 ppm, CANNOT meet it" in text
        assert "[plan.two]" in text  # shown as text, not taken for markup
