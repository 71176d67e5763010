"""Quaternion integration of gyro moves and the fit of S from them (canimucal.model.moves)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from canimucal.model import moves as mv
from canimucal.model.frames import earth_rate_level, position_dcm
from canimucal.model.sensor import DEFAULT_GYRO_LSB
from canimucal.model.vocabulary.constants import OUTPUT_DATA_RATES_HZ
from canimucal.sim.imu import ImuSimulator
from canimucal.sim.schedule import min_jerk
from canimucal.sim.truth import Truth
from tests.support.chi2_band import chi2_ratio_band, mahalanobis
from tests.support.moves import TURN_POSES_DEG

NOMINAL_S = np.eye(3) / DEFAULT_GYRO_LSB
TURNS = [
    ((1, 0, 0), np.pi / 2),
    ((0, 1, 0), -np.pi / 2),
    ((0, 0, 1), np.pi / 2),
    ((1, 1, 0), np.pi / 2),
    ((0, 1, 1), -np.pi / 2),
    ((1, 0, 1), np.pi / 2),
]


def _true_s(rng: np.random.Generator) -> np.ndarray:
    e = rng.uniform(-0.01, 0.01, (3, 3)) + np.diag(rng.uniform(-0.03, 0.03, 3))
    return np.asarray((np.eye(3) + e) / DEFAULT_GYRO_LSB)


def _synthetic_moves(
    rng: np.random.Generator,
    S: np.ndarray,
    bias: np.ndarray,
    sigma_counts: float,
    turns: list[tuple[tuple[int, int, int], float]],
    fs_hz: float = 100.0,
    seconds: float = 1.0,
) -> list[mv.Move]:
    """Minimum-jerk turns about fixed axes, sampled as gyro counts with white noise."""
    out = []
    n = int(round(seconds * fs_hz)) + 1
    _, ds = min_jerk(np.linspace(0.0, 1.0, n))
    for axis, angle in turns:
        u = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
        w = np.outer(ds / seconds * angle, u)
        counts = bias + w @ S.T + rng.normal(0.0, sigma_counts, (n, 3))
        rot = mv.rotvec_to_matrix(angle * u).T
        out.append(mv.Move(counts, 1.0 / fs_hz, rot, angle * u, sigma_rad=0.0))
    return out


def _position_chain(
    rng: np.random.Generator,
    S: np.ndarray,
    bias: np.ndarray,
    sigma_counts: float,
    tolerance_rad: float,
    n_mean: int,
    fs_hz: float = 50.0,
    seconds: float = 1.0,
    n_positions: int = len(TURN_POSES_DEG),
) -> tuple[list[mv.Move], np.ndarray, mv.Shared]:
    """Moves from one still position to the next, as a session makes them.

    Every pose of :data:`TURN_POSES_DEG` is really set off by a draw from its tolerance, and
    each position's mean gyro (``n_mean`` samples) is off by its own noise; each move's
    bias is the mean of its two positions' means, as the procedure forms it. The moves are
    returned on one common bias (the first), as :func:`fit_recording_moves` passes them.
    """
    poses = np.deg2rad(np.array(TURN_POSES_DEG[:n_positions], dtype=float))
    real = poses + rng.normal(0.0, tolerance_rad, poses.shape)
    means = bias + rng.normal(0.0, sigma_counts / np.sqrt(n_mean), poses.shape)
    n = int(round(seconds * fs_hz)) + 1
    _, ds = min_jerk(np.linspace(0.0, 1.0, n))
    moves = []
    for a in range(len(poses) - 1):
        turn = mv.matrix_to_rotvec(position_dcm(*real[a]) @ position_dcm(*real[a + 1]).T)
        counts = bias + np.outer(ds / seconds, turn) @ S.T + rng.normal(0, sigma_counts, (n, 3))
        own_bias = 0.5 * (means[a] + means[a + 1])
        c_a, c_b = position_dcm(*poses[a]), position_dcm(*poses[a + 1])
        common = counts - own_bias + 0.5 * (means[0] + means[1])
        moves.append(mv.pose_move(common, 1 / fs_hz, c_a, c_b, 0.0, positions=(a, a + 1)))
    shared = mv.Shared(
        {p: mv.attitude_covariance(poses[p], tolerance_rad) for p in range(len(poses))},
        {p: np.eye(3) * sigma_counts**2 / n_mean for p in range(len(poses))},
    )
    return moves, 0.5 * (means[0] + means[1]), shared


def _noise_free_truth(fs_hz: float, seed: int) -> Truth:
    d = Truth.random(np.random.default_rng(seed), heading_deg=30.0).to_dict()
    d["sample_rate_hz"] = fs_hz
    for sensor in ("accel", "gyro"):
        d[sensor]["noise_density"] = [0.0] * 3
        d[sensor]["quantization"] = 0.0
    return Truth.from_dict(d)


def test_constant_rate_turn_integrates_exactly() -> None:
    axis = np.array([1.0, -2.0, 0.5]) / np.linalg.norm([1.0, -2.0, 0.5])
    rates = np.tile(axis * 0.7, (301, 1))  # 0.7 rad/s for 3 s: 2.1 rad
    r = mv.integrate_rates(rates, 0.01)
    np.testing.assert_allclose(mv.matrix_to_rotvec(r), axis * 2.1, atol=1e-12)


def test_integration_error_is_second_order_on_the_simulator() -> None:
    """A two-axis minimum-jerk move with a turn, at every rate the IMU offers."""
    errors = {}
    p0, p1 = np.deg2rad([10.0, 20.0, 0.0]), np.deg2rad([-80.0, 60.0, 90.0])
    for fs in OUTPUT_DATA_RATES_HZ:
        truth = _noise_free_truth(fs, seed=3)
        sim = ImuSimulator(truth, seed=0)
        sim.set_pose(*p0, transient_s=0.0)
        sim.next_block(5)
        sim.set_pose(*p1, transient_s=2.0)
        counts = sim.next_block(int(2 * fs) + 1).gyro
        c0 = position_dcm(*p0, truth.alpha0, truth.beta0)
        c1 = position_dcm(*p1, truth.alpha0, truth.beta0)
        earth = c0 @ earth_rate_level(truth.latitude, truth.heading)
        rates = np.linalg.solve(truth.gyro.S, (counts - truth.gyro.bias).T).T
        m = mv.move_rotation(rates, 1.0 / fs, earth)
        errors[fs] = np.linalg.norm(mv.matrix_to_rotvec(m @ (c1 @ c0.T).T))
    arcsec = {fs: np.rad2deg(e) * 3600 for fs, e in errors.items()}
    assert arcsec[50] < 20.0, arcsec
    assert arcsec[1000] < 0.1, arcsec
    assert errors[50] / errors[1000] > 0.5 * 20.0**2, arcsec  # error ∝ Δt²


def test_earth_rate_is_removed() -> None:
    truth = _noise_free_truth(100, seed=4)
    sim = ImuSimulator(truth, seed=0)
    pose = np.deg2rad([30.0, -40.0, 0.0])
    sim.set_pose(*pose, transient_s=0.0)
    counts = sim.next_block(1001).gyro  # 10 s at rest
    rates = np.linalg.solve(truth.gyro.S, (counts - truth.gyro.bias).T).T
    earth = position_dcm(*pose, truth.alpha0, truth.beta0) @ earth_rate_level(
        truth.latitude, truth.heading
    )
    with_earth = mv.matrix_to_rotvec(mv.move_rotation(rates, 0.01, earth))
    without = mv.matrix_to_rotvec(mv.move_rotation(rates, 0.01, None))
    assert np.linalg.norm(with_earth) < 1e-9
    np.testing.assert_allclose(-without, earth * 10.0, rtol=1e-6)


def test_s_recovered_with_std_at_the_cramer_rao_bound() -> None:
    """Monte Carlo, 200 fixed seeds: std/CRLB per entry of S, and no bias beyond 4σ/√N."""
    S, bias = _true_s(np.random.default_rng(7)), np.array([12.0, -30.0, 5.0])
    sigma = 2.0
    estimates = []
    for trial in range(200):
        moves = _synthetic_moves(np.random.default_rng(1000 + trial), S, bias, sigma, TURNS)
        fit = mv.solve_moves(moves, bias, NOMINAL_S, [sigma] * 3)
        assert fit.identifiable.all()
        estimates.append(fit.S.reshape(9))
    est = np.array(estimates)
    bound = np.sqrt(np.diag(mv.crlb(moves, bias, S, fit.sigmas_rad)))
    ratio = est.std(axis=0, ddof=1) / bound
    assert ratio.mean() <= 1.1 and ratio.max() <= 1.25, ratio
    assert ratio.min() > 0.75, ratio  # σ not inflated either
    z = (est.mean(axis=0) - S.reshape(9)) / (bound / np.sqrt(len(est)))
    assert np.all(np.abs(z) < 4.0), z


def test_reported_sigma_matches_the_scatter() -> None:
    S, bias = _true_s(np.random.default_rng(8)), np.zeros(3)
    z = []
    for trial in range(40):
        moves = _synthetic_moves(np.random.default_rng(50 + trial), S, bias, 3.0, TURNS)
        fit = mv.solve_moves(moves, bias, NOMINAL_S, [3.0] * 3)
        z.append(((fit.S - S) / fit.S_sigma).reshape(9))
    assert 0.7 < np.std(z) < 1.3
    assert np.all(np.abs(np.asarray(z)) < 5.0)


def test_sigma_counts_the_errors_moves_share_through_their_positions() -> None:
    """Monte Carlo over sessions of moves between positions set to within their tolerance.

    The errors of S against the truth, normalised by the fit's covariance, spread as χ²(9)
    per session (GLS over eq. F2). Weighing the same moves as if each pose's error were the
    move's own (``√2 · tolerance`` per move, no shared mean gyro) gives a σ that the same
    check refuses: this check can tell an honest σ from an optimistic one.
    """
    S, bias = _true_s(np.random.default_rng(22)), np.array([12.0, -30.0, 5.0])
    sigma, tolerance, trials = 3.0, np.deg2rad(0.05), 120
    gls, independent = [], []
    for trial in range(trials):
        moves, b0, shared = _position_chain(
            np.random.default_rng(9000 + trial), S, bias, sigma, tolerance, n_mean=100
        )
        fit = mv.solve_moves(moves, b0, NOMINAL_S, [sigma] * 3, shared=shared)
        gls.append(mahalanobis(fit.S - S, fit.covariance))
        alone = [
            dataclasses.replace(m, sigma_rad=np.sqrt(2.0) * tolerance, positions=None)
            for m in moves
        ]
        naive = mv.solve_moves(alone, b0, NOMINAL_S, [sigma] * 3)
        independent.append(mahalanobis(naive.S - S, naive.covariance))
    low, high = chi2_ratio_band(9 * trials, comparisons=2)
    assert low <= np.mean(gls) / 9 <= high, (np.mean(gls) / 9, low, high)
    assert np.mean(independent) / 9 > high, (np.mean(independent) / 9, high)


def test_moves_through_one_position_correlate_as_predicted() -> None:
    """Residuals of two moves through one position, at the true S, over many draws (F1–F2).

    Whitened by the predicted covariance ``R`` (which has the −½ correlation of the shared
    pose and its bias term) they must be uncorrelated with unit variance.
    """
    S, bias, draws = _true_s(np.random.default_rng(4)), np.array([5.0, -2.0, 9.0]), 400
    white = []
    for draw in range(draws):
        moves, b0, shared = _position_chain(
            np.random.default_rng(700 + draw), S, bias, 3.0, np.deg2rad(0.05), 20, n_positions=3
        )
        parts = [mv._residual_parts(m, S, b0, None) for m in moves]
        sigmas = [mv.move_sigma(m, np.full(3, 3.0), S) for m in moves]
        cov = mv.residual_covariance(moves, [p[2] for p in parts], np.array(sigmas), shared)
        r = np.concatenate([p[0] for p in parts])
        white.append(np.linalg.solve(np.linalg.cholesky(cov), r))
    emp = np.cov(np.array(white).T)
    assert np.max(np.abs(emp - np.eye(6))) < 5.0 / np.sqrt(draws), np.round(emp, 2)


def test_column_without_a_turn_is_not_identifiable() -> None:
    S, bias = _true_s(np.random.default_rng(9)), np.zeros(3)
    turns = [((1, 0, 0), np.pi / 2), ((0, 1, 0), np.pi / 2), ((1, 1, 0), -np.pi / 2)]
    moves = _synthetic_moves(np.random.default_rng(1), S, bias, 2.0, turns)
    fit = mv.solve_moves(moves, bias, NOMINAL_S, [2.0] * 3)
    assert fit.identifiable.tolist() == [True, True, False]
    assert np.all(np.isnan(fit.S[:, 2])) and np.all(np.isnan(fit.S_sigma[:, 2]))
    assert "S_xz" not in fit.names and "S_zy" in fit.names
    assert any("column z not identifiable" in note for note in fit.notes)
    assert np.all(np.abs(fit.S[:, :2] - S[:, :2]) < 4.0 * fit.S_sigma[:, :2])
    np.testing.assert_array_equal(fit.S_used()[:, 2], NOMINAL_S[:, 2])


def test_held_out_moves_integrate_to_their_angles_within_sigma() -> None:
    """Moves not used in the fit: chi² of their turn errors, before and after calibration."""
    S, bias = _true_s(np.random.default_rng(10)), np.array([3.0, 4.0, -5.0])
    rng = np.random.default_rng(11)
    fit = mv.solve_moves(_synthetic_moves(rng, S, bias, 2.0, TURNS), bias, NOMINAL_S, [2.0] * 3)
    axes = rng.normal(size=(30, 3))
    held = _synthetic_moves(rng, S, bias, 2.0, [(tuple(a), 1.2) for a in axes])
    chi2_after, worst_before = [], 0.0
    for move in held:
        e, jac = mv.move_residual(move, fit.S_used(), bias)
        cov = jac @ fit.covariance @ jac.T + mv.move_sigma(move, np.full(3, 2.0), S) ** 2 * np.eye(
            3
        )
        chi2_after.append(float(e @ np.linalg.solve(cov, e)))
        before = mv.integrated_turn(move, NOMINAL_S, bias) - move.turn_rad
        worst_before = max(worst_before, float(np.linalg.norm(before)))
    assert 0.6 < np.mean(chi2_after) / 3.0 < 1.5, chi2_after
    assert max(chi2_after) < 25.0
    assert worst_before > 100 * np.sqrt(np.median(chi2_after)) * mv.move_sigma(
        held[0], np.full(3, 2.0), S
    )


def test_full_turn_reads_its_angle() -> None:
    S, bias = _true_s(np.random.default_rng(12)), np.zeros(3)
    n = 301
    _, ds = min_jerk(np.linspace(0.0, 1.0, n))
    w = np.outer(ds / 3.0 * -2 * np.pi, [0.0, 1.0, 0.0])
    move = mv.turn_move(bias + w @ S.T, 0.01, axis=1, angle_rad=-2 * np.pi, sigma_rad=0.0)
    turn = mv.integrated_turn(move, S, bias)
    np.testing.assert_allclose(turn, [0.0, -2 * np.pi, 0.0], atol=1e-6)
    raw = mv.integrated_turn(move, NOMINAL_S, bias)
    assert raw[1] == pytest.approx(-2 * np.pi * S[1, 1] * DEFAULT_GYRO_LSB, rel=2e-3)


def test_no_moves_is_an_input_error() -> None:
    from canimucal.errors import InputError

    with pytest.raises(InputError, match="no moves"):
        mv.solve_moves([], np.zeros(3), NOMINAL_S, [1.0] * 3)
