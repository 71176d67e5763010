"""Held-out error by refitting with each position left out, term selection included.

For each position ``P`` the linearised problem (:class:`.significance.LinearProblem`)
without ``P``'s rows is handed to the same selection the full data went through (forward
selection with Holm, then the PRESS check), the chosen model is fitted, and ``P``'s raw
residual is predicted: ``e_P = L_PP (r_w,P − X_w,P γ̂_{−P})`` with ``L`` the whitening's
Cholesky factor (block-diagonal by position when no random walk couples positions; with
one, the coupling across positions is ignored here). The base model is scored the same way
with no terms. ``cv_rms`` per sensor is the rms of the held-out raw residuals (SI), so it
prices the selection itself: a term chosen on noise costs held-out error.

The ratio base/extended ``cv_rms`` gets a 95 % interval from a bootstrap over positions
(paired: each resample draws positions, with both models' held-out residuals); a gain is
claimed only when that interval lies above 1 and the extended fit keeps at least
:data:`MIN_GAIN_DOF` residual degrees of freedom (DESIGN §9).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

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


def _drop(problem: LinearProblem, keep: NDArray[np.bool_]) -> LinearProblem:
    return LinearProblem(
        residual_w=problem.residual_w[keep],
        base_w=problem.base_w[keep],
        block=problem.block[keep],
        unwhiten=problem.unwhiten[np.ix_(keep, keep)],
        si_scale=problem.si_scale[keep],
        sensor=problem.sensor[keep],
    )


def held_out_residuals(
    problem: LinearProblem,
    columns: Mapping[str, Array],
    select: Selector | None,
) -> tuple[Array, list[tuple[str, ...]]]:
    """Raw held-out residuals (SI) of every row, and the terms each fold chose.

    ``select`` None scores the base model alone.
    """
    out = np.empty_like(problem.residual_w)
    chosen_per_fold: list[tuple[str, ...]] = []
    for b in np.unique(problem.block):
        out_rows = problem.block == b
        sub = _drop(problem, ~out_rows)
        sub_cols = {k: v[~out_rows] for k, v in columns.items()}
        terms, masks = select(sub, sub_cols) if select is not None else ([], {})
        used = {t: columns[t] * masks[t] if t in masks else columns[t] for t in terms}
        fit = fit_terms(sub, {t: v[~out_rows] for t, v in used.items()}, terms)
        design = np.hstack([problem.base_w] + [used[t] for t in terms])
        coef = np.concatenate([fit.base_delta] + [fit.coefficients[t] for t in terms])
        white = problem.residual_w[out_rows] - design[out_rows] @ coef
        raw = problem.unwhiten[np.ix_(out_rows, out_rows)] @ white
        out[out_rows] = raw * problem.si_scale[out_rows]
        chosen_per_fold.append(tuple(terms))
    return out, chosen_per_fold


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
    base, _ = held_out_residuals(problem, columns, None)
    ext, folds = held_out_residuals(problem, columns, select)
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
    return Holdout(base_cv, ext_cv, ci, claimed, tuple(folds), dof)


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
