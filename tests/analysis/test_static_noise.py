"""One long static recording: noise terms within their intervals, drift, per-axis times."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from canimucal.analysis.static_noise import analyse_static, recording_lsb, static_rows
from canimucal.cli.main import main
from canimucal.io.grouping import position_rows
from canimucal.io.recording import Recording, recording_from_columns
from canimucal.io.recording_writer import write_recording
from canimucal.runtime.inputs import read_recording

DATA = Path(__file__).resolve().parents[3] / "shared" / "data"
HAND_HELD = (DATA / "imutk_xsens_acc.mat", DATA / "imutk_xsens_gyro.mat")

FS = 100.0
SECONDS = 300.0
ACCEL_N = np.array([2.0, 3.0, 2.5])
"""White noise density, counts·√s."""
ACCEL_Q = np.array([0.0, 1.0, 0.0])
"""Random walk, counts/√s: accel y drifts (its ADEV minimum at √3·3/1 = 5.2 s)."""
GYRO_N = np.array([1.5, 1.5, 1.5])


def _static(seed: int) -> Recording:
    rng = np.random.default_rng(seed)
    n = int(SECONDS * FS)
    t = np.arange(n) / FS
    walk = np.cumsum(rng.normal(0.0, 1.0, (n, 3)), axis=0) / np.sqrt(FS)
    accel = np.array([10.0, -20.0, 4000.0]) + rng.normal(0.0, 1.0, (n, 3)) * ACCEL_N * np.sqrt(FS)
    accel += walk * ACCEL_Q
    gyro = np.array([5.0, -3.0, 2.0]) + rng.normal(0.0, 1.0, (n, 3)) * GYRO_N * np.sqrt(FS)
    return recording_from_columns({"sample_rate_hz": FS}, t=t, accel=accel, gyro=gyro)


def test_static_record_terms_lie_within_their_intervals() -> None:
    covered = total = 0
    for seed in (1401, 1402, 1403):
        rec = _static(seed)
        rows = static_rows(rec)
        assert rows is not None and rows.size > 0.9 * SECONDS * FS
        sa = analyse_static(rec, rows, recording_lsb(rec))
        for name, n, q in (("accel", ACCEL_N, ACCEL_Q), ("gyro", GYRO_N, np.zeros(3))):
            ci = sa.sensors[name].intervals
            for truth, band in ((n, ci.white_noise_density), (q, ci.random_walk)):
                covered += int(np.sum((band[:, 0] <= truth) & (truth <= band[:, 1])))
                total += 3
        # the drifting accel y is named, the white gyro is not
        assert sa.sensors["accel"].drift_named
        assert not sa.sensors["gyro"].drift_named
        q_hat = sa.sensors["accel"].drift.random_walk[1]
        assert 0.5 < q_hat < 2.0
        # accel y's optimum is the one inside the averaging range: it limits the time
        assert sa.choice.limiting_axis == "accel.y"
        assert sa.sensors["accel"].optima_s[1] == pytest.approx(np.sqrt(3) * 3.0, rel=0.5)
        assert sa.choice.seconds < 60.0
    # 36 nominal 95 % intervals: fewer than 31 covering has binomial probability < 1 %
    assert covered >= 31, (covered, total)


def test_analyze_takes_one_static_file(tmp_path: Path, capsys: Any) -> None:
    path = write_recording(tmp_path / "static.csv", _static(1404), overwrite=False)
    assert main(["analyze", str(path), "--json", "-"]) == 0
    doc = json.loads(capsys.readouterr().out)
    noise = doc["noise"]
    assert noise["limiting_axis"] == "accel.y"
    assert set(noise["best_averaging_s_per_axis"]) == {"accel", "gyro"}
    assert len(noise["best_averaging_s_per_axis"]["gyro"]) == 3
    white = noise["sensors"]["accel"]["white_noise_density_counts"]
    assert all(w["ci95"][0] <= w["value"] <= w["ci95"][1] for w in white)
    assert [f["sensor"] for f in doc["findings"] if f["effect"] == "bias_drift"] == ["accel"]
    # a truth file is refused before anything is written
    out = tmp_path / "truth.json"
    assert main(["analyze", str(path), "--truth-out", str(out)]) == 2
    assert not out.exists()


def test_allan_takes_one_static_file(tmp_path: Path, capsys: Any) -> None:
    path = write_recording(tmp_path / "static.csv", _static(1405), overwrite=False)
    assert main(["allan", str(path), "--json", "-"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["limiting_axis"] == "accel.y"
    assert doc["best_averaging_s"] < 60.0
    q = doc["sensors"]["accel"]["random_walk_counts_per_sqrt_s"][1]
    assert q["ci95"][0] <= 1.0 <= q["ci95"][1]
    assert doc["sensors"]["accel"]["drift"]["named"]


def test_several_poses_are_not_one_static_record() -> None:
    if not all(p.exists() for p in HAND_HELD):
        pytest.skip(f"imu_tk data absent ({DATA})")
    rec = read_recording(HAND_HELD[0], second=HAND_HELD[1])
    assert static_rows(rec) is None


def test_real_static_stretch_gives_per_axis_times() -> None:
    """The Xsens file's still start (about 50 s): terms with intervals, a time per axis."""
    if not all(p.exists() for p in HAND_HELD):
        pytest.skip(f"imu_tk data absent ({DATA})")
    rec = read_recording(HAND_HELD[0], second=HAND_HELD[1])
    rows = max(position_rows(rec)[0], key=len)
    sa = analyse_static(rec, rows, recording_lsb(rec), where="the still start")
    for name, s in sa.sensors.items():
        ci = s.intervals.white_noise_density
        assert np.all((0 < ci[:, 0]) & (ci[:, 1] < 1.2 * ci[:, 0]))  # 50 s: N within ±10 %
        n = s.terms.white_noise_density
        for axis in np.flatnonzero((n < ci[:, 0]) | (n > ci[:, 1])):
            # the Xsens output is filtered: where the fit misses its interval (or the ADEV
            # points admit no three-term curve at all), the report says the model misfits
            assert any(w.startswith(f"{name} {'xyz'[axis]}: the three-term") for w in sa.warnings)
    assert sa.choice.limiting_axis.split(".")[0] in {"accel", "gyro"}
    assert 15.0 <= sa.choice.seconds <= 120.0


def test_the_public_api_analyses_a_static_file_and_points_each_kind_to_its_function() -> None:
    import canimucal as cm

    rec = _static(1406)
    sa = cm.analyze_static(rec)
    assert isinstance(sa, cm.StaticAnalysis)
    assert sa.choice.limiting_axis == "accel.y" and sa.sensors["accel"].drift_named
    with pytest.raises(cm.InputError, match="use canimucal.analyze_static"):
        cm.analyze(rec)
    if all(p.exists() for p in HAND_HELD):  # several poses: the other way round
        poses = read_recording(HAND_HELD[0], second=HAND_HELD[1])
        with pytest.raises(cm.InputError, match="several poses.*use canimucal.analyze"):
            cm.analyze_static(poses)
