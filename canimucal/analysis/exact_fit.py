"""Exact fits of an extended known-position model (docs/design.md §6).

The candidate columns of :mod:`.base_fit` are the derivatives of the prediction at the
tilt-free base fit. A base tilt of a degree or more is not linear there: the columns of the
other candidates are those of a level base, and the leftover of the linearisation (0.2–0.7
counts a position where the mean's σ is 0.06) was taken up by phantom causes
(``scale_nonlinearity``, ``cross_axis``). So the model holding the chosen terms is fitted to
convergence by Gauss–Newton: at its current estimate ``p = (θ, γ)`` the prediction is
evaluated exactly,

    U_i = b + K C_i(α0, β0) f_L + Σ_t X_t(p)_i γ_t                                       (1)

(K full when ``cross_axis`` is chosen, the rigid tilt ``(α0, β0)`` when ``base_tilt`` is,
the gyro ``B + S C_i w_L``; every other effect of the registry is linear in its entries, its
columns ``X_t`` evaluated at the tilted specific force ``f_i = C_i f_L``), and every column
(base, chosen and not) is re-derived there. The linear problem handed back is the tangent at
``p`` written in the terms' absolute coefficients,

    r = U − U(p) + Σ_{t chosen} X_t γ_t ≈ J δθ + Σ_t X_t γ_t,                               (2)

exact at ``γ = γ(p)``, so a term left out of a model is held at zero, not at its value in
``p``. The noise model follows: the covariance an angle-setting error adds to each mean is
re-derived at the tilted poses too,

    A_i(p) = J_i(p) J_i(p)ᵀ,   J_i = ∂U_i/∂(α, β, ψ) at p's tilt                       (3)

(:mod:`.noise_model` eq. 1), so the directions along gravity stay free of pose scatter;
K's cross-axis terms and the Earth rate stay as the base fit had them
(:func:`_without_cross_axis`). The trials' bias offsets (:func:`.base_fit.trial_offsets`)
are linear: they add to ``U(p)`` and their columns are the same at every ``p``.
Iterations stop when no parameter moves by more than :data:`STEP_SIGMAS` of its σ (two or
three at a 3° tilt).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping, Sequence

import numpy as np
from numpy.typing import NDArray

from canimucal.analysis.base_fit import (
    EARTH_RATE_NAMES,
    PreparedBase,
    block_covariance,
    temperature_status,
    trial_offsets,
    unit_angle_covariance,
)
from canimucal.analysis.candidates import candidates_at_inputs
from canimucal.analysis.data import SessionData
from canimucal.analysis.significance import LinearProblem, fit_terms
from canimucal.model.dcm_stack import dcm_stack
from canimucal.model.layout import (
    JointSpec,
    ModelContext,
    ParameterLayout,
    angle_error_moments,
    predict,
)
from canimucal.model.positions import PositionAverage
from canimucal.model.vocabulary.effects import OFF_DIAGONAL, PoseInputs

Array = NDArray[np.float64]

STEP_SIGMAS = 0.01
"""Converged when every parameter's step is below this fraction of its σ."""
MAX_ITERATIONS = 8

TILT = "accel.base_tilt"
CROSS = "accel.cross_axis"


def relinearised(
    data: SessionData, base: PreparedBase, values: Array, coefs: Mapping[str, Array]
) -> PreparedBase:
    """Return ``base`` linearised at the extended estimate (eq. 2).

    ``values`` the base parameters (``base.names``), ``coefs`` the chosen terms' entries.
    The angle errors' covariances are re-derived there (eq. 3); the within-position
    covariance, blocks and residual table of ``base`` are kept.
    """
    n, m = base.residual_table.shape
    angles = np.array([a.pose.angles for a in data.averages])
    tilt = np.asarray(coefs.get(TILT, np.zeros(2)), dtype=float)
    layout = ParameterLayout.of(
        JointSpec(accel_k="full", tilt="rigid", gyro="mems" if m == 6 else "none")
    )
    theta = np.zeros(layout.size)
    named = dict(zip(base.names, values, strict=True))
    for k, name in enumerate(layout.names):
        if name in named:
            theta[k] = named[name]
    if CROSS in coefs:
        for (i, j), v in zip(OFF_DIAGONAL, coefs[CROSS], strict=True):
            theta[layout.index(f"accel.K[{i}][{j}]")] = v
    theta[layout.index("base_tilt.alpha0")], theta[layout.index("base_tilt.beta0")] = tilt
    ctx = ModelContext.build(data.g, data.latitude, data.heading, data.gyro_lsb)
    at_base = ctx  # the site's Earth rate, as the base fit's noise model has it (eq. 3)
    nuisance = [name for name in base.names if name in EARTH_RATE_NAMES]
    w_level = ctx.w_level.copy()
    for name in nuisance:
        w_level[EARTH_RATE_NAMES.index(name)] = named[name]
    ctx = dataclasses.replace(ctx, w_level=w_level)
    pred = predict(layout, theta, angles, ctx)
    offset_names, offset_columns = trial_offsets(data.averages, m)
    offset_values = np.array([named[name] for name in offset_names], dtype=float)
    par = layout.unpack(theta, ctx.gyro_lsb)
    c, _, _ = dcm_stack(angles, float(tilt[0]), float(tilt[1]), "rigid")
    temps, _ = temperature_status(data)
    inputs = PoseInputs(
        angles, c @ ctx.f_level, data.g, par.K, par.S, w_level, m,
        None if temps is None else temps - np.mean(temps),
    )  # fmt: skip
    tilt_cols = pred.d_theta[
        :, :, [layout.index("base_tilt.alpha0"), layout.index("base_tilt.beta0")]
    ]
    cands = []
    for cand in candidates_at_inputs(inputs):
        if cand.key == TILT:  # the rigid tilt's derivative at the current tilt and full K
            cand = dataclasses.replace(cand, columns=tilt_cols.reshape(n * m, 2))
        cands.append(cand)
    by_key = {cand.key: cand.columns for cand in cands}
    mean = pred.mean.ravel() + offset_columns @ offset_values  # each trial's own biases
    for key, gamma in coefs.items():
        if key not in (TILT, CROSS):  # linear in their entries (eq. 1)
            mean = mean + by_key[key] @ gamma
    observed = np.array([_observed(a, m) for a in data.averages]).ravel()
    shifted = observed - mean + sum((by_key[k] @ g for k, g in coefs.items()), np.zeros(n * m))
    jac = np.zeros((n * m, len(base.names)))
    for k, name in enumerate(base.names):
        if name in nuisance:  # ∂V/∂w_L = S C_i on the gyro rows, at the current tilt
            axis = EARTH_RATE_NAMES.index(name)
            cols = np.zeros((n, m))
            cols[:, 3:] = (par.S @ c)[:, :, axis]
            jac[:, k] = cols.ravel()
        elif name in offset_names:  # linear: the trials' contrast on its bias channel
            jac[:, k] = offset_columns[:, offset_names.index(name)]
        else:
            jac[:, k] = pred.d_theta[:, :, layout.index(name)].ravel()
    keep = {cand.key for cand in base.candidates}
    # the angle errors' covariance at the tilted poses (eq. 3): at the level base's, a 2° tilt
    # leaks 0.1° of pose scatter into the direction along gravity (0.12 counts, twice a 30 s
    # mean's σ) and phantom terms (cross_axis) took it up on 4 of 12 seeds at 0.1° poses
    tol = np.array([a.pose.tolerance for a in data.averages])
    at_tilt = _without_cross_axis(layout, theta)
    moments = angle_error_moments(layout, at_tilt, angles, at_base, tol)
    return dataclasses.replace(
        base,
        residual=shifted,
        jacobian=jac,
        covariance=block_covariance(data, moments.covariance),
        angle_unit_covariance=block_covariance(
            data, unit_angle_covariance(layout, at_tilt, angles, at_base), False
        ),
        candidates=tuple(cand for cand in cands if cand.key in keep),
        values=np.asarray(values, dtype=float),
    )


def _without_cross_axis(layout: ParameterLayout, theta: Array) -> Array:
    """Return ``theta`` with K's off-diagonal at zero: the point eq. (3) is evaluated at.

    The tilt rotates the directions the angle errors reach, and eq. (3) follows it. What
    else the extended fit holds is left as the base fit had it, K's cross-axis terms and
    the Earth rate (the site's, not the fitted nuisance): each adds to the angle errors'
    covariance a trace the base's lacks, along gravity (1.5 % of the pose effect) and on
    the gyro rows (2.5e-5 counts² per rad² on imucal's session), and the scatter's REML, on
    the five positions a held-out fold leaves, stretched τ over them. Measured on imucal's
    session (issue 21): with both traces two folds' τ ran to the 10° bound and cross_axis was
    refuted held out (cv_rms 0.080 → 0.42 m/s²); with the cross-axis trace alone the held-out
    ratio fell from 0.98 to 0.08 (95 % 0.05–1.26).
    """
    out = theta.copy()
    for i, j in OFF_DIAGONAL:
        out[layout.index(f"accel.K[{i}][{j}]")] = 0.0
    return out


def _observed(average: PositionAverage, m: int) -> Array:
    """Return the position's observed means: accelerometer, then (``m`` 6) gyro, counts."""
    accel = np.asarray(average.mean_accel, dtype=np.float64)
    if m == 3 or average.mean_gyro is None:
        return accel
    return np.concatenate([accel, np.asarray(average.mean_gyro, dtype=np.float64)])


Linearise = Callable[[PreparedBase], tuple[LinearProblem, dict[str, Array]]]
"""Whiten a prepared fit: its linear problem and the whitened columns of the candidates."""


def exact_fit(
    data: SessionData,
    base: PreparedBase,
    terms: Sequence[str],
    linearise: Linearise,
) -> PreparedBase:
    """Fit the model holding ``terms`` to convergence; return it linearised there (eq. 2).

    ``base`` is the tilt-free base fit (its own linearisation); ``linearise`` whitens a
    prepared fit under the session's noise model. Without terms the base fit is returned.
    """
    if not terms:
        return base
    prepared = base
    coefs: dict[str, Array] = {t: np.zeros(0) for t in terms}
    for _ in range(MAX_ITERATIONS):
        problem, columns = linearise(prepared)
        fit = fit_terms(problem, columns, list(terms))
        values = prepared.values + fit.base_delta
        new = {t: np.asarray(fit.coefficients[t], dtype=float) for t in terms}
        moves = [np.abs(fit.base_delta) / np.maximum(base.sigmas, 1e-300)]
        for t in terms:
            old = coefs[t] if coefs[t].size else np.zeros_like(new[t])
            moves.append(np.abs(new[t] - old) / np.maximum(fit.sigmas[t], 1e-300))
        coefs = new
        prepared = relinearised(data, base, values, coefs)
        if float(np.max(np.concatenate(moves))) < STEP_SIGMAS:
            break
    return prepared
