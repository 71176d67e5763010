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

Holm's step-down procedure controls the family-wise error of the candidates; the forward
selection adds, at step k, the smallest p-value if it beats ``α/(m − k)``, which is Holm's
procedure applied to the terms in the order they enter. Leave-one-position-out
cross-validation uses the block form of the PRESS residual, ``e_P = (I − H_PP)⁻¹ r_P``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy import stats

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
    re-estimates within each of its two models (:mod:`.noise_model`).
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
    q, _ = np.linalg.qr(problem.base_w)
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
    """One nested-model test: statistic, its degrees of freedom and the raw p-value."""

    term: str
    statistic: float
    df: int
    p_value: float
    kind: str


def nested_test(
    problem: LinearProblem,
    columns: Mapping[str, Array],
    smaller: Sequence[str],
    term: str,
    *,
    use_f: bool = False,
) -> NestedTest:
    """Test ``smaller + [term]`` against ``smaller``: LR χ² (known noise) or F (noise unknown).

    With ``problem.scatter`` (and no F test) the pose-setting scatter is the larger model's
    REML estimate and the test is Satterthwaite's F (:func:`.noise_model.scatter_f_test`).
    """
    q = effective_rank(problem, np.hstack([columns[t] for t in smaller] + [columns[term]]))
    q -= effective_rank(problem, np.hstack([columns[t] for t in smaller])) if smaller else 0
    if q <= 0:
        return NestedTest(term, 0.0, 0, 1.0, "none")
    small = fit_terms(problem, columns, smaller)
    big = fit_terms(problem, columns, [*smaller, term])
    delta = max(small.chi2 - big.chi2, 0.0)
    if use_f and big.dof > 0:
        f = (delta / q) / max(big.chi2 / big.dof, 1e-300)
        return NestedTest(term, f, q, float(stats.f.sf(f, q, big.dof)), "F")
    if problem.scatter is not None and problem.scatter.fixed is None:
        raw_r = problem.unwhiten @ problem.residual_w
        small_x = problem.unwhiten @ _design(problem, columns, smaller)
        big_x = problem.unwhiten @ _design(problem, columns, [*smaller, term])
        test = scatter_f_test(problem.scatter, raw_r, small_x, big_x)
        if test is None:
            return NestedTest(term, 0.0, 0, 1.0, "none")
        return NestedTest(term, test.statistic, test.q, test.p_value, "F (Satterthwaite)")
    return NestedTest(term, delta, q, float(stats.chi2.sf(delta, q)), "LR")


def holm_adjust(p_values: Sequence[float]) -> Array:
    """Holm step-down adjusted p-values (monotone, capped at 1)."""
    p = np.asarray(p_values, dtype=float)
    m = p.size
    order = np.argsort(p)
    adjusted = np.empty(m)
    running = 0.0
    for rank, idx in enumerate(order):
        running = max(running, min(1.0, (m - rank) * p[idx]))
        adjusted[idx] = running
    return adjusted


def forward_select(
    problem: LinearProblem,
    columns: Mapping[str, Array],
    *,
    alpha: float,
    family_size: int,
    use_f: bool = False,
) -> list[str]:
    """Add terms in order of significance while the smallest p beats Holm's ``α/(m − k)``.

    Then drop any chosen term whose test against all the others chosen no longer passes
    ``α/m`` (a term that only stood in for one chosen later).
    """
    chosen: list[str] = []
    remaining = list(columns)
    while remaining:
        tests = [nested_test(problem, columns, chosen, t, use_f=use_f) for t in remaining]
        best = min(tests, key=lambda s: s.p_value)
        if best.p_value >= alpha / (family_size - len(chosen)):
            break
        chosen.append(best.term)
        remaining.remove(best.term)
    for term in list(chosen):
        others = [t for t in chosen if t != term]
        if nested_test(problem, columns, others, term, use_f=use_f).p_value >= alpha / family_size:
            chosen.remove(term)
    return chosen


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
