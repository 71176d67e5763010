"""The procedure's S from its confirmed moves: its σ is honest over a sweep of seeds.

The procedure is fed straight from the simulator (no CAN), the operator sets every pose off
by a draw from its tolerance (as the demo's does), and the unit's S is off nominal. Over
fixed seeds, the errors of S against the truth, normalised by the reported covariance, must
spread as χ² does: a σ that forgets the errors moves share through their positions (each
pose's attitude, each position's mean gyro) is ~15 % optimistic and the z of single entries
reached 4σ.
"""

from __future__ import annotations

import numpy as np

from canimucal.procedure import events as ev
from canimucal.procedure.machine import Phase
from canimucal.runtime.wiring import spec_for_plan
from canimucal.sim.truth import Truth
from tests.support.chi2_band import chi2_ratio_band, mahalanobis
from tests.support.moves import turns_plan
from tests.support.procedure_bench import Bench, of

S_NAMES = [f"gyro.S[{i}][{j}]" for i in range(3) for j in range(3)]
SEEDS = range(12)


def _session_error(seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """S − truth, its reported σ and covariance (9, 9) of one simulated session."""
    truth = Truth.random(
        np.random.default_rng(seed),
        scale_error_max=0.03,
        cross_axis_max=0.01,
        tilt_max_deg=0.0,
        gyro_g_max=0.5,
        sample_rate_hz=50,
    )
    spec = spec_for_plan("custom", "mems", gyro_g=True)
    bench = Bench([truth], turns_plan(seconds=2.0), seed=seed, spec=spec)
    operator = np.random.default_rng(seed + 1000)
    while bench.proc.phase is not Phase.READY_TO_SOLVE:
        target = bench.proc.target
        placed = target.angles + operator.normal(0.0, target.tolerances)
        for sim in bench.sims.values():
            sim.set_pose(*placed, transient_s=1.0)
        bench.run(1.5, block_n=25)
        bench.do("confirm_pose")
        bench.run_until(ev.PositionAveraged, 60.0, block_n=25)
        bench.do("accept")
    record = of(bench.do("solve"), ev.Solved)[0].solutions[0x10].record
    assert record.gyro is not None and record.covariance is not None
    S = np.array(record.gyro.S, dtype=float)
    sigma = np.array(record.gyro.S_sigma, dtype=float)
    order = list(record.covariance.order)
    idx = [order.index(n) for n in S_NAMES]
    cov = np.array(record.covariance.matrix, dtype=float)[np.ix_(idx, idx)]
    return (S - truth.gyro.S).reshape(9), sigma.reshape(9), cov


def test_session_sigma_of_s_is_honest_over_a_seed_sweep() -> None:
    errors, sigmas, d2 = [], [], []
    for seed in SEEDS:
        d, sigma, cov = _session_error(seed)
        assert np.all(np.isfinite(d)), f"seed {seed}: every column of S is identifiable"
        errors.append(d)
        sigmas.append(sigma)
        d2.append(mahalanobis(d, cov))
    z = np.array(errors) / np.array(sigmas)
    n = len(SEEDS)
    assert np.max(np.abs(z)) < 4.0, np.round(z, 2)
    low, high = chi2_ratio_band(9 * n)
    assert low <= np.mean(d2) / 9 <= high, (np.round(d2, 1), low, high)
    low, high = chi2_ratio_band(n, comparisons=9)
    per_entry = np.mean(z**2, axis=0)
    assert np.all((low <= per_entry) & (per_entry <= high)), (np.round(per_entry, 2), low, high)
