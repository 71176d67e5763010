"""Real time: the TUI drives a five-position calibration of the simulated node over CAN.

Random truth (fixed seed), 10 s per position, the simulated clock 20× the wall clock. The
operator's keys go through Pilot (``tests/support/pilot_steps.py``); the values read back from
the device after the write must agree with the truth within 4σ each. With about 11 values
and Gaussian errors, the chance that any exceeds 4σ is 11 × 6.3e-5 ≈ 7e-4, and the seed is
fixed.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from canimucal.procedure.machine import Phase
from canimucal.runtime.readback_check import readback_deviations
from canimucal.sim.truth import Truth
from canimucal.tui.app import make_app
from canimucal.tui.screens.position import PositionScreen
from canimucal.tui.source import demo_source
from tests.support.pilot_steps import measure_positions, press, until, write_and_verify

SEED = 20261121
pytestmark = pytest.mark.asyncio


async def test_the_tui_calibrates_the_simulated_node_and_the_device_holds_the_truth(
    tmp_path: Path,
) -> None:
    truth = Truth.random(np.random.default_rng(SEED), cross_axis_max=0.0)
    source = demo_source([truth], tmp_path, time_scale=20.0, seed=SEED, seconds=10.0)
    source.verify_seconds = 5.0
    app = make_app(source, plan_name="five")
    async with app.run_test(size=(80, 24)) as pilot:
        await until(pilot, lambda: app.screen.check_action("next", ()) is True, "the node")
        await press(pilot, "enter")  # connection -> plan
        await pilot.pause()
        await press(pilot, "enter")  # plan five -> position
        screen = app.screen
        assert isinstance(screen, PositionScreen)
        await until(pilot, lambda: screen.phase is Phase.WARMUP, "warm-up")
        await press(pilot, "w")
        await measure_positions(pilot, screen, range(5))
        await write_and_verify(pilot, screen)
        assert [v.index for v in screen.verified] == [0, 1]  # two poses re-read
    record = json.loads((tmp_path / "calibration.json").read_text())
    assert record["readback"]["valid"] == 1 and record["readback"]["crc_ok"] is True
    deviations = readback_deviations(record, truth)
    names = {d.name for d in deviations}
    assert {"accel.bias[2]", "accel.K[1][1]", "base_tilt.beta0 (deg)"} <= names
    worst = max(deviations, key=lambda d: abs(d.dev_sigma))
    assert abs(worst.dev_sigma) < 4.0, worst
    assert (tmp_path / "certificate.md").exists() and (tmp_path / "recording.csv").exists()
