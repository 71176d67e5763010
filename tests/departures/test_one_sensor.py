"""Files of one sensor: accelerometer-only and gyro-only recordings analyse and solve.

Seeds 0–19 dealt round the five and recommended plans at exact and 0.1° poses (10 s
positions, the sensor at 100 Hz), no tolerance in the header, a clean unit:

- accelerometer-only (gyro columns empty): `solve`'s errors spread as their σ say (rms of
  (estimate − truth)/σ within 0.8–1.25, each parameter's Σz²/n in its χ² band);
  `analyze` names nothing;
- gyro-only (accelerometer columns empty; before, `analyze` exited 2 "found 0 positions"
  and `solve` "a position needs at least two accelerometer samples"): `solve` gives the
  gyro's bias, whose errors spread as their σ say, and acceptance fails for want of an
  accelerometer fit (nothing of the accelerometer may be written); `analyze` names nothing
  and lists every accelerometer effect as untestable; what needs the accelerometer (gyro
  moves, plots, the extended truth, the public ``analyze``) is refused in one line.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
import pytest

from canimucal.analysis.gyro_only import NO_ACCEL, analyse_gyro_only
from canimucal.analysis.report import analyze
from canimucal.analysis.session_model import ModelChoice
from canimucal.analysis.solve import site_of, solve_recording
from canimucal.errors import InputError
from canimucal.io.recording_writer import write_recording
from tests.support import departures as dep
from tests.support.cli_run import CliRun

SEEDS = tuple(range(20))


def test_an_accelerometer_only_file_solves_with_honest_sigma() -> None:
    pairs = dep.rotation(dep.ACCEL_ONLY, SEEDS)
    spread = dep.spread_of([dep.recording_errors(case, seed) for case, seed in pairs])
    assert not spread.within(), (spread.rms, spread.within())


def test_an_accelerometer_only_file_analyses() -> None:
    case, seed = dep.rotation(dep.ACCEL_ONLY, SEEDS)[1]  # the recommended plan
    a = analyze(dep.short_recording(case, seed))
    assert a.session.known_positions and not a.session.has_gyro
    assert not a.result.findings, [f.effect for f in a.result.findings]
    assert a.result.untestable["gyro_g_sensitivity"] == "no gyro data"


def _gyro_bias_z(case: dep.Case, seed: int) -> dict[str, float]:
    truth = dep.case_truth(case, seed)
    solved = solve_recording(dep.short_recording(case, seed))
    gyro = solved.record.gyro
    assert gyro is not None and gyro.bias_sigma is not None
    assert solved.record.accel.bias == (None, None, None)
    assert solved.verdict is not None and not solved.verdict.report.passed
    return {
        f"gyro.bias[{i}]": (gyro.bias[i] - truth.gyro.bias[i]) / gyro.bias_sigma[i]
        for i in range(3)
    }


def test_a_gyro_only_file_solves_the_gyro_bias_with_honest_sigma() -> None:
    pairs = dep.rotation_all(dep.GYRO_ONLY, SEEDS)
    spread = dep.spread_of([_gyro_bias_z(case, seed) for case, seed in pairs])
    assert not spread.within(), (spread.rms, spread.within())


def test_a_gyro_only_file_analyses_and_names_nothing() -> None:
    named = {}
    for case, seed in dep.rotation_all(dep.GYRO_ONLY, SEEDS):
        rec = dep.short_recording(case, seed)
        site, _ = site_of(rec, ModelChoice())
        a = analyse_gyro_only(rec, site)
        assert a.untestable["cross_axis"] == NO_ACCEL and a.untestable["base_tilt"] == NO_ACCEL
        if a.findings:
            named[seed] = [f.effect for f in a.findings]
    assert len(named) <= 2, named  # P(Bin(20, 0.01) ≥ 3) = 1.0e-3


def test_what_needs_the_accelerometer_is_refused_in_one_line(
    tmp_path: Path, cli: Callable[[Sequence[str]], CliRun]
) -> None:
    case, seed = dep.rotation_all(dep.GYRO_ONLY, SEEDS)[1]
    rec = dep.short_recording(case, seed)
    path = write_recording(tmp_path / "gyro.csv", rec, overwrite=False)
    with pytest.raises(InputError, match="no accelerometer data"):
        analyze(rec)
    with pytest.raises(InputError, match="needs the accelerometer"):
        solve_recording(rec, ModelChoice(gyro="moves"))
    run = cli(["analyze", str(path)])
    assert run.code == 0 and "the gyro alone is analysed" in run.out, run.err
    assert "no cause named; the base model fits" in run.out
    run = cli(["analyze", str(path), "--plots", str(tmp_path / "plots")])
    assert run.code == 2 and run.err.count("\n") == 1 and "no accelerometer data" in run.err
    run = cli(["solve", str(path)])
    assert run.code == 3 and "accelerometer parameters determined" in run.out
    assert f"warning: {NO_ACCEL}" in run.err
    assert np.isfinite(rec.gyro).all()
