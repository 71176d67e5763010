"""Nested-model tests on a linearised fit: likelihood ratio / F, Holm, cross-validation.

Every model of the discrepancy loop is the base fit plus a few extra terms. Around the base
estimate the whitened residuals ``r`` of the per-position means are linear in the parameters:
``r ≈ J δ + X β + e`` with ``J`` the base model's whitened Jacobian and ``X`` the whitened
derivatives of the extra terms (one Gauss–Newton step; the effects tested are small, so the
step is exact to well below the noise). Then, for a candidate with ``q`` columns,

- ``Δχ² = χ²(base) − χ²(base + candidate)`` is χ²(q) under the null when the whitening is
  right (likelihood-ratio test with known noise), and
- ``F = (Δχ²/q) / (χ²_ext/ν)`` is F(q, ν) when the noise level itself is in doubt (after
  drift inside the positions was found), and
- with the pose-setting scatter estimated from the same residuals, ``F = Δχ²/q`` at the
  larger model's REML scatter is referred to F(q, ν) with Satterthwaite's ν
  (:func:`~canimucal.analysis.noise_model.scatter_f_test`).

A candidate of ``q`` entries is tested entry by entry (:func:`entry_test`: the largest of
its 1-dof tests, Bonferroni over the entries), because an effect usually sits in one entry
and a ``q``-dof group test dilutes it. Holm's step-down procedure, weighted by each
candidate's number of entries (:func:`holm_adjust`), controls the family-wise error of the
candidates: every entry of every candidate gets the same share of α. The forward selection
adds, at step k, the term of smallest ``p/w`` if it beats ``α/(W − Σ w_chosen)``, which is
weighted Holm applied to the terms in the order they enter. Leave-one-position-out
cross-validation uses the block form of the PRESS residual, ``e_P = (I − H_PP)⁻¹ r_P``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from canimucal.analysis.noise_model import ScatterModel, scatter_f_test

Array = NDArray[np.float64]

RANK_TOLERANCE = 1e-8
"""Relative singular value under which a candidate column adds nothing (not identifiable)."""


@dataclass(frozen=True)
class LinearProblem:
    """The linearised base fit of one data set.

    ``residual_w`` ``(N,)`` whitened residuals of the base fit; ``base_w`` ``(N, p)`` its
    whitened Jacobian; ``block`` ``(N,)`` the position of each row (for cross-validation);
    ``unwhiten`` ``(N, N)`` maps whitened rows back to raw residuals; ``si_scale`` ``(N,)``
    turns a raw residual into SI units (nominal LSB); ``sensor`` ``(N,)`` ``accel``/``gyro``.
    ``scatter``, when given, is the noise family whose pose-setting scatter each nested test
    estimates by REML in its larger model, the test then Satterthwaite's F
    (:func:`.noise_model.scatter_f_test`); None: the whitening is the known noise (χ²).
    """

    residual_w: Array
    base_w: Array
    block: NDArray[np.int64]
    unwhiten: Array
    si_scale: Array
    sensor: NDArray[np.str_]
    scatter: ScatterModel | None = None


@dataclass(frozen=True)
class TermFit:
    """A fit of the base model plus some terms: coefficients of the terms, χ², dof."""

    terms: tuple[str, ...]
    coefficients: Mapping[str, Array]
    sigmas: Mapping[str, Array]
    residual_w: Array
    chi2: float
    dof: int
    base_delta: Array


def _design(problem: LinearProblem, columns: Mapping[str, Array], terms: Sequence[str]) -> Array:
    parts = [problem.base_w] + [columns[t] for t in terms]
    return np.hstack(parts) if parts else np.zeros((problem.residual_w.size, 0))


def effective_rank(problem: LinearProblem, columns: Array) -> int:
    """Count the directions ``columns`` add to the base model's column space."""
    if columns.shape[1] == 0:
        return 0
    return _rank_off(np.linalg.qr(problem.base_w)[0], columns)


def _rank_off(q: Array, columns: Array) -> int:
    """Directions ``columns`` add to the span of the orthonormal ``q``."""
    if columns.shape[1] == 0:
        return 0
    rest = columns - q @ (q.T @ columns)
    sv = np.linalg.svd(rest, compute_uv=False)
    scale = max(float(np.max(np.linalg.norm(columns, axis=0))), 1e-300)
    return int(np.sum(sv > RANK_TOLERANCE * scale))


def fit_terms(
    problem: LinearProblem, columns: Mapping[str, Array], terms: Sequence[str]
) -> TermFit:
    """Least-squares fit of the base model plus ``terms`` to the whitened residuals."""
    a = _design(problem, columns, terms)
    coef, *_ = np.linalg.lstsq(a, problem.residual_w, rcond=None)
    resid = problem.residual_w - a @ coef
    rank = int(np.linalg.matrix_rank(a)) if a.size else 0
    cov = np.linalg.pinv(a.T @ a) if a.size else np.zeros((0, 0))
    out: dict[str, Array] = {}
    sig: dict[str, Array] = {}
    k = problem.base_w.shape[1]
    for t in terms:
        width = columns[t].shape[1]
        out[t] = np.asarray(coef[k : k + width], dtype=float)
        sig[t] = np.sqrt(np.abs(np.diag(cov)[k : k + width]))
        k += width
    chi2 = float(resid @ resid)
    return TermFit(
        tuple(terms),
        out,
        sig,
        resid,
        chi2,
        resid.size - rank,
        np.asarray(coef[: problem.base_w.shape[1]], dtype=float),
    )


@dataclass(frozen=True)
class NestedTest:
    """One nested-model test: statistic, its degrees of freedom and the raw p-value.

    ``entries`` is the number of single-entry tests a per-entry test took the largest of
    (its p-value is already corrected for them); 1 for a group test. ``column`` is the
    index, within the term's columns, of the entry whose test gave the p-value (None for a
    group test).
    """

    term: str
    statistic: float
    df: int
    p_value: float
    kind: str
    entries: int = 1
    column: int | None = None


def nested_test(
    problem: LinearProblem,
    columns: Mapping[str, Array],
    smaller: Sequence[str],
    term: str,
    *,
    use_f: bool = False,
) -> NestedTest:
    """Test ``smaller + [term]`` against ``smaller``: LR χ² (known noise) or F (noise unknown).

    The group test of all of ``term``'s entries at once, ``q`` dof. With ``problem.scatter``
    estimated (and no F test) the pose-setting scatter is the larger model's REML estimate
    and the test is Satterthwaite's F (:func:`.noise_model.scatter_f_test`); with it fixed,
    the known-noise χ².
    """
    ref = _Smaller(problem, columns, smaller, use_f)
    q = ref.gain(columns[term])
    if q <= 0:
        return NestedTest(term, 0.0, 0, 1.0, "none")
    return ref.test(term, columns[term], q)


def entry_test(
    problem: LinearProblem,
    columns: Mapping[str, Array],
    smaller: Sequence[str],
    term: str,
    *,
    use_f: bool = False,
) -> NestedTest:
    """Test ``term`` entry by entry beside ``smaller``, and as a group; Bonferroni over both.

    Every entry (column) of ``term`` that adds a direction to ``smaller`` gets the 1-dof
    test of :func:`nested_test`, and the whole term its ``q``-dof group test. With ``m``
    such entries, ``p_min`` the smallest entry p-value, ``p_group`` the group test's and
    ``ε = GROUP_SHARE``, the test of the whole term (null: every entry zero) has

        p = min(1, m · p_min / (1 − ε), p_group / ε)              (weighted Bonferroni)

    so its size stays at most the nominal level whatever the correlation of the entries.
    Against a term whose effect sits in one entry the entry tests are far more powerful
    than the group test, whose statistic spreads that entry's non-centrality over ``q``
    dof: at non-centrality 25 and α = 1 %/9, the 6-entry group test has power 0.79, the
    per-entry test 0.90 (critical z = √χ²₁ at ``α/(9·6)``: 3.74 against a mean of 5).
    Against an effect spread over many entries (a real misalignment, a tilt) the group
    test is the stronger one, the more so when the pose scatter is estimated: one entry
    alone leaves most of the misfit to be absorbed by a larger scatter. The statistic
    reported is that of the test giving ``p`` (``entries`` 1 for the group test).
    """
    ref = _Smaller(problem, columns, smaller, use_f)
    block = columns[term]
    tests = {}
    for k in range(block.shape[1]):
        col = block[:, k : k + 1]
        if ref.gain(col) == 1:
            tests[k] = ref.test(term, col, 1)
    if not tests:
        return NestedTest(term, 0.0, 0, 1.0, "none")
    column = min(tests, key=lambda k: (tests[k].p_value, -tests[k].statistic))
    best = tests[column]
    m = len(tests)
    q = ref.gain(block)
    entry_p = m * best.p_value / (1.0 - GROUP_SHARE if q > 1 else 1.0)
    if q > 1:
        group = ref.test(term, block, q)
        if group.p_value / GROUP_SHARE < entry_p:
            return NestedTest(term, group.statistic, q, min(1.0, group.p_value / GROUP_SHARE),
                              group.kind)  # fmt: skip
    return NestedTest(term, best.statistic, 1, min(1.0, entry_p), best.kind, m, column)


GROUP_SHARE = 0.2
"""Share of a candidate's α given to its group test in :func:`entry_test` (the rest: entries)."""


class _Smaller:
    """The smaller model of a nested comparison, fitted once for several larger ones."""

    def __init__(
        self,
        problem: LinearProblem,
        columns: Mapping[str, Array],
        smaller: Sequence[str],
        use_f: bool,
    ) -> None:
        self.problem, self.columns, self.smaller, self.use_f = problem, columns, smaller, use_f
        stacked = [columns[t] for t in smaller]
        self.stacked = np.hstack(stacked) if stacked else np.zeros((problem.base_w.shape[0], 0))
        self.q_base = np.linalg.qr(problem.base_w)[0]
        self.rank = _rank_off(self.q_base, self.stacked)
        self.design = _design(problem, columns, smaller)
        self.chi2 = _chi2_dof(self.design, problem.residual_w)[0]
        self.raw_r = problem.unwhiten @ problem.residual_w
        self.raw_design = problem.unwhiten @ self.design

    def gain(self, extra: Array) -> int:
        """Directions ``extra`` adds to the smaller model."""
        return _rank_off(self.q_base, np.hstack([self.stacked, extra])) - self.rank

    def test(self, term: str, extra: Array, q: int) -> NestedTest:
        """Test the smaller model plus ``extra`` (``q`` new directions) against it."""
        from scipy import special  # lazy (issue 23): loads with a test, not with the module

        problem = self.problem
        design = np.hstack([self.design, extra])
        chi2, dof = _chi2_dof(design, problem.residual_w)
        delta = max(self.chi2 - chi2, 0.0)
        if self.use_f and dof > 0:
            f = (delta / q) / max(chi2 / dof, 1e-300)
            return NestedTest(term, f, q, float(special.fdtrc(q, dof, f)), "F")
        if problem.scatter is not None and problem.scatter.fixed is None:
            raw_big = np.hstack([self.raw_design, problem.unwhiten @ extra])
            test = scatter_f_test(problem.scatter, self.raw_r, self.raw_design, raw_big)
            if test is None:
                return NestedTest(term, 0.0, 0, 1.0, "none")
            return NestedTest(term, test.statistic, test.q, test.p_value, "F (Satterthwaite)")
        return NestedTest(term, delta, q, float(special.chdtrc(q, delta)), "LR")


def _chi2_dof(design: Array, residual: Array) -> tuple[float, int]:
    """χ² and residual dof of the least-squares fit of ``residual`` on ``design``."""
    if design.shape[1] == 0:
        return float(residual @ residual), residual.size
    u, sv, _ = np.linalg.svd(design, full_matrices=False)
    tol = float(sv[0]) * max(design.shape) * np.finfo(float).eps if sv.size else 0.0
    u = u[:, sv > tol]
    resid = residual - u @ (u.T @ residual)
    return float(resid @ resid), residual.size - u.shape[1]


def holm_adjust(p_values: Sequence[float], weights: Sequence[float] | None = None) -> Array:
    """Holm step-down adjusted p-values (monotone, capped at 1), weighted when asked.

    Weighted Holm (Holm 1979, §5): hypotheses are taken in increasing ``p_i / w_i``; at step
    ``j`` the adjusted value is ``max_{i ≤ j} min(1, (p_(i) / w_(i)) · Σ_{k ≥ i} w_(k))``, so
    that ``H_i`` is rejected at level α when ``p_i / w_i ≤ α / (weight still untested)``.
    Equal weights give the usual ``(m − rank) · p``.
    """
    p = np.asarray(p_values, dtype=float)
    w = np.ones(p.size) if weights is None else np.asarray(weights, dtype=float)
    ratio = p / w
    order = np.argsort(ratio, kind="stable")
    left = float(np.sum(w))
    adjusted = np.empty(p.size)
    running = 0.0
    for idx in order:
        running = max(running, min(1.0, ratio[idx] * left))
        adjusted[idx] = running
        left -= float(w[idx])
    return adjusted


def entry_weights(problem: LinearProblem, columns: Mapping[str, Array]) -> dict[str, int]:
    """Count the entries of each term that add a direction to the base model on their own.

    A term's weight in the weighted Holm procedure of :func:`forward_select`: the family is
    then, in effect, every single entry of every candidate (the per-entry tests of
    :func:`entry_test`), each with the same share of α.
    """
    return {
        key: sum(effective_rank(problem, col[:, k : k + 1]) for k in range(col.shape[1]))
        for key, col in columns.items()
    }


def forward_select(
    problem: LinearProblem,
    columns: Mapping[str, Array],
    *,
    alpha: float,
    family_size: float,
    use_f: bool = False,
    weights: Mapping[str, float] | None = None,
) -> list[str]:
    """Add terms in order of significance while weighted Holm's step-down test passes.

    Each term is tested by :func:`entry_test` beside the terms already chosen. With
    weights ``w`` (default 1 each) and ``family_size`` the family's total weight ``W``
    (terms, and the other tests of the family that share α), step ``k`` adds the term of
    smallest ``p / w`` if ``p / w < α / (W − Σ w_chosen)`` (weighted Holm, see
    :func:`holm_adjust`). Then any chosen term whose test against all the others chosen no
    longer passes ``p / w < α / W`` is dropped (a term that only stood in for one chosen
    later).
    """
    w = {t: 1.0 for t in columns} if weights is None else weights
    chosen: list[str] = []
    remaining = list(columns)
    left = float(family_size)
    while remaining:
        tests = [entry_test(problem, columns, chosen, t, use_f=use_f) for t in remaining]
        best = min(tests, key=lambda s: _per_weight(s.p_value, w[s.term]))
        if left <= 0.0 or _per_weight(best.p_value, w[best.term]) >= alpha / left:
            break
        chosen.append(best.term)
        remaining.remove(best.term)
        left -= w[best.term]
    for term in list(chosen):
        others = [t for t in chosen if t != term]
        test = entry_test(problem, columns, others, term, use_f=use_f)
        if _per_weight(test.p_value, w[term]) >= alpha / family_size:
            chosen.remove(term)
    return chosen


def _per_weight(p: float, w: float) -> float:
    return p / w if w > 0 else float("inf")


MIN_HOLDOUT = 0.05
"""Directions of a position's block with ``1 − leverage`` below this cannot be held out."""


def loo_residuals(problem: LinearProblem, design: Array, resid: Array) -> Array:
    """Leave-one-position-out prediction residuals (whitened), block PRESS form.

    ``e_P = (I − H_PP)⁻¹ r_P``, inverted only over the directions with ``1 − leverage ≥
    MIN_HOLDOUT``: with angle errors a tilted position's covariance is nearly singular, so
    that position alone fixes one direction, and its held-out residual there says nothing.
    """
    if design.shape[1] == 0:
        return resid.copy()
    pinv = np.linalg.pinv(design.T @ design)
    out = np.empty_like(resid)
    for b in np.unique(problem.block):
        rows = np.flatnonzero(problem.block == b)
        h = design[rows] @ pinv @ design[rows].T
        lam, vec = np.linalg.eigh(np.eye(rows.size) - 0.5 * (h + h.T))
        inv = np.where(lam >= MIN_HOLDOUT, 1.0 / np.maximum(lam, MIN_HOLDOUT), 0.0)
        out[rows] = vec @ (inv * (vec.T @ resid[rows]))
    return out


def si_rms(problem: LinearProblem, resid_w: Array, sensor: str) -> float:
    """Root mean square of the raw residuals of ``sensor`` in SI units (NaN if it has none)."""
    raw = problem.unwhiten @ resid_w * problem.si_scale
    mask = problem.sensor == sensor
    return float(np.sqrt(np.mean(raw[mask] ** 2))) if mask.any() else float("nan")


@dataclass(frozen=True)
class ModelScore:
    """rms and leave-one-position-out cv_rms of one model, per sensor (SI units)."""

    terms: tuple[str, ...]
    rms: Mapping[str, float]
    cv_rms: Mapping[str, float]
    cv_chi2: float


def score_model(
    problem: LinearProblem, columns: Mapping[str, Array], terms: Sequence[str]
) -> ModelScore:
    """Score the base model plus ``terms``: rms, cv_rms and the whitened PRESS (cv_chi2)."""
    fit = fit_terms(problem, columns, terms)
    design = _design(problem, columns, terms)
    loo = loo_residuals(problem, design, fit.residual_w)
    sensors = sorted(set(problem.sensor.tolist()))
    return ModelScore(
        tuple(terms),
        {s: si_rms(problem, fit.residual_w, s) for s in sensors},
        {s: si_rms(problem, loo, s) for s in sensors},
        float(loo @ loo),
    )


def _press(problem: LinearProblem, columns: Mapping[str, Array], terms: Sequence[str]) -> float:
    """Whitened leave-one-position-out PRESS of the base model plus ``terms``."""
    fit = fit_terms(problem, columns, terms)
    loo = loo_residuals(problem, _design(problem, columns, terms), fit.residual_w)
    return float(loo @ loo)


SPARSE_Z = 3.0
"""In cross-validation a term keeps only its entries beyond this many σ (at least one)."""


def significant_masks(
    problem: LinearProblem, columns: Mapping[str, Array], kept: Sequence[str]
) -> dict[str, NDArray[np.bool_]]:
    """Mark the entries of each kept term that earn their place (|z| ≥ SPARSE_Z, ≥ 1)."""
    fit = fit_terms(problem, columns, kept)
    out = {}
    for term in kept:
        z = np.abs(fit.coefficients[term]) / np.where(
            fit.sigmas[term] > 0, fit.sigmas[term], np.inf
        )
        out[term] = z >= min(SPARSE_Z, float(np.max(z)))
    return out


def significant_columns(
    problem: LinearProblem, columns: Mapping[str, Array], kept: Sequence[str]
) -> dict[str, Array]:
    """Zero the entries of each kept term that do not earn their place (|z| < SPARSE_Z).

    The columns keep their shape (a zero column gets a zero coefficient from the
    minimum-norm least squares), so coefficients still line up with the entry labels.
    """
    out = dict(columns)
    for term, keep in significant_masks(problem, columns, kept).items():
        out[term] = columns[term] * keep
    return out


def confirm_by_cv(
    problem: LinearProblem, columns: Mapping[str, Array], chosen: Sequence[str]
) -> list[str]:
    """Keep each chosen term only if it lowers the leave-one-position-out whitened PRESS.

    Each term enters with only its significant entries (a 9-entry G of which one is real
    would otherwise pay for eight idle ones in every held-out prediction).
    """
    kept = list(chosen)
    for term in list(kept):
        sparse = significant_columns(problem, columns, kept)
        without = [t for t in kept if t != term]
        if _press(problem, sparse, kept) > _press(problem, sparse, without):
            kept.remove(term)
    return kept


def canonical_correlation(cov: Array, a: slice, b: slice) -> Array:
    """Largest canonical correlation between the estimates of blocks ``a`` and ``b``.

    ``cov`` is a stack ``(k, p, p)`` of estimate covariances. The canonical correlation
    (Hotelling 1936) is the largest correlation between any linear combination of the ``a``
    estimates and any of the ``b`` estimates: the largest singular value of
    ``Σ_aa^(−1/2) Σ_ab Σ_bb^(−1/2)``. It is the correlation of two scalar estimates when each
    block has one entry (its magnitude), does not change when a block's entries are rescaled
    or mixed, and is at least the largest |correlation| of any entry pair. Entries with no
    variance (columns zeroed, directions no data determine: below 1e-12 of the block's
    largest eigenvalue) are left out; a block with none left gives 0.
    """

    def inverse_root(m: Array) -> Array:
        w, v = np.linalg.eigh(m)
        top = np.max(w, axis=1, keepdims=True)
        kept = w > np.maximum(top, 0.0) * 1e-12
        root = np.where(kept, 1.0 / np.sqrt(np.where(kept, w, 1.0)), 0.0)
        return np.asarray(np.einsum("kij,kj,klj->kil", v, root, v))

    whitened = inverse_root(cov[:, a, a]) @ cov[:, a, b] @ inverse_root(cov[:, b, b])
    if whitened.shape[1] == 0 or whitened.shape[2] == 0:
        return np.zeros(cov.shape[0])
    rho = np.linalg.svd(whitened, compute_uv=False)[:, 0]
    return np.asarray(np.minimum(rho, 1.0))


def pair_correlation(
    problem: LinearProblem, columns: Mapping[str, Array], terms: Sequence[str], a: str, b: str
) -> float:
    """Correlation of the estimates of ``a`` and ``b`` in the model holding ``terms`` (both in).

    The largest canonical correlation (:func:`canonical_correlation`) of the two candidates'
    coefficient blocks under the least-squares covariance ``(DᵀD)⁺`` of the whitened design.
    """
    design = _design(problem, columns, terms)
    cov = np.asarray(np.linalg.pinv(design.T @ design, hermitian=True), dtype=float)
    start, k = {}, problem.base_w.shape[1]
    for t in terms:
        start[t] = slice(k, k + columns[t].shape[1])
        k += columns[t].shape[1]
    return float(canonical_correlation(cov[None], start[a], start[b])[0])
