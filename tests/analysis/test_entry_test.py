"""The per-entry candidate test and weighted Holm (significance.entry_test, forward_select).

Simulated linear problems (no CAN, no simulator): 20 positions × 3 rows, a 2-column base
model, and three candidates of 2, 6 and 9 random columns (fixed design), the family's
weight 17 (every entry once). Seeds fixed; bounds are binomial statements given in each test.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from scipy import stats

from canimucal.analysis.noise_model import ScatterModel, scatter_f_test
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


def test_entries_with_estimated_scatter_are_satterthwaite_f_tests() -> None:
    # 8 positions × 3 rows ruled by a 0.1° pose scatter (τ estimated), 9 base columns and a
    # 3-entry candidate, one entry planted: every single-entry test is scatter_f_test on that
    # one column (F(1, ν) with the entry's own ν), the group test is scatter_f_test on the
    # three; entry_test combines them by the weighted Bonferroni. With τ held, the same
    # problem gets the known-noise χ² ("LR").
    rng = np.random.default_rng(11)
    n, m = 8, 3
    size = n * m
    unit = np.zeros((size, size))
    for k in range(n):
        j = rng.normal(0.0, 1500.0, (m, 3))
        unit[k * m : (k + 1) * m, k * m : (k + 1) * m] = j @ j.T
    model = ScatterModel(np.eye(size) * 3e-3, unit, "estimated")
    chol = np.linalg.cholesky(model.covariance(float(np.deg2rad(0.1))))
    base, cand = rng.normal(size=(size, 9)), rng.normal(size=(size, 3))
    raw = base @ rng.normal(size=9) + 4.0 * cand[:, 1] + chol @ rng.normal(size=size)
    inv = np.linalg.inv(chol)
    problem = LinearProblem(
        residual_w=inv @ raw,
        base_w=inv @ base,
        block=np.repeat(np.arange(n), m),
        unwhiten=chol,
        si_scale=np.ones(size),
        sensor=np.array(["accel"] * size),
        scatter=model,
    )
    cols = {"a.three": inv @ cand}
    singles = [
        scatter_f_test(model, raw, base, np.column_stack([base, cand[:, k]])) for k in range(3)
    ]
    group = scatter_f_test(model, raw, base, np.hstack([base, cand]))
    assert group is not None and all(s is not None and s.q == 1 for s in singles)
    nus = [s.nu for s in singles if s is not None]
    assert all(2.0 <= nu < 1e7 for nu in nus) and len(set(np.round(nus, 6))) > 1
    p_min = min(s.p_value for s in singles if s is not None)
    expected = min(1.0, 3 * p_min / (1 - GROUP_SHARE), group.p_value / GROUP_SHARE)
    test = entry_test(problem, cols, [], "a.three")
    assert test.kind == "F (Satterthwaite)"
    assert 1e-9 < test.p_value < 0.5 and np.isclose(test.p_value, expected)
    assert np.isclose(nested_test(problem, cols, [], "a.three").p_value, group.p_value)
    held = entry_test(dataclasses.replace(problem, scatter=None), cols, [], "a.three")
    assert held.kind == "LR"
