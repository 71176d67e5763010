"""Held-out error by refitting with each position left out, term selection included.

For each position ``P`` the linearised problem (:class:`.significance.LinearProblem`)
without ``P``'s rows is handed to the same selection the full data went through (forward
selection with Holm, then the PRESS check), the chosen model is fitted, and ``P``'s raw
residual is predicted: ``e_P = r_P − X_P γ̂_{−P}`` (raw rows ``r = L r_w``, ``X = L X_w``
with ``L`` the full data's whitening Cholesky factor). When the pose-setting scatter τ is
estimated (:mod:`.noise_model`, eq. 1), each fold re-estimates it by REML on its training
positions alone, as the full data did: in the model holding every candidate before the
selection, then in the model holding the terms the fold chose, and whitens its rows with
``V_{−P}(τ̂_{−P})``; so neither the selection nor the fit sees ``P`` through τ. Inside a
fold the selection's nested tests hold τ at that fold's estimate (Δχ², not the profile
likelihood ratio of the full data: twelve profile searches per test would multiply the
cost of every fold). The base
model is scored the same way with no terms (τ re-estimated in the base model). ``cv_rms``
per sensor is the rms of the held-out raw residuals (SI), so it prices the selection
itself: a term chosen on noise costs held-out error.

The ratio base/extended ``cv_rms`` gets a 95 % interval from a bootstrap over positions
(paired: each resample draws positions, with both models' held-out residuals); a gain is
claimed only when that interval lies above 1 and the extended fit keeps at least
:data:`MIN_GAIN_DOF` residual degrees of freedom (docs/design.md §6).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from canimucal.analysis.noise_model import ScatterModel, reml_scatter
from canimucal.analysis.significance import LinearProblem, fit_terms

Array = NDArray[np.float64]

MIN_GAIN_DOF = 10
"""A gain is claimed only with at least this many residual degrees of freedom."""

BOOTSTRAP_DRAWS = 2000
BOOTSTRAP_SEED = 0
"""Fixed, so one data set always gives the same interval."""

Selector = Callable[
    [LinearProblem, Mapping[str, Array]], tuple[list[str], Mapping[str, NDArray[np.bool_]]]
]
"""Terms chosen on a fold's data, and the entries of each that are used."""


@dataclass(frozen=True)
class Holdout:
    """Held-out rms per sensor (SI), the ratio's 95 % interval and whether a gain is claimed."""

    base_cv_rms: Mapping[str, float]
    extended_cv_rms: Mapping[str, float]
    ratio_ci95: Mapping[str, tuple[float, float]]
    claimed: Mapping[str, bool]
    fold_terms: tuple[tuple[str, ...], ...]
    dof: Mapping[str, int]
    fold_tau: tuple[float, ...] = ()
    """Pose scatter (rad) each fold of the extended model re-estimated (empty: τ held)."""


def _estimated(problem: LinearProblem) -> ScatterModel | None:
    """Return the noise family whose τ is estimated, or None (τ held, or no angle scatter)."""
    scatter = problem.scatter
    return scatter if scatter is not None and scatter.fixed is None else None


def rescatter(
    problem: LinearProblem,
    columns: Mapping[str, Array],
    terms: Sequence[str],
    keep: NDArray[np.bool_] | None = None,
) -> tuple[LinearProblem, dict[str, Array], float]:
    """Return the rows ``keep`` (default all), whitened with τ re-estimated on them alone.

    τ is the REML estimate of noise_model eq. (1) over those rows in the model holding
    ``terms``. With τ held (no estimated scatter) the rows keep their whitening and the
    returned τ is NaN.
    """
    keep = np.ones(problem.block.size, dtype=bool) if keep is None else keep
    scatter = _estimated(problem)
    if scatter is None:
        sub = LinearProblem(
            residual_w=problem.residual_w[keep],
            base_w=problem.base_w[keep],
            block=problem.block[keep],
            unwhiten=problem.unwhiten[np.ix_(keep, keep)],
            si_scale=problem.si_scale[keep],
            sensor=problem.sensor[keep],
        )
        return sub, {k: v[keep] for k, v in columns.items()}, float("nan")
    lower = problem.unwhiten
    raw_r = (lower @ problem.residual_w)[keep]
    raw_base = (lower @ problem.base_w)[keep]
    raw_cols = {k: (lower @ v)[keep] for k, v in columns.items()}
    fold = ScatterModel(
        scatter.base[np.ix_(keep, keep)],
        scatter.unit[np.ix_(keep, keep)],
        scatter.source,
        blocks=None if scatter.blocks is None else scatter.blocks[keep],
        tau_max=scatter.tau_max,
    )
    design = np.hstack([raw_base] + [raw_cols[t] for t in terms])
    tau = reml_scatter(fold, raw_r, design)
    cov = fold.covariance(tau)
    chol = np.asarray(np.linalg.cholesky(0.5 * (cov + cov.T)), dtype=float)
    whiten = np.linalg.inv(chol)
    sub = LinearProblem(
        residual_w=whiten @ raw_r,
        base_w=whiten @ raw_base,
        block=problem.block[keep],
        unwhiten=chol,
        si_scale=problem.si_scale[keep],
        sensor=problem.sensor[keep],
        scatter=fold,
    )
    return sub, {k: whiten @ v for k, v in raw_cols.items()}, float(tau)


def held_out_residuals(
    problem: LinearProblem,
    columns: Mapping[str, Array],
    select: Selector | None,
    cache: dict[tuple[int, tuple[str, ...]], tuple[LinearProblem, dict[str, Array], float]]
    | None = None,
) -> tuple[Array, list[tuple[str, ...]], list[float]]:
    """Raw held-out residuals (SI) of every row, the terms and the τ of each fold.

    ``select`` None scores the base model alone. τ is NaN for every fold when it is held.
    ``cache`` keeps each fold's rows for a set of terms between calls (the base model's
    folds serve every fold of the extended model that chose no terms).
    """
    cache = {} if cache is None else cache
    out = np.empty_like(problem.residual_w)
    raw_r = problem.unwhiten @ problem.residual_w
    raw_base = problem.unwhiten @ problem.base_w
    chosen_per_fold: list[tuple[str, ...]] = []
    taus: list[float] = []
    for b in np.unique(problem.block):
        out_rows = problem.block == b
        train = ~out_rows
        if select is None:
            terms: list[str] = []
            masks: Mapping[str, NDArray[np.bool_]] = {}
        else:
            sub, sub_cols, _ = rescatter(problem, columns, list(columns), train)
            terms, masks = select(dataclasses.replace(sub, scatter=None), sub_cols)
        key = (int(b), tuple(terms))
        if key not in cache:
            cache[key] = rescatter(problem, columns, terms, train)
        sub, sub_cols, tau = cache[key]
        used = {t: sub_cols[t] * masks[t] if t in masks else sub_cols[t] for t in terms}
        fit = fit_terms(sub, used, terms)
        raw_x = [raw_base] + [
            problem.unwhiten @ (columns[t] * masks[t] if t in masks else columns[t]) for t in terms
        ]
        coef = np.concatenate([fit.base_delta] + [fit.coefficients[t] for t in terms])
        raw = raw_r[out_rows] - np.hstack(raw_x)[out_rows] @ coef
        out[out_rows] = raw * problem.si_scale[out_rows]
        chosen_per_fold.append(tuple(terms))
        taus.append(tau)
    return out, chosen_per_fold, taus


def refit_holdout(
    problem: LinearProblem,
    columns: Mapping[str, Array],
    select: Selector,
    *,
    extended: Sequence[str],
) -> Holdout:
    """Score base and selected models by refitting without each position (module doc).

    ``extended`` are the terms the full data chose (no terms for a sensor: no gain there).
    """
    dof = sensor_dof(problem, columns, extended)
    cache: dict[tuple[int, tuple[str, ...]], tuple[LinearProblem, dict[str, Array], float]] = {}
    base, _, _ = held_out_residuals(problem, columns, None, cache)
    ext, folds, taus = held_out_residuals(problem, columns, select, cache)
    sensors = sorted(set(problem.sensor.tolist()))
    rng = np.random.default_rng(BOOTSTRAP_SEED)
    blocks = np.unique(problem.block)
    draws = rng.integers(0, blocks.size, (BOOTSTRAP_DRAWS, blocks.size))
    base_cv, ext_cv, ci, claimed = {}, {}, {}, {}
    for s in sensors:
        mask = problem.sensor == s
        sb = np.array([np.sum(base[mask & (problem.block == b)] ** 2) for b in blocks])
        se = np.array([np.sum(ext[mask & (problem.block == b)] ** 2) for b in blocks])
        count = np.array([np.sum(mask & (problem.block == b)) for b in blocks], dtype=float)
        base_cv[s] = float(np.sqrt(sb.sum() / count.sum()))
        ext_cv[s] = float(np.sqrt(se.sum() / count.sum()))
        ratios = np.sqrt(sb[draws].sum(axis=1) / np.maximum(se[draws].sum(axis=1), 1e-300))
        low, high = (float(x) for x in np.percentile(ratios, [2.5, 97.5]))
        ci[s] = (low, high)
        has_terms = any(t.startswith(s + ".") for t in extended)
        claimed[s] = bool(has_terms and low > 1.0 and dof[s] >= MIN_GAIN_DOF)
    fold_tau = () if all(np.isnan(taus)) else tuple(taus)
    return Holdout(base_cv, ext_cv, ci, claimed, tuple(folds), dof, fold_tau)


def sensor_dof(
    problem: LinearProblem, columns: Mapping[str, Array], terms: Sequence[str]
) -> dict[str, int]:
    """Residual dof of each sensor: its rows less the rank of the design on those rows."""
    design = np.hstack([problem.base_w] + [columns[t] for t in terms])
    out = {}
    for s in sorted(set(problem.sensor.tolist())):
        rows = design[problem.sensor == s]
        rank = int(np.linalg.matrix_rank(rows)) if rows.size else 0
        out[s] = int(rows.shape[0] - rank)
    return out
