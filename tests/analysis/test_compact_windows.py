"""`analyze` of a long recording holds no copy of its samples (issue 23).

The session's windows are views of the recording's compact (float32) columns, converted to
float64 one window at a time inside each reduction; the figures are those of the same
recording read with float64 columns, to the last bit. The whole-file checks the analysis
and the trial detection make (whole counts, the largest count, pauses in ``t``) read their
column in chunks and give the same answers at any chunk size.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

import canimucal.analysis.report as report_module
import canimucal.io.grouping as grouping_module
from canimucal.analysis.drift import allan_walk_upper, drift_test
from canimucal.analysis.motion import positions_that_moved
from canimucal.analysis.report import analyse_recording, analysis_document, extended_truth
from canimucal.analysis.session import session_from_recording
from canimucal.analysis.simulated import simulate_plan_recording
from canimucal.io.grouping import detect_trials
from canimucal.io.recording import Recording, read_recording_csv, recording_from_columns
from canimucal.io.recording_writer import write_recording
from canimucal.model.vocabulary.plans import builtin_plan
from canimucal.sim.truth import Truth

COMPACT = ("counter", "alpha_deg", "beta_deg", "psi_deg", "accel", "gyro", "temp_c")


def _file_recording(tmp_path: Path, seconds: float = 30.0) -> Recording:
    """A simulated session written and read back: whole counts, so float32 columns."""
    truth = Truth.random(np.random.default_rng(23), cross_axis_max=0.0)
    plan = builtin_plan("recommended").with_total_seconds(8 * seconds)
    rec = simulate_plan_recording(truth, plan, seed=23)
    rec = dataclasses.replace(rec, temp_c=np.round(rec.temp_c))  # whole °C: float32 too
    return read_recording_csv(write_recording(tmp_path / "r.csv", rec, overwrite=False))


def _widened(rec: Recording) -> Recording:
    """The same recording with every compact column as float64 (the old windows' type)."""
    wide = {name: np.asarray(getattr(rec, name), dtype=np.float64) for name in COMPACT}
    return dataclasses.replace(rec, **wide)


def _analysis_json(rec: Recording) -> dict[str, object]:
    a = analyse_recording(rec, g=9.81, latitude=np.deg2rad(50.0))
    return {"document": analysis_document(a), "truth": extended_truth(a)}


def _same(a: object, b: object) -> bool:
    """Equal to the last bit, arrays and dataclasses of arrays included."""
    if dataclasses.is_dataclass(a) and dataclasses.is_dataclass(b):
        return all(_same(getattr(a, f.name), getattr(b, f.name)) for f in dataclasses.fields(a))
    if isinstance(a, np.ndarray | float) or isinstance(b, np.ndarray | float):
        return bool(np.array_equal(a, b, equal_nan=True))  # type: ignore[arg-type]
    if isinstance(a, tuple | list) and isinstance(b, tuple | list):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b, strict=True))
    return a == b


def test_windows_are_views_and_give_the_float64_figures(tmp_path: Path) -> None:
    # 120 s positions: an axis's sum (24 000 samples of ~2000 counts) is past float32's
    # 2**24, where a float32 reduction would round
    rec = _file_recording(tmp_path, seconds=120.0)
    assert all(getattr(rec, name).dtype == np.float32 for name in COMPACT)
    session = session_from_recording(rec, g=9.81, latitude=np.deg2rad(50.0))
    assert len(session.windows) == 8
    for w in session.windows:
        assert w.accel.dtype == np.float32 and np.shares_memory(w.accel, rec.accel)
        assert w.gyro is not None and np.shares_memory(w.gyro, rec.gyro)
        assert w.temp_c is not None and np.shares_memory(w.temp_c, rec.temp_c)
        assert np.shares_memory(w.t_s, rec.t)
    wide = _widened(rec)
    wide_session = session_from_recording(wide, g=9.81, latitude=np.deg2rad(50.0))
    assert _same(session.averages, wide_session.averages)
    assert _same(session.settling["accel"], wide_session.settling["accel"])
    assert _same(session.settling["gyro"], wide_session.settling["gyro"])
    for sensor in ("accel", "gyro"):
        narrow = [(w.t_s, getattr(w, sensor)) for w in session.windows]
        wide_windows = [(w.t_s, getattr(w, sensor)) for w in wide_session.windows]
        assert _same(drift_test(narrow), drift_test(wide_windows))
        assert _same(allan_walk_upper(narrow), allan_walk_upper(wide_windows))
        assert _same(positions_that_moved(narrow, 0.5), positions_that_moved(wide_windows, 0.5))
    assert _analysis_json(rec) == _analysis_json(wide)


def test_a_position_with_lost_rows_is_a_copy_with_the_same_figures(tmp_path: Path) -> None:
    rec = _file_recording(tmp_path)
    accel = np.array(rec.accel)
    rows = np.flatnonzero(rec.position == 3)
    accel[rows[rows.size // 2 :: 97]] = np.nan  # lost accel halves inside position 3
    holed = dataclasses.replace(rec, accel=accel)
    session = session_from_recording(holed, g=9.81, latitude=np.deg2rad(50.0))
    assert not np.shares_memory(session.windows[3].accel, holed.accel)
    assert np.shares_memory(session.windows[2].accel, holed.accel)
    assert np.all(np.isfinite(session.windows[3].accel))
    assert _analysis_json(holed) == _analysis_json(_widened(holed))


def test_count_checks_do_not_depend_on_the_chunk(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    rec = _file_recording(tmp_path)
    scaled = dataclasses.replace(rec, accel=np.asarray(rec.accel, dtype=np.float64) * 0.37)
    a = analyse_recording(rec, g=9.81, latitude=np.deg2rad(50.0))
    for r in (rec, scaled):
        with_r = dataclasses.replace(a, recording=r)
        whole = extended_truth(with_r)
        monkeypatch.setattr(report_module, "FACT_CHUNK_ROWS", 333)
        assert extended_truth(with_r) == whole
        monkeypatch.undo()
    # the rescaled accelerometer is not whole counts: a scale of its own, rounding kept
    scaled_truth = extended_truth(dataclasses.replace(a, recording=scaled))["accel"]
    assert scaled_truth["nominal_lsb"] != extended_truth(a)["accel"]["nominal_lsb"]
    assert scaled_truth["quantization"] == 1.0


def _paused(step_s: float, pauses_s: tuple[float, ...], repeat: bool) -> Recording:
    """Labelled runs of 40 rows at ``step_s``; a pause before each later piece."""
    t, position, now = [], [], 0.0
    for k, pause in enumerate((0.0, *pauses_s)):
        now += pause
        for label in range(3):
            t.append(now + step_s * np.arange(40))
            position.append(np.full(40, label if repeat else 3 * k + label))
            now = float(t[-1][-1]) + step_s
    n = sum(x.size for x in t)
    return recording_from_columns(
        {"sample_rate_hz": 1.0 / step_s},
        t=np.concatenate(t),
        accel=np.ones((n, 3)),
        position=np.concatenate(position),
    )


@pytest.mark.parametrize(
    ("step_s", "pauses_s", "repeat", "trials"),
    [
        (0.005, (61.0, 300.0), False, 3),  # pauses over 60 s split
        (0.005, (59.0, 30.0), False, None),  # shorter ones do not
        (1.0, (80.0, 90.0), False, None),  # 1 s steps: a pause must exceed 100 s
        (1.0, (150.0, 120.0), False, 3),
        (0.005, (0.005, 0.005), True, 3),  # the labels run again: trials without pauses
    ],
)
def test_trials_do_not_depend_on_the_chunk(
    monkeypatch: pytest.MonkeyPatch,
    step_s: float,
    pauses_s: tuple[float, ...],
    repeat: bool,
    trials: int | None,
) -> None:
    rec = _paused(step_s, pauses_s, repeat)
    whole, note = detect_trials(rec)
    count = None if whole.trial is None else int(np.unique(whole.trial).size)
    assert count == trials, note
    for chunk in (1, 7, 40):
        monkeypatch.setattr(grouping_module, "PAUSE_CHUNK_ROWS", chunk)
        found, again = detect_trials(rec)
        assert again == note
        assert (found.trial is None) == (whole.trial is None)
        if whole.trial is not None:
            assert found.trial is not None and np.array_equal(found.trial, whole.trial)
