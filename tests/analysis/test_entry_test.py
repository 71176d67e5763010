"""The per-entry candidate test and weighted Holm (significance.entry_test, forward_select).

Simulated linear problems (no CAN, no simulator): 20 positions × 3 rows, a 2-column base
model, and three candidates of 2, 6 and 9 random columns (fixed design), the family's
weight 17 (every entry once). Seeds fixed; bounds are binomial statements given in each test.
"""

from __future__ import annotations

import numpy as np
from scipy import stats

from canimucal.analysis.significance import (
    GROUP_SHARE,
    LinearProblem,
    entry_test,
    entry_weights,
    forward_select,
    holm_adjust,
    nested_test,
)

N_BLOCKS, ROWS = 20, 3
N = N_BLOCKS * ROWS


def _design(seed: int) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    rng = np.random.default_rng(seed)
    base = np.column_stack([np.ones(N), rng.normal(size=N)])
    cols = {"a.two": rng.normal(size=(N, 2)), "a.six": rng.normal(size=(N, 6))}
    cols["b.nine"] = rng.normal(size=(N, 9))
    return base, cols


def _problem(base: np.ndarray, residual: np.ndarray) -> LinearProblem:
    return LinearProblem(
        residual_w=residual,
        base_w=base,
        block=np.repeat(np.arange(N_BLOCKS), ROWS),
        unwhiten=np.eye(N),
        si_scale=np.ones(N),
        sensor=np.array(["accel"] * N),
    )


def test_weighted_holm_matches_hand_computed_values() -> None:
    # p/w = 0.001, 0.0025, 0.04; total weight 7, then 5 (after the 2-weight), then 1:
    # 0.001·7 = 0.007, max(0.007, 0.0025·5) = 0.0125, max(0.0125, 0.04·1) = 0.04
    adjusted = holm_adjust([0.002, 0.01, 0.04], [2.0, 4.0, 1.0])
    assert np.allclose(adjusted, [0.007, 0.0125, 0.04])
    assert np.allclose(holm_adjust([0.04, 0.001, 0.01]), holm_adjust([0.04, 0.001, 0.01], [1] * 3))


def test_entry_test_is_the_weighted_bonferroni_of_entries_and_group() -> None:
    base, cols = _design(1)
    noise = np.random.default_rng(2).normal(size=N)
    problem = _problem(base, noise + 0.4 * cols["a.six"][:, 3])  # one entry, about 3σ
    test = entry_test(problem, cols, [], "a.six")
    singles = [
        nested_test(problem, {"x": cols["a.six"][:, k : k + 1]}, [], "x").p_value for k in range(6)
    ]
    group = nested_test(problem, cols, [], "a.six").p_value
    expected = min(1.0, 6 * min(singles) / (1 - GROUP_SHARE), group / GROUP_SHARE)
    assert 1e-6 < test.p_value < 0.5
    assert np.isclose(test.p_value, expected)
    assert (test.df, test.entries) == (1, 6)
    assert entry_weights(problem, cols) == {"a.two": 2, "a.six": 6, "b.nine": 9}
    # an effect spread evenly over the six entries: the group test carries it
    spread = _problem(base, noise + cols["a.six"] @ np.full(6, 0.3))
    test = entry_test(spread, cols, [], "a.six")
    assert test.df == 6
    assert np.isclose(test.p_value, nested_test(spread, cols, [], "a.six").p_value / GROUP_SHARE)


def test_family_wise_size_on_clean_problems() -> None:
    # 400 null problems at α = 5 %: the weighted Holm selection names anything on at most
    # 5 % of them (Bonferroni over 17 nearly independent entries: 4.9 %). Any-rejection
    # count ~ Bin(400, ≤ 0.05): P(≥ 35) = 0.001 at 0.05; and the test is not empty:
    # P(Bin(400, 0.045) ≤ 7) = 0.002.
    base, cols = _design(3)
    rng = np.random.default_rng(4)
    weights = entry_weights(_problem(base, np.zeros(N)), cols)
    alarms = 0
    for _ in range(400):
        problem = _problem(base, rng.normal(size=N))
        chosen = forward_select(
            problem, cols, alpha=0.05, family_size=sum(weights.values()), weights=weights
        )
        alarms += bool(chosen)
    assert 8 <= alarms <= 34, alarms


def test_one_planted_entry_beats_the_group_test() -> None:
    # One entry of the 6-entry candidate at non-centrality 25 (5σ off the base model) in
    # 300 problems, family-wise α = 1 %. Analytic power: per-entry test at 0.8 α/17 per entry
    # (GROUP_SHARE 0.2 goes to the group test) 0.934; the 6-dof group test alone at Holm's
    # first step (α/3) 0.867. The selection must name exactly that candidate in ≥ 90 %
    # (P(Bin(300, 0.934) < 270) = 0.008) and beat the group test on the same problems
    # (expected margin 20, sd of the paired difference about 6).
    base, cols = _design(5)
    rng = np.random.default_rng(6)
    q, _ = np.linalg.qr(base)
    col = cols["a.six"][:, 2]
    off = col - q @ (q.T @ col)
    size = 5.0 / float(np.linalg.norm(off))
    weights = entry_weights(_problem(base, np.zeros(N)), cols)
    crit_group = stats.chi2.isf(0.01 / 3, 6)
    entry_hits = group_hits = 0
    for _ in range(300):
        problem = _problem(base, rng.normal(size=N) + size * col)
        chosen = forward_select(problem, cols, alpha=0.01, family_size=17.0, weights=weights)
        entry_hits += chosen == ["a.six"]
        group_hits += nested_test(problem, cols, [], "a.six").statistic > crit_group
    assert entry_hits >= 270, entry_hits
    assert entry_hits > group_hits, (entry_hits, group_hits)
