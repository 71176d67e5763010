"""Real time: the TUI drives a five-position calibration of the simulated node over CAN.

Random truth (fixed seed), 10 s per position, the simulated clock 20× the wall clock. The
operator's keys go through Pilot; the values read back from the device after the write must
agree with the truth within 4σ each. Keys are posted with ``App.simulate_key`` and followed by
short pauses: ``Pilot.press`` waits for an idle app, which a live session never is (about
2 s a key). With about 11 values and Gaussian errors, the chance
that any exceeds 4σ is 11 × 6.3e-5 ≈ 7e-4, and the seed is fixed.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from canimucal.procedure.demo_rig import readback_deviations
from canimucal.sim.truth import Truth
from canimucal.tui.app import make_app
from canimucal.tui.modals import ConfirmWrite
from canimucal.tui.position import PositionScreen
from canimucal.tui.results import ResultsScreen
from canimucal.tui.source import DemoSource
from canimucal.tui.verification import VerificationScreen

SEED = 20261121
pytestmark = pytest.mark.asyncio


async def _until(pilot, condition, what: str, timeout_s: float = 30.0) -> None:  # type: ignore[no-untyped-def]
    for _ in range(int(timeout_s / 0.05)):
        if condition():
            return
        await pilot.pause(0.05)
    raise AssertionError(f"timed out waiting for {what}")


async def _press(pilot, key: str) -> None:  # type: ignore[no-untyped-def]
    pilot.app.simulate_key(key)
    await pilot.pause(0.05)


async def test_the_tui_calibrates_the_simulated_node_and_the_device_holds_the_truth(
    tmp_path: Path,
) -> None:
    truth = Truth.random(np.random.default_rng(SEED), cross_axis_max=0.0)
    source = DemoSource([truth], tmp_path, time_scale=20.0, seed=SEED, seconds=10.0)
    source.verify_seconds = 5.0
    app = make_app(source, plan_name="five")
    async with app.run_test(size=(80, 24)) as pilot:
        await _until(pilot, lambda: app.screen.check_action("next", ()) is True, "the node")
        await _press(pilot, "enter")  # connection -> plan
        await pilot.pause()
        await _press(pilot, "enter")  # plan five -> position
        screen = app.screen
        assert isinstance(screen, PositionScreen)
        await _until(pilot, lambda: screen.phase == "warmup", "warm-up")
        await _press(pilot, "w")
        for index in range(5):
            await _until(pilot, lambda: screen.phase == "instruct", f"pose {index + 1}")
            assert screen.index == index
            await _press(pilot, "enter")
            await _until(pilot, lambda: screen.phase == "review_position", f"average {index}")
            await _press(pilot, "a")
        await _until(pilot, lambda: screen.phase == "ready_to_solve", "all positions")
        await _press(pilot, "v")
        await _until(pilot, lambda: isinstance(app.screen, ResultsScreen), "the results")
        results = app.screen
        assert isinstance(results, ResultsScreen)
        await _press(pilot, "w" if results.solved.acceptable else "o")
        await _until(pilot, lambda: isinstance(app.screen, ConfirmWrite), "the confirmation")
        await _press(pilot, "y")
        await _until(
            pilot, lambda: screen.verification and screen.phase == "instruct", "verification"
        )
        await _press(pilot, "enter")
        await _until(pilot, lambda: isinstance(app.screen, VerificationScreen), "the end")
        assert any(c.stage == "after" for c in screen.level_checks)
    record = json.loads((tmp_path / "calibration.json").read_text())
    assert record["readback"]["valid"] == 1 and record["readback"]["crc_ok"] is True
    deviations = readback_deviations(record, truth)
    names = {d.name for d in deviations}
    assert {"accel.bias[2]", "accel.K[1][1]", "base_tilt.beta0 (deg)"} <= names
    worst = max(deviations, key=lambda d: abs(d.dev_sigma))
    assert abs(worst.dev_sigma) < 4.0, worst
    assert (tmp_path / "certificate.md").exists() and (tmp_path / "recording.csv").exists()
