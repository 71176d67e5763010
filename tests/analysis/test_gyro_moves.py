"""Gyro S from a recording's moves: simulated sessions with a hidden S, lost samples, plans."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from canimucal.analysis.calibrate import SiteConditions, solve_positions
from canimucal.analysis.gyro_moves import fit_recording_moves, recording_moves, solve_gyro_moves
from canimucal.analysis.simulated import simulate_plan_recording
from canimucal.errors import InputError
from canimucal.io.calibration import Device
from canimucal.io.grouping import position_averages
from canimucal.io.recording import Recording
from canimucal.model.layout import JointSpec
from canimucal.model.positions import Plan
from canimucal.model.vocabulary.plans import builtin_plan
from canimucal.sim.truth import Truth
from tests.support.chi2_band import chi2_ratio_band, mahalanobis
from tests.support.moves import TURN_POSES_DEG, turns_plan


def site_of(truth: Truth) -> SiteConditions:
    return SiteConditions(
        g=truth.g,
        latitude=truth.latitude,
        heading=truth.heading,
        accel_lsb=truth.accel.nominal_lsb,
        gyro_lsb=truth.gyro.nominal_lsb,
    )


def simulated(seed: int, plan: Plan, sample_rate_hz: int = 100) -> tuple[Truth, Recording]:
    truth = Truth.random(np.random.default_rng(seed), sample_rate_hz=sample_rate_hz)
    return truth, simulate_plan_recording(truth, plan, seed=seed, transient_s=2.0)


def test_hidden_s_recovered_with_an_honest_sigma_over_a_seed_sweep() -> None:
    """40 sessions, each with its own S (scales ±3 %, cross-axis ±1 %) and pose errors.

    The errors of S against the truth, normalised by the fit's covariance, must spread as
    χ² over that many sessions (and per entry over that many seeds): a σ that counts each
    pose's error once per move was ~10 % optimistic on this path.
    """
    z, d2 = [], []
    for seed in range(40):
        truth, rec = simulated(seed, turns_plan(seconds=2.0), sample_rate_hz=50)
        found = recording_moves(rec, site_of(truth))
        assert len(found.moves) == len(TURN_POSES_DEG) - 1 and not found.notes
        fit = fit_recording_moves(found, site_of(truth))
        assert fit.identifiable.all() and not fit.notes
        z.append(((fit.S - truth.gyro.S) / fit.S_sigma).reshape(9))
        d2.append(mahalanobis(fit.S - truth.gyro.S, fit.covariance))
        assert np.all(fit.S_sigma / np.abs(truth.gyro.S[0, 0]) < 0.002)  # σ below 0.2 %
    assert np.all(np.abs(z) < 4.5), np.round(z, 2)
    low, high = chi2_ratio_band(9 * len(d2))
    assert low <= np.mean(d2) / 9 <= high, (np.mean(d2) / 9, low, high)
    low, high = chi2_ratio_band(len(d2), comparisons=9)
    per_entry = np.mean(np.square(z), axis=0)
    assert np.all((low <= per_entry) & (per_entry <= high)), (np.round(per_entry, 2), low, high)


def _by_stand() -> Plan:
    """The recommended poses with each stand's four turns in a row: level ×4, then tilted ×4."""
    positions = builtin_plan("recommended").with_total_seconds(40.0).positions
    return Plan("custom", tuple(positions[i] for i in (0, 3, 4, 7, 1, 2, 5, 6)))


def test_recommended_plan_gives_the_full_s_in_the_record() -> None:
    truth, rec = simulated(4, builtin_plan("recommended").with_total_seconds(40.0))
    site = site_of(truth)
    spec = JointSpec(accel_k="full", tilt="rigid", gyro="mems")
    static = solve_positions(position_averages(rec), spec, site, Device(serial=1))
    solution, fit = solve_gyro_moves(rec, static, site)
    assert fit.identifiable.all()
    gyro = solution.record.gyro
    assert gyro is not None and gyro.S is not None and gyro.S_sigma is not None
    s, sigma = np.array(gyro.S, dtype=float), np.array(gyro.S_sigma, dtype=float)
    assert np.all(np.abs(s - truth.gyro.S) < 4.0 * sigma), (s - truth.gyro.S) / sigma
    assert np.all(sigma * truth.gyro.nominal_lsb < 0.005)


def test_turns_stand_by_stand_see_only_column_y_and_say_so() -> None:
    """The recommended poses, each stand's turns in a row: the turns are about y; the one
    move between the stands mixes x and z too little to fix them."""
    truth, rec = simulated(1, _by_stand())
    site = site_of(truth)
    spec = JointSpec(accel_k="full", tilt="rigid", gyro="mems")
    static = solve_positions(position_averages(rec), spec, site, Device(serial=1))
    solution, fit = solve_gyro_moves(rec, static, site)
    assert fit.identifiable.tolist() == [False, True, False]
    assert np.all(np.abs(fit.S[:, 1] - truth.gyro.S[:, 1]) < 4.0 * fit.S_sigma[:, 1])
    gyro = solution.record.gyro
    assert gyro is not None and gyro.S is not None and gyro.S_sigma is not None
    for i in range(3):
        assert gyro.S[i][0] is None and gyro.S[i][2] is None
        assert gyro.S[i][1] == pytest.approx(fit.S[i, 1]) and gyro.S_sigma[i][1] is not None
    assert "not identifiable" in solution.undetermined["gyro.S[0][2]"]
    assert any("column z not identifiable" in w for w in solution.warnings)


def _lose_rows(rec: Recording, rows: np.ndarray) -> Recording:
    keep = np.ones(rec.n_rows, dtype=bool)
    keep[rows] = False
    fields = ("t", "counter", "position", "alpha_deg", "beta_deg", "psi_deg", "accel", "gyro")
    cut = {name: getattr(rec, name)[keep] for name in (*fields, "temp_c")}
    return dataclasses.replace(rec, **cut)


def test_move_with_lost_samples_is_filled_or_dropped() -> None:
    truth, rec = simulated(2, turns_plan())
    site = site_of(truth)
    moving = np.flatnonzero(rec.position < 0)
    first_move = moving[(moving > 100) & (moving < moving[0] + 400)]
    n = first_move.size
    few = _lose_rows(rec, first_move[10:11])  # one sample of ~200: below 1 %
    found = recording_moves(few, site)
    assert len(found.moves) == len(TURN_POSES_DEG) - 1 and not found.notes
    spread = first_move[5 : n - 5 : max(n // 8, 1)][:4]  # four lost of ~200: 2 %
    many = _lose_rows(rec, spread)
    found = recording_moves(many, site)
    assert len(found.moves) == len(TURN_POSES_DEG) - 2
    assert any("lost (more than 1 %)" in note for note in found.notes), found.notes
    gap = _lose_rows(rec, first_move[20:40])  # 0.2 s without samples
    assert any("time gap" in note for note in recording_moves(gap, site).notes)


def test_without_labelled_positions_moves_are_refused() -> None:
    truth, rec = simulated(3, turns_plan(seconds=2.0))
    unlabelled = dataclasses.replace(rec, position=np.full(rec.n_rows, -1, dtype=np.int64))
    with pytest.raises(InputError, match="labelled positions"):
        recording_moves(unlabelled, site_of(truth))


@pytest.mark.parametrize(("plan", "determined"), [("two", False), ("five", True)])
def test_g_from_the_positions_feeds_the_moves_where_the_plan_allows(
    plan: str, determined: bool
) -> None:
    """Five positions determine G, which the moves then remove; two do not, and it is said."""
    truth = Truth.random(np.random.default_rng(4), sample_rate_hz=100, gyro_g_max=0.5)
    rec = simulate_plan_recording(truth, builtin_plan(plan), seed=4, transient_s=2.0)
    site = site_of(truth)
    spec = JointSpec(accel_k="diag", tilt="none", gyro="mems", gyro_g=True)
    solution = solve_positions(position_averages(rec), spec, site, Device(serial=0))
    solved, fit = solve_gyro_moves(rec, solution, site)
    gyro = solved.record.gyro
    assert gyro is not None and gyro.G is not None
    said = [w for w in solved.warnings if w.startswith("gyro G is not determined")]
    if determined:
        G, sigma = np.array(gyro.G, dtype=float), np.array(gyro.G_sigma, dtype=float)
        assert np.all(np.abs(G - truth.gyro.G) < 4.0 * sigma) and not said
    else:
        assert all(v is None for row in gyro.G for v in row) and len(said) == 1
    assert fit.identifiable[2]  # both plans turn about z: that column is fitted either way
    z = (fit.S[:, 2] - truth.gyro.S[:, 2]) / fit.S_sigma[:, 2]
    assert np.all(np.abs(z) < 4.0), z
