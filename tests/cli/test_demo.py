"""`canimucal demo --headless`: the whole job on the simulated IMU, compared with the truth."""

from __future__ import annotations

import json
import re
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from canimucal.io.calibration import read_calibration
from canimucal.io.grouping import position_averages
from canimucal.io.truth import load_truth
from canimucal.runtime.inputs import read_recording

Cli = Callable[[Sequence[Any]], Any]  # conftest.cli: argv -> CliRun(code, out, err)

RMS_LIMIT = 2.0
"""The rms of n ≈ 17 deviations in σ is √(χ²_n/n): rms > 2 means χ²_17 > 68, p ≈ 1e-8 (the
seed is fixed; a σ under-reported by half would fail it)."""

FAST = ("--headless", "--seconds", "5", "--time-scale", "30", "--seed", "2026")


def test_demo_writes_files_and_prints_rms_deviation(cli: Cli, tmp_path: Path) -> None:
    out = tmp_path / "demo-out"
    out.mkdir()
    (out / "calibration.json").write_text("from an earlier run\n")  # its own files: replaced
    run = cli(["demo", "--out", out, *FAST])
    assert run.code == 0, run.err
    for name in ("recording.csv", "calibration.json", "truth.json"):
        assert (out / name).stat().st_size > 0, name
    record = read_calibration(out / "calibration.json")
    truth = load_truth(out / "truth.json")
    assert record.plan == "recommended"
    assert record.device.serial == truth.serial
    assert record.readback is not None and record.readback.crc_ok
    rec = read_recording(out / "recording.csv")
    assert len(position_averages(rec)) == 8
    match = re.search(r"rms deviation ([0-9.]+) σ over (\d+) values", run.out)
    assert match, run.out
    rms, count = float(match.group(1)), int(match.group(2))
    assert count >= 17  # accel bias, full K, tilt, gyro bias
    assert 0.0 < rms < RMS_LIMIT
    assert re.search(r"^base_tilt\.alpha0 \(deg\)", run.out, re.MULTILINE)
    doc = json.loads((out / "calibration.json").read_text())
    assert doc["recording"]["file"] == "recording.csv"


def test_demo_bad_plan_is_exit_2(cli: Cli, tmp_path: Path) -> None:
    run = cli(["demo", "--out", tmp_path / "d", "--headless", "--plan", tmp_path / "absent.json"])
    assert run.code == 2
    assert run.err.startswith("error: ") and run.err.count("\n") == 1
