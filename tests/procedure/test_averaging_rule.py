"""The averaging-time rule: per-axis optima of the limiting sensor, one number everywhere."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from canimucal.cli.main import main
from canimucal.io.recording import read_recording, recording_from_columns
from canimucal.io.recording_writer import write_recording
from canimucal.model.plan import TWO
from canimucal.procedure import events as ev
from canimucal.procedure.averaging import AveragingPolicy, choose_time, noise_choice
from canimucal.procedure.config import ResumeState
from canimucal.sim.truth import Truth
from tests.support.procedure_bench import Bench, of

FS = 100.0


def _rows(seed: int, walk: list[float], seconds: float = 120.0) -> np.ndarray:
    """White noise 3 counts/sample with a random walk per axis (counts/√s)."""
    rng = np.random.default_rng(seed)
    n = int(seconds * FS)
    steps = rng.normal(0.0, 1.0, (n, 3)) * np.array(walk) / np.sqrt(FS)
    return rng.normal(0.0, 3.0, (n, 3)) + np.cumsum(steps, axis=0)


def test_one_drifting_axis_sets_the_time_and_is_named() -> None:
    # z walks (τ* = √3·0.3/0.02 ≈ 26 s); x and y are white: the old rule took 120 s
    event = choose_time(AveragingPolicy(), [_rows(1, [0.0, 0.0, 0.02])], FS)
    assert event.source == "noise"
    assert event.limiting_axis == "accel.z"
    assert len(event.optima_s) == 3 and event.optima_s[2] < 60.0
    assert min(event.optima_s[:2]) > 2 * event.optima_s[2]
    assert event.seconds < 120.0
    text = event.describe()
    assert "per-axis optima x " in text and "limiting axis accel.z" in text


def test_the_rule_is_one_function_of_the_samples() -> None:
    rows = _rows(2, [0.0, 0.03, 0.0])
    choice = noise_choice({"accel": rows}, FS, (15.0, 120.0))
    assert choice is not None
    event = choose_time(AveragingPolicy(), [rows[:6000], rows[6000:]], FS)
    assert event.seconds == choice[0].seconds
    assert event.limiting_axis == choice[0].limiting_axis == "accel.y"


def test_session_and_resume_average_the_later_positions_alike() -> None:
    truth = Truth.random(
        np.random.default_rng(5), cross_axis_max=0.0, accel={"random_walk": [0.0, 0.0, 0.05]}
    )
    bench = Bench([truth], TWO, averaging=AveragingPolicy())
    bench.position()
    node = bench.node_ids[0]
    attempt = bench.proc.tracks[node].attempt
    assert attempt is not None
    samples = np.concatenate(attempt.accel)
    events = bench.do("accept")
    chosen = of(events, ev.AveragingTimeChosen)[0]
    assert chosen.source == "noise" and chosen.limiting_axis.startswith("accel.")
    assert bench.proc.seconds_for(1) == chosen.seconds
    average = bench.proc.accepted[node][0]
    state = ResumeState({node: {0: average}}, 1, first_accel=samples)
    resumed = Bench([truth], TWO, averaging=AveragingPolicy(), resume_from=state)
    assert resumed.proc.seconds_for(1) == chosen.seconds
    assert resumed.proc.resumed_time is not None
    assert resumed.proc.resumed_time.limiting_axis == chosen.limiting_axis
    # a user's time still overrides, on resume too
    fixed = Bench([truth], TWO, averaging=AveragingPolicy(user_s=20.0), resume_from=state)
    assert fixed.proc.seconds_for(1) == 20.0


def test_plan_prints_the_rule_per_axis_from_a_still_recording(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    accel = _rows(3, [0.0, 0.0, 0.04]) + np.array([0.0, 0.0, 4000.0])
    t = np.arange(accel.shape[0]) / FS
    rec = recording_from_columns({"sample_rate_hz": FS}, t=t, accel=accel)
    path = write_recording(tmp_path / "still.csv", rec, overwrite=False)
    assert main(["plan", "--plan", "two", "--noise", str(path), "--json", "-"]) == 0
    doc = json.loads(capsys.readouterr().out)["averaging"]
    session = choose_time(AveragingPolicy(), [read_recording(path).accel], FS)
    assert doc["seconds"] == session.seconds and doc["limiting_axis"] == "accel.z"
    assert doc["optima_s"]["accel"] == list(session.optima_s)
    assert main(["plan", "--plan", "two"]) == 0
    out = capsys.readouterr().out
    assert "averaging: first position 120 s; then" in out
    block = out[out.index("averaging: ") :].splitlines()
    assert max(len(line) for line in block) <= 80
