"""Trials in a file without angles: the |f| = g fit keys positions by (trial, label).

Four re-mountings of one unit (each trial's accelerometer bias moved by up to ±20 counts,
the gyro's by ±5; K, S and G shared: :func:`canimucal.analysis.simulated.remounted`), the
twelve-pose plan, 10 s a position at 100 Hz, the angle columns emptied: the scalar fit
(docs/design.md §6 *Trials*). The trials' biases differ by tens of σ of one trial's bias.

Before, a label's rows of all four trials were averaged as one position with one bias for
all: each such mean held the bias steps, its scatter inflated, and both sensors' steps were
named ``bias_drift`` on a clean unit (seeds 0–5). Now each trial has its own biases (the
trials' mean and offsets, as with angles) and K is shared: K and every trial's bias lie
within their σ of the truth, nothing is named.
"""

from __future__ import annotations

import dataclasses
import json
from functools import cache

import numpy as np

from canimucal.analysis.base_fit import fit_scalar_base
from canimucal.analysis.report import Analysis, analyze, extended_truth
from canimucal.analysis.simulated import TrialsTruth
from canimucal.analysis.solve import solve_recording
from canimucal.io.grouping import interval_trials, rows_count
from canimucal.io.recording import Recording
from canimucal.sim.truth import Truth
from tests.support import departures as dep

SEEDS = (0, 1, 2, 3)
Z_LIMIT = 4.0
"""|estimate − truth|/σ allowed for each of K's 3 and the trials' 12 bias entries per seed."""


def without_angles(rec: Recording) -> Recording:
    """``rec`` with its angle columns emptied (labels kept): only the |f| = g fit applies."""
    nan = np.full(rec.n_rows, np.nan)
    return dataclasses.replace(rec, alpha_deg=nan, beta_deg=nan, psi_deg=nan)


@cache
def analysed(seed: int) -> tuple[Analysis, TrialsTruth]:
    case = dep.Case(dep.REMOUNTED, "twelve", 0.1)
    rec, units = dep.trials_recording(case, seed)
    return analyze(without_angles(rec)), units


def test_positions_are_keyed_by_trial_and_label_without_angles() -> None:
    a, _units = analysed(0)
    assert not a.session.known_positions
    assert a.result.trials == dep.TRIALS
    assert [x.trial for x in a.session.averages] == [
        t for t in range(dep.TRIALS) for _ in range(12)
    ]
    assert not any("one bias for all" in n for n in a.notes), a.notes


def test_k_and_each_trials_bias_mean_what_their_sigma_say() -> None:
    worst = {}
    for seed in SEEDS:
        a, units = analysed(seed)
        r = a.result
        k_true = np.diag(units.trials[0].accel.K)
        z_k = [
            (r.base_values[f"accel.K[{i}][{i}]"] - k_true[i]) / r.base_sigmas[f"accel.K[{i}][{i}]"]
            for i in range(3)
        ]
        fit = fit_scalar_base(a.session)[1]
        assert fit.trial_bias is not None and fit.trial_bias_sigma is not None
        z_b = (fit.trial_bias - units.accel_bias) / fit.trial_bias_sigma
        worst[seed] = float(np.max(np.abs(np.concatenate([z_k, z_b.ravel()]))))
        # the steps between trials are many σ of one trial's bias (the twelve poses fix y's
        # least): one bias could not hold them
        steps = np.ptp(units.accel_bias, axis=0) / fit.trial_bias_sigma.max(axis=0)
        assert np.max(steps) > 100.0, steps
    assert max(worst.values()) < Z_LIMIT, worst


def test_a_clean_unit_remounted_names_nothing() -> None:
    named = {}
    for seed in SEEDS:
        r = analysed(seed)[0].result
        if r.findings or r.ambiguous:
            named[seed] = sorted({f"{f.sensor}.{f.effect}" for f in r.findings})
        chi2, dof, p = r.lack_of_fit
        assert p > 1e-3, (seed, chi2, dof)
    assert not named, named


def test_the_truth_of_trials_without_angles_holds_each_trials_biases() -> None:
    """``--truth-out``'s ``trials`` from the |f| = g fit, read back by the simulator's reader."""
    for seed in SEEDS[:2]:
        a, units = analysed(seed)
        truth = Truth.from_dict(json.loads(json.dumps(extended_truth(a))))
        fit = fit_scalar_base(a.session)[1]
        assert fit.trial_bias_sigma is not None
        # the truth's counts per count of the data (finer counts for fractional data)
        ka = a.session.accel_lsb / truth.accel.nominal_lsb
        kg = a.session.gyro_lsb / truth.gyro.nominal_lsb
        accel = np.array([u.accel.bias for u in truth.trial_units()]) / ka
        z = (accel - units.accel_bias) / fit.trial_bias_sigma
        assert np.all(np.abs(z) < Z_LIMIT), z
        gyro = np.array([u.gyro.bias for u in truth.trial_units()]) / kg
        assert np.all(np.abs(gyro - units.gyro_bias) < 1.0), gyro - units.gyro_bias


def test_solve_without_angles_gives_each_trial_its_bias() -> None:
    """`solve`'s |f| = g path shares the model: K and each trial's bias within 4σ, the fit
    accepted; one bias for all left χ²/dof in the thousands on these files (seed 0: 8508)."""
    from canimucal.analysis.solve import solve_recording

    for seed in SEEDS:
        case = dep.Case(dep.REMOUNTED, "twelve", 0.1)
        rec, units = dep.trials_recording(case, seed)
        solution = solve_recording(without_angles(rec)).solution
        fit = solution.scalar
        assert fit is not None and fit.trial_bias is not None
        assert fit.trial_bias_sigma is not None
        assert solution.quality.inflation == 1.0, solution.quality  # χ² within its tail
        record = solution.record
        assert [t.trial for t in record.trials] == list(range(dep.TRIALS))
        z_b = (fit.trial_bias - units.accel_bias) / fit.trial_bias_sigma
        k_true = np.diag(units.trials[0].accel.K)
        z_k = (np.diag(fit.K) - k_true) / np.diag(fit.K_sigma)
        assert np.max(np.abs(np.concatenate([z_b.ravel(), z_k]))) < Z_LIMIT, (seed, z_b, z_k)
        assert record.accel is not None
        np.testing.assert_allclose(record.accel.bias, fit.trial_bias.mean(axis=0), atol=1e-9)


def test_unlabelled_still_intervals_take_their_trial() -> None:
    """No labels either: the detector's still intervals carry the trial of their rows.

    Before, the trial column of an unlabelled file was ignored: the |f| = g fit gave one bias
    for all four trials (χ²/dof 7941 on this seed) and analyze named scale_nonlinearity.
    """
    rec, _units = dep.trials_recording(dep.Case(dep.REMOUNTED, "twelve", 0.1), 0)
    unlabelled = dataclasses.replace(
        without_angles(rec), position=np.full(rec.n_rows, -1, dtype=np.int64)
    )
    solved = solve_recording(unlabelled)
    assert solved.record.trials is not None and len(solved.record.trials) == dep.TRIALS
    quality = solved.solution.quality
    assert quality is not None and quality.p_value > 0.01, quality.line("the noise")
    a = analyze(unlabelled)
    assert a.result.trials == dep.TRIALS and not a.result.findings, a.result.findings
    pooled = solve_recording(dataclasses.replace(unlabelled, trial=None)).solution.quality
    assert pooled is not None and pooled.p_value < 1e-6  # the departure is real


def test_trials_are_found_without_angles_or_a_trial_column() -> None:
    """Labels that run again, no angles, no trial column: found as trials by solve and analyze.

    Before, trials were looked for only in files with angles: these four were one, with one
    bias for all (the pooled fit of the test above).
    """
    rec, _units = dep.trials_recording(dep.Case(dep.REMOUNTED, "twelve", 0.1), 0)
    bare = dataclasses.replace(without_angles(rec), trial=None)
    solved = solve_recording(bare)
    assert any("treated as 4 trials" in note for note in solved.notes), solved.notes
    assert solved.record.trials is not None and len(solved.record.trials) == dep.TRIALS
    quality = solved.solution.quality
    assert quality is not None and quality.p_value > 0.01, quality.line("the noise")
    a = analyze(bare)
    assert a.result.trials == dep.TRIALS and not a.result.findings, a.result.findings


def test_a_still_interval_cut_by_a_trial_boundary_keeps_its_long_pieces() -> None:
    rec, _units = dep.trials_recording(dep.Case(dep.REMOUNTED, "twelve", 0.1), 0)
    n = rec.n_rows
    trial = np.zeros(n, dtype=np.int64)
    trial[n // 2 :] = 1
    trial[n // 2 + 5 :] = 2  # trial 1: five rows only
    cut = dataclasses.replace(rec, trial=trial)
    pieces = interval_trials(cut, [slice(n // 2 - 100, n // 2 + 100)])
    assert [t for t, _ in pieces] == [0, 2]  # the five rows of trial 1 are too few to keep
    assert [rows_count(r) for _, r in pieces] == [100, 95]
    assert interval_trials(dataclasses.replace(rec, trial=None), [slice(0, 9)]) == [
        (None, slice(0, 9))
    ]
