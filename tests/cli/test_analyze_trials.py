"""`analyze` of a file of several trials: its truth-out and residual table (docs/design.md §6).

A unit re-mounted between four trials (each trial's biases moved by up to ±20 counts on
the accelerometer and ±5 on the gyro; K, S and G shared: :mod:`tests.support.departures`).
``--truth-out`` writes what the base model fitted, each trial's biases (``trials``; before,
only their mean in ``accel.bias``/``gyro.bias``), and the simulator's truth reader takes
them back (:meth:`~canimucal.sim.truth.Truth.trial_units`). The residual table names each
position's trial. A file of one trial writes what it wrote before.
"""

from __future__ import annotations

import contextlib
import dataclasses
import io
import json
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from canimucal.analysis.base_fit import fit_known
from canimucal.analysis.data import SessionData
from canimucal.analysis.report import analyze
from canimucal.analysis.session import session_from_recording
from canimucal.analysis.simulated import TrialsTruth
from canimucal.cli.analyze_plots import residual_figure, trial_spans
from canimucal.cli.main import main
from canimucal.io.recording import read_recording_csv
from canimucal.io.recording_writer import write_recording
from canimucal.io.truth import load_truth
from canimucal.sim.truth import AccelTruth, GyroTruth, Truth
from tests.support import departures as dep
from tests.support.cli_run import CliRun

Z_LIMIT = 4.0
"""|written − simulated|/σ allowed for each trial's bias entries."""


def counts_per_count(sensor: AccelTruth | GyroTruth, session: SessionData) -> float:
    """The truth's counts per count of the data (a truth of data in fractional counts is in
    a finer count: :func:`canimucal.analysis.report.extended_truth`)."""
    lsb = session.accel_lsb if isinstance(sensor, AccelTruth) else session.gyro_lsb
    return float(lsb / sensor.nominal_lsb)


@dataclass(frozen=True)
class TrialsRun:
    """One ``analyze --truth-out`` of a four-trial file: its text, truth, session, units."""

    out: str
    truth: Truth
    session: SessionData
    units: TrialsTruth


@pytest.fixture(scope="module")
def trials_run(tmp_path_factory: pytest.TempPathFactory) -> TrialsRun:
    where = tmp_path_factory.mktemp("trials")
    case = dep.Case(dep.REMOUNTED, "recommended", 0.0)
    rec, units = dep.trials_recording(case, 1)
    path = write_recording(where / "trials.csv", rec, overwrite=False)
    target = where / "truth.json"
    text = io.StringIO()
    with contextlib.redirect_stdout(text):
        code = main(["analyze", str(path), "--truth-out", str(target)])
    assert code == 0
    truth = load_truth(target)
    session = session_from_recording(
        read_recording_csv(path), g=truth.g, latitude=truth.latitude, heading=0.0
    )
    return TrialsRun(text.getvalue(), truth, session, units)


def test_truth_out_holds_each_trials_biases_and_reads_back(trials_run: TrialsRun) -> None:
    truth, session, units = trials_run.truth, trials_run.session, trials_run.units
    assert [t.trial for t in truth.trials] == list(range(dep.TRIALS))
    joint = fit_known(session)[1]
    assert joint.trial_bias_cov is not None
    sigma = np.sqrt(np.diagonal(joint.trial_bias_cov, axis1=1, axis2=2))
    written = truth.trial_units()
    accel = np.array([u.accel.bias for u in written]) / counts_per_count(truth.accel, session)
    gyro = np.array([u.gyro.bias for u in written]) / counts_per_count(truth.gyro, session)
    z_accel = (accel - units.accel_bias) / sigma[:, :3]
    z_gyro = (gyro - units.gyro_bias) / sigma[:, 3:]
    assert np.all(np.abs(z_accel) < Z_LIMIT), z_accel
    assert np.all(np.abs(z_gyro) < Z_LIMIT), z_gyro
    # the steps between trials are many σ: the trials' mean would not do for any of them
    assert np.max(np.abs(units.accel_bias - units.accel_bias.mean(axis=0)) / sigma[:, :3]) > 20
    mean = [np.array(t.bias) / counts_per_count(t, session) for t in (truth.accel, truth.gyro)]
    np.testing.assert_allclose(mean[0], accel.mean(axis=0), rtol=0, atol=1e-9)
    np.testing.assert_allclose(mean[1], gyro.mean(axis=0), rtol=0, atol=1e-9)


def test_the_residual_table_names_each_positions_trial(trials_run: TrialsRun) -> None:
    """A label recurs in every trial: the first column says whose each position is."""
    averages = trials_run.session.averages
    table = trials_run.out.split("(residual of each position's mean", 1)[1].splitlines()[1:]
    assert table[0].split()[:2] == ["trial", "pos"], table[0]
    rows = [r.split() for r in table[1 : 1 + len(averages)]]
    assert [int(r[0]) for r in rows] == [x.trial for x in averages]
    assert [int(r[1]) for r in rows] == list(range(len(averages)))
    assert table[1 + len(averages)].lstrip().startswith("lack of fit"), table[1 + len(averages)]


def test_one_trial_writes_the_same_files_as_no_trial_column(
    tmp_path: Path, cli: Callable[[Sequence[str]], CliRun]
) -> None:
    """No ``trials`` key, no trial column: the bytes of a file without the column."""
    rec = dep.short_recording(dep.Case(dep.REMOUNTED, "recommended", 0.1), 2)
    outputs = []
    for name, trial in (("plain", None), ("one", np.zeros(rec.n_rows, dtype=np.int64))):
        where = tmp_path / name
        where.mkdir()
        path = write_recording(
            where / "rec.csv", dataclasses.replace(rec, trial=trial), overwrite=False
        )
        truth, analysis = where / "truth.json", where / "analysis.json"
        run = cli(["analyze", str(path), "--truth-out", str(truth), "--json", str(analysis)])
        assert run.code == 0, run.err
        text = run.out.replace(str(where), "DIR")  # the outputs' paths are said
        outputs.append((text, truth.read_bytes(), analysis.read_bytes()))
    assert outputs[0] == outputs[1]
    assert "trials" not in json.loads(outputs[0][1])
    assert "trial" not in outputs[0][0].split("(residual of each position's mean", 1)[1]


def test_the_residual_plot_marks_each_trial(tmp_path: Path) -> None:
    """residuals.png: each trial's positions between dotted lines, named above them."""
    plt = pytest.importorskip("matplotlib.pyplot")  # the dev extra installs it
    rec, _ = dep.trials_recording(dep.Case(dep.REMOUNTED, "recommended", 0.0), 1)
    analysis = analyze(rec)
    spans = trial_spans(analysis.session.averages, len(analysis.result.residuals))
    assert [t for t, _, _ in spans] == list(range(dep.TRIALS))
    assert spans[0][1] == 1 and spans[-1][2] == len(analysis.result.residuals)
    assert all(b[1] == a[2] + 1 for a, b in zip(spans, spans[1:], strict=False))
    fig = residual_figure(plt, analysis)
    for ax in fig.axes:
        names = [t.get_text() for t in ax.texts if t.get_text().startswith("trial")]
        assert names == [f"trial {t}" for t in range(dep.TRIALS)]
        dotted = [x for x in ax.lines if x.get_linestyle() == ":"]
        assert sorted(x.get_xdata()[0] for x in dotted) == [s[1] - 0.5 for s in spans[1:]]
    plt.close(fig)
    one_trial = [dataclasses.replace(a, trial=0) for a in analysis.session.averages]
    assert trial_spans(one_trial, len(one_trial)) == []  # one trial: nothing to mark
