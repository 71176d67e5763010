"""Resuming an interrupted session: the earlier positions come from its recording.

The headless demo (five positions, 3 s each at 30× real time) is interrupted after two
accepted positions as Ctrl-C would (the session is closed, the recording kept), then
``--resume DIR`` finishes it. The two earlier averages must come unchanged from the first
run, the recording must hold every position, and the read-back values agree with the truth
within 4σ (see ``tests/cli/test_demo_headless.py`` for the odds).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from canimucal.cli.main import main
from canimucal.model.vocabulary.plans import builtin_plan
from canimucal.runtime.inputs import read_recording
from canimucal.runtime.readback_check import readback_deviations
from canimucal.runtime.resume import load_resume_state
from canimucal.sim.truth import Truth
from tests.support.interrupt import assert_kept, run_interrupted

FAST = ["demo", "--headless", "--plan", "five", "--seconds", "3", "--time-scale", "30"]
SEED = ["--seed", "2031"]


def test_an_interrupted_demo_resumes_and_uses_every_position(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "demo-out"
    run_interrupted(monkeypatch, [*FAST, *SEED, "--out", str(out)], 2)
    plan = builtin_plan("five")
    first = load_resume_state(out, plan, (0x10,))
    assert first.next_index == 2 and sorted(first.averages[0x10]) == [0, 1]
    # the first position's rows of both sensors go along: the averaging rule reads both
    assert first.first_accel is not None and first.first_gyro is not None
    assert first.first_gyro.shape == first.first_accel.shape
    assert np.all(np.isfinite(first.first_gyro))
    rows_before = read_recording(out / "recording.csv").n_rows

    capsys.readouterr()
    without_plan = [a for a in FAST if a not in ("--plan", "five")]  # the header names it
    code = main([*without_plan, *SEED, "--resume", str(out), "--json", str(tmp_path / "cal.json")])
    err = capsys.readouterr().err
    assert code == 0, err
    assert f"resumed: positions 1–2 kept from {out / 'recording.csv'}" in err
    record = json.loads((out / "calibration.json").read_text())
    assert_kept(first, record, 0x10)
    rec = read_recording(out / "recording.csv")
    assert rec.n_rows > rows_before
    assert sorted(set(rec.position.tolist()) - {-1}) == [0, 1, 2, 3, 4]
    truth = Truth.from_dict(json.loads((out / "truth.json").read_text()))
    worst = max(readback_deviations(record, truth), key=lambda d: abs(d.dev_sigma))
    assert abs(worst.dev_sigma) < 4.0, worst


def test_resuming_with_another_plan_exits_2_with_a_clear_message(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "demo-out"
    run_interrupted(monkeypatch, [*FAST, *SEED, "--out", str(out)], 2)
    capsys.readouterr()
    # killed before closing: the .partial is the newer copy and is read instead
    (out / "recording.csv").rename(out / "recording.csv.partial")
    assert load_resume_state(out, builtin_plan("five")).next_index == 2
    other = [a if a != "five" else "recommended" for a in FAST]
    assert main([*other, *SEED, "--resume", str(out)]) == 2
    err = capsys.readouterr().err
    assert "a different plan?" in err and "recording.csv" in err, err
    assert main(["tui", "--sim", "--plan", "two", "--resume", str(out)]) == 2
    assert "a different plan?" in capsys.readouterr().err


def test_resuming_with_another_unit_exits_3_and_writes_nothing(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "demo-out"
    run_interrupted(monkeypatch, [*FAST, *SEED, "--out", str(out)], 2)
    capsys.readouterr()
    recording = (out / "recording.csv").read_bytes()
    # another seed draws another unit (another serial): its averages must not join these
    assert main([*FAST, "--seed", "7", "--resume", str(out)]) == 3
    err = capsys.readouterr().err
    assert "cannot resume: recording.csv was recorded from serial" in err, err
    assert "another unit" in err
    assert (out / "recording.csv").read_bytes() == recording
    assert not (out / "calibration.json").exists()
