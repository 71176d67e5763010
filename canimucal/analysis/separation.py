"""The one added position that would best separate an ambiguous pair of candidates.

When two candidates explain the same discrepancy (DESIGN §9's head-to-head rule fails), each
pose ``x`` of a grid is scored by what the model holding both would know with ``x`` added to
the recording. Its Fisher information (parameters: the base model, the other chosen terms,
the term ``a`` and its rival ``b``) is

    F(x) = Dᵀ D + R_xᵀ V_x⁻¹ R_x                                                   (1)

with ``D`` the recording's whitened design at its estimated noise model, ``R_x`` the raw
rows of the added pose (the base Jacobian and every candidate's columns at ``x``, linearised
at the base fit) and ``V_x = C̄ + τ̂² J_x J_xᵀ`` its mean's covariance: the mean
within-position covariance of the recording's positions plus the pose-setting scatter
through the angle derivatives ``J_x`` (noise_model eq. 1). With ``Σ(x) = F(x)⁻¹``, the
head-to-head test of ``a`` in the model holding both has non-centrality

    λ_a(x) = γ_aᵀ Σ_aa(x)⁻¹ γ_a                                                    (2)

at ``γ_a``, ``a``'s coefficients fitted without ``b`` (the size ``a`` has if it is the
cause), and ``λ_b`` likewise. The separating position maximises ``min(λ_a, λ_b)``: whichever
of the two is the cause, its test gains the most power against the other. Reported with it:
the correlation of the pair's most correlated entries under ``Σ(x)`` (as
:func:`.significance.entry_correlation`).

The grid: ``alpha`` and ``beta`` on 5° steps within ± the plan's tilt limit (the largest
|alpha|, |beta| of the built-in plan named in the recording's header), else within
± :data:`DEFAULT_TILT_LIMIT_DEG`; ``psi`` on 5° steps over the full turn. It is searched
coarse to fine: every third step (15°) first, then every 5° pose within ±10° of the best
coarse pose (the score varies smoothly with the pose; the full 5° grid would cost 25×).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
from numpy.typing import NDArray

from canimucal.analysis.candidates import candidates_at_angles
from canimucal.analysis.data import SeparatingPosition, SessionData
from canimucal.analysis.significance import LinearProblem, fit_terms
from canimucal.errors import ModelError
from canimucal.model.joint import JointResult
from canimucal.model.layout import ModelContext, ParameterLayout, predict
from canimucal.model.plan import builtin_plan

Array = NDArray[np.float64]

GRID_STEP_DEG = 5.0
COARSE_STEPS = 3
"""The first pass scores every third grid step."""
DEFAULT_TILT_LIMIT_DEG = 90.0
"""Tilt limit without a built-in plan: any pose up to a side lying down (|alpha|, |beta| ≤ 90°)."""

CHUNK = 2048
"""Poses scored per batch (bounds the memory of the batched inverses)."""


def plan_tilt_limit_deg(name: object) -> float | None:
    """Return the largest |alpha|, |beta| (degrees) of the built-in plan ``name``, else None."""
    if not isinstance(name, str):
        return None
    try:
        plan = builtin_plan(name)
    except ModelError:  # an unknown or custom plan: no limits known
        return None
    tilts = [max(abs(p.alpha), abs(p.beta)) for p in plan.positions]
    return float(np.rad2deg(max(tilts)))


def pose_grid(limit_deg: float, step_deg: float = GRID_STEP_DEG) -> Array:
    """Every (alpha, beta, psi) on the ``step_deg`` grid within ± ``limit_deg``, degrees."""
    n = int(np.floor(limit_deg / step_deg + 1e-9))
    tilt = np.arange(-n, n + 1) * step_deg
    psi = np.arange(0.0, 360.0 - 1e-9, step_deg)
    a, b, p = np.meshgrid(tilt, tilt, psi, indexing="ij")
    return np.column_stack([a.ravel(), b.ravel(), p.ravel()])


def _neighbourhood(centre: Array, limit_deg: float) -> Array:
    """Return the 5° grid poses within ±(COARSE_STEPS − 1) steps of ``centre`` (degrees)."""
    offsets = np.arange(-(COARSE_STEPS - 1), COARSE_STEPS) * GRID_STEP_DEG
    a, b, p = np.meshgrid(
        centre[0] + offsets, centre[1] + offsets, centre[2] + offsets, indexing="ij"
    )
    out = np.column_stack([a.ravel(), b.ravel(), np.mod(p.ravel(), 360.0)])
    keep = np.all(np.abs(out[:, :2]) <= limit_deg + 1e-9, axis=1)
    return out[keep]


def _pose_rows(
    data: SessionData, joint: JointResult, keys: Sequence[str], angles: Array, tau: float
) -> tuple[Array, Array]:
    """Raw rows ``R_x`` ``(k, m, p)`` and covariances ``V_x`` ``(k, m, m)`` of eq. (1)."""
    layout = ParameterLayout.of(joint.spec)
    ctx = ModelContext.build(data.g, data.latitude, data.heading, data.gyro_lsb)
    pred = predict(layout, joint.values, angles, ctx)
    k, m = angles.shape[0], joint.spec.channels
    gyro = joint.gyro_params()
    cands = candidates_at_angles(
        angles,
        g=data.g,
        k_matrix=joint.accel_params().K,
        s_matrix=gyro.S if gyro is not None else np.eye(3) / data.gyro_lsb,
        w_level=ctx.w_level,
        channels=m,
        temperatures=np.zeros(k),  # the added pose at the mean temperature: no information
    )
    by_key = {c.key: c.columns.reshape(k, m, -1) for c in cands}
    rows = np.concatenate([pred.d_theta] + [by_key[t] for t in keys], axis=2)
    within = np.zeros((m, m))
    for a in data.averages:
        within[:3, :3] += a.cov_accel / len(data.averages)
        if m == 6 and a.cov_gyro is not None:
            within[3:, 3:] += a.cov_gyro / len(data.averages)
    cov = within + tau * tau * np.einsum("kia,kja->kij", pred.d_angles, pred.d_angles)
    return rows, cov


def _entry_slices(
    problem: LinearProblem, columns: Mapping[str, Array], keys: Sequence[str]
) -> dict[str, slice]:
    out, start = {}, problem.base_w.shape[1]
    for t in keys:
        out[t] = slice(start, start + columns[t].shape[1])
        start += columns[t].shape[1]
    return out


def _noncentrality(cov: Array, block: slice, gamma: Array) -> Array:
    """Eq. (2) for each pose: ``γᵀ Σ_aa⁻¹ γ`` (pseudo-inverse: entries no pose determines)."""
    sub = cov[:, block, block]
    return np.einsum("i,kij,j->k", gamma, np.linalg.pinv(sub, hermitian=True), gamma)


def _correlation(cov: Array, a: slice, b: slice) -> Array:
    """Signed largest |correlation| between an entry of ``a`` and one of ``b``, per pose."""
    sd = np.sqrt(np.maximum(np.einsum("kii->ki", cov), 1e-300))
    corr = cov[:, a, b] / (sd[:, a, None] * sd[:, None, b])
    flat = corr.reshape(corr.shape[0], -1)
    pick = np.argmax(np.abs(flat), axis=1)
    return np.asarray(flat[np.arange(flat.shape[0]), pick], dtype=float)


def separating_position(
    data: SessionData,
    joint: JointResult,
    problem: LinearProblem,
    columns: Mapping[str, Array],
    others: Sequence[str],
    pair: tuple[str, str],
    tau: float,
) -> SeparatingPosition:
    """Find the grid pose that maximises ``min(λ_a, λ_b)`` of eq. (2) (module doc).

    ``columns`` are whitened as ``problem``; ``pair`` the term and its rival (keys
    ``sensor.effect``); ``others`` the other terms in the model; ``tau`` radians.
    """
    a, b = pair
    keys = [*others, a, b]
    design = np.hstack([problem.base_w] + [columns[t] for t in keys])
    scale = 1.0 / np.maximum(np.linalg.norm(design, axis=0), 1e-300)  # Jacobi preconditioning
    info0 = (design * scale).T @ (design * scale)
    slices = _entry_slices(problem, columns, keys)
    gamma = {
        a: fit_terms(problem, columns, [*others, a]).coefficients[a] / scale[slices[a]],
        b: fit_terms(problem, columns, [*others, b]).coefficients[b] / scale[slices[b]],
    }
    limit = DEFAULT_TILT_LIMIT_DEG if data.tilt_limit_deg is None else data.tilt_limit_deg
    before = np.linalg.pinv(info0, hermitian=True)[None]
    lam0 = min(float(_noncentrality(before, slices[t], gamma[t])[0]) for t in (a, b))

    def best(grid_deg: Array) -> tuple[float, Array, Array]:
        top: tuple[float, Array, Array] = (-np.inf, grid_deg[0], before[0])
        for start in range(0, grid_deg.shape[0], CHUNK):
            poses = grid_deg[start : start + CHUNK]
            rows, cov_x = _pose_rows(data, joint, keys, np.deg2rad(poses), tau)
            white = np.linalg.solve(np.linalg.cholesky(cov_x), rows * scale)
            info = info0[None] + np.einsum("kmi,kmj->kij", white, white)
            cov = np.linalg.pinv(info, hermitian=True)
            score = np.minimum(
                _noncentrality(cov, slices[a], gamma[a]), _noncentrality(cov, slices[b], gamma[b])
            )
            k = int(np.argmax(score))
            if score[k] > top[0]:
                top = (float(score[k]), poses[k], cov[k])
        return top

    coarse = best(pose_grid(limit, GRID_STEP_DEG * COARSE_STEPS))
    score, pose, cov = best(_neighbourhood(coarse[1], limit))
    corr = float(_correlation(cov[None], slices[a], slices[b])[0])
    alpha, beta, psi = (float(x) for x in pose)
    return SeparatingPosition(alpha, beta, psi, corr, score, lam0, limit)
