"""The one added position that would best separate an ambiguous pair of candidates.

When two candidates explain the same discrepancy (docs/design.md §6's head-to-head rule fails), each
pose ``x`` of a grid is scored by what the model holding both would know with ``x`` added to
the recording. Its Fisher information (parameters: the base model, the other chosen terms,
the term ``a`` and its rival ``b``) is

    F(x) = Dᵀ D + R_xᵀ V_x⁻¹ R_x                                                   (1)

with ``D`` the recording's whitened design at its estimated noise model, ``R_x`` the raw
rows of the added pose (the base Jacobian and every candidate's columns at ``x``, linearised
at the base fit; with trials the pose is added to the first) and ``V_x = C̄ + τ̂² J_x J_xᵀ``
its mean's covariance: the mean
within-position covariance of the recording's positions plus the pose-setting scatter
through the angle derivatives ``J_x`` (noise_model eq. 1). With ``Σ(x) = F(x)⁻¹`` the
correlation of the pair's estimates is the largest canonical correlation between the two
candidates' coefficient blocks (:func:`.significance.canonical_correlation`),

    ρ(x) = σ_max( Σ_aa^(−1/2) Σ_ab Σ_bb^(−1/2) ),                                    (2)

the quantity reported as the ambiguity's ``correlation`` (at ``F = DᵀD``, the recording as
it is) and as ``correlation_after``: the largest correlation between any combination of one
candidate's entries and any of the other's, so one number for candidates of several entries
(the look-alike y→z cross-axis vs z quadratic: 6 entries against 3) that no relabelling of
the entries changes. The separating position minimises ρ(x) (docs/design.md §6). Poses whose ρ lies
within :data:`RHO_TIE` of the smallest are told apart by the head-to-head test of each
candidate in the model holding both, whose non-centrality is

    λ_a(x) = γ_aᵀ Σ_aa(x)⁻¹ γ_a                                                    (3)

at ``γ_a``, ``a``'s coefficients fitted without ``b`` (the size ``a`` has if it is the
cause), and ``λ_b`` likewise: of those, the pose with the largest ``min(λ_a, λ_b)``, which is
also reported. On the look-alike (tests/analysis/test_separation.py, exact poses, seeds 0–7,
both signs) the pose minimising ρ takes it from 0.996 to 0.69–0.695 and ``min λ`` from 2–8 to
140–4300; with it added ``cross_axis`` is named in 8 of 8. (The pose maximising ``min λ``
also resolved 8 of 8, at λ 1900 and 67000 on seeds 0 and 1, but left ρ at 0.98 and 0.91.)

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

from canimucal.analysis.base_fit import EARTH_RATE_NAMES, TRIAL_OFFSET_PREFIX, free_earth_rate
from canimucal.analysis.candidates import candidates_at_angles
from canimucal.analysis.data import SeparatingPosition, SessionData
from canimucal.analysis.significance import LinearProblem, canonical_correlation, fit_terms
from canimucal.errors import ModelError
from canimucal.model.joint import JointResult
from canimucal.model.layout import ModelContext, ParameterLayout, predict
from canimucal.model.vocabulary.plans import builtin_plan

Array = NDArray[np.float64]

GRID_STEP_DEG = 5.0
COARSE_STEPS = 3
"""The first pass scores every third grid step."""
DEFAULT_TILT_LIMIT_DEG = 90.0
"""Tilt limit without a built-in plan: any pose up to a side lying down (|alpha|, |beta| ≤ 90°)."""

RHO_TIE = 1e-3
"""Poses whose ρ (eq. 2) is within this of the smallest count as equal; eq. (3) decides."""

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
    data: SessionData,
    joint: JointResult,
    keys: Sequence[str],
    angles: Array,
    tau: float,
    nuisance: Sequence[str] = (),
) -> tuple[Array, Array]:
    """Raw rows ``R_x`` ``(k, m, p)`` and covariances ``V_x`` ``(k, m, m)`` of eq. (1).

    ``nuisance``: the base model's parameters beyond the joint fit's (the Earth rate fitted
    without a latitude, :mod:`.base_fit`), in the order of the base columns.
    """
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
    s_matrix = gyro.S if gyro is not None else np.eye(3) / data.gyro_lsb
    earth = free_earth_rate(angles, s_matrix, m).reshape(k, m, 3)
    extra = np.zeros((k, m, 0))
    if nuisance:
        extra = np.stack([_nuisance_rows(name, earth, nuisance) for name in nuisance], axis=2)
    rows = np.concatenate([pred.d_theta, extra] + [by_key[t] for t in keys], axis=2)
    within = np.zeros((m, m))
    for a in data.averages:
        within[:3, :3] += a.cov_accel / len(data.averages)
        if m == 6 and a.cov_gyro is not None:
            within[3:, 3:] += a.cov_gyro / len(data.averages)
    cov = within + tau * tau * np.einsum("kia,kja->kij", pred.d_angles, pred.d_angles)
    return rows, cov


def _nuisance_rows(name: str, earth: Array, nuisance: Sequence[str]) -> Array:
    """Return the added pose's ``(k, m)`` rows of one base parameter beyond the joint fit's.

    An Earth-rate component (:mod:`.base_fit`), or a trial's bias offset: the added pose is
    set in the first trial (its biases, the shared ones plus that trial's offsets), so the
    first trial's offsets reach its own channel and the others nothing.
    """
    if name in EARTH_RATE_NAMES:
        return np.asarray(earth[:, :, EARTH_RATE_NAMES.index(name)], dtype=float)
    rows = np.zeros(earth.shape[:2])
    offsets = [n for n in nuisance if n.startswith(TRIAL_OFFSET_PREFIX)]
    first = offsets[0].split(".", 1)[0]
    if name.split(".", 1)[0] == first:
        sensor, axis = name.split(".", 1)[1], int(name[-2])
        rows[:, axis + (3 if sensor.startswith("gyro") else 0)] = 1.0
    return rows


def _entry_slices(
    problem: LinearProblem, columns: Mapping[str, Array], keys: Sequence[str]
) -> dict[str, slice]:
    out, start = {}, problem.base_w.shape[1]
    for t in keys:
        out[t] = slice(start, start + columns[t].shape[1])
        start += columns[t].shape[1]
    return out


def _noncentrality(cov: Array, block: slice, gamma: Array) -> Array:
    """Eq. (3) for each pose: ``γᵀ Σ_aa⁻¹ γ`` (pseudo-inverse: entries no pose determines)."""
    sub = cov[:, block, block]
    return np.einsum("i,kij,j->k", gamma, np.linalg.pinv(sub, hermitian=True), gamma)


def separating_position(
    data: SessionData,
    joint: JointResult,
    problem: LinearProblem,
    columns: Mapping[str, Array],
    others: Sequence[str],
    pair: tuple[str, str],
    tau: float,
    nuisance: Sequence[str] = (),
    enough: float = np.inf,
) -> SeparatingPosition | None:
    """Find the grid pose that minimises the pair's correlation ρ of eq. (2) (module doc).

    ``columns`` are whitened as ``problem``; ``pair`` the term and its rival (keys
    ``sensor.effect``); ``others`` the other terms in the model; ``tau`` radians;
    ``nuisance`` the base parameters ``problem`` holds beyond ``joint``'s (see
    :func:`_pose_rows`). None when the recording's own head-to-head non-centrality (eq. 3,
    the smaller of the two) is already ``enough``: no added position is needed to tell
    them apart.
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
    if lam0 >= enough:
        return None

    def scored(grid_deg: Array) -> tuple[Array, Array, Array, Array]:
        """ρ (eq. 2), min λ (eq. 3) and Σ of every pose of ``grid_deg``."""
        rhos, lams, covs = [], [], []
        for start in range(0, grid_deg.shape[0], CHUNK):
            poses = grid_deg[start : start + CHUNK]
            rows, cov_x = _pose_rows(data, joint, keys, np.deg2rad(poses), tau, nuisance)
            white = np.linalg.solve(np.linalg.cholesky(cov_x), rows * scale)
            info = info0[None] + np.einsum("kmi,kmj->kij", white, white)
            cov = np.linalg.pinv(info, hermitian=True)
            rhos.append(canonical_correlation(cov, slices[a], slices[b]))
            lams.append(
                np.minimum(
                    _noncentrality(cov, slices[a], gamma[a]),
                    _noncentrality(cov, slices[b], gamma[b]),
                )
            )
            covs.append(cov)
        return grid_deg, np.concatenate(rhos), np.concatenate(lams), np.concatenate(covs)

    def best(grid_deg: Array) -> tuple[Array, float, float]:
        poses, rho, lam, _ = scored(grid_deg)
        near = np.flatnonzero(rho <= np.min(rho) + RHO_TIE)
        k = int(near[np.argmax(lam[near])])
        return poses[k], float(rho[k]), float(lam[k])

    coarse, _, _ = best(pose_grid(limit, GRID_STEP_DEG * COARSE_STEPS))
    pose, rho, lam = best(_neighbourhood(coarse, limit))
    alpha, beta, psi = (float(x) for x in pose)
    return SeparatingPosition(alpha, beta, psi, rho, lam, lam0, limit)
