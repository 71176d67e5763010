"""The base fits of the discrepancy loop, prepared for the linearised candidate tests.

Known positions: ``solve_joint`` with bias + diagonal K, no tilt, and the gyro bias with the
Earth rate through the nominal S (docs/design.md §6). Unknown positions: the scalar ``|f| = g`` fit,
model "6" (bias + diagonal K), and the gyro bias. Each gives the raw residuals, the raw
Jacobian of the prediction, the covariance of the residual vector (within-position scatter,
angle tolerances, and a random-walk term when drift was found) and the candidates' columns.

Trials (several mountings of the unit in one file, docs/design.md §5 Trials): the known-
position base model gives each trial its own accelerometer and gyro biases, as ``solve``
does, the shared biases the trials' mean and ``T − 1`` offsets per bias channel among the
base parameters (:func:`trial_offsets`); K, the gyro's scale and every candidate stay
shared. Without it the trials' bias steps were the misfit, and named (``bias_drift``).

The Earth rate is part of the gyro's base model even when the site is unknown, because
leaving it out fakes g-sensitivity (docs/design.md §6: its part along gravity *is* an isotropic G,
``ω_up = Ω sin φ · f/|f|``, and a consumer MEMS gyro sees it at 1-2σ of a 10-30 s mean).
Where the gyro cannot see it (:func:`earth_rate_visible`: its whole non-centrality over the
positions below 1 at a known gyro scale) it is left out, as before; else

- known positions: the Earth rate in the level frame ``w_L`` is seen through S in each
  pose, ``S C_i w_L`` (:func:`free_earth_rate`). Its horizontal components (East, North)
  are two nuisance parameters, since a heading is seldom known to the few degrees that
  would fix them (a session's default is 0°); the vertical one ``−Ω sin φ`` is a third
  when no latitude is given. Combinations the poses cannot tell from the gyro bias are
  left to the bias;
- unknown positions (no orientation): its vertical part ``Ω sin φ`` is one nuisance
  parameter along the measured ``f/|f|``; its horizontal part, of magnitude ``Ω cos φ``
  (``Ω`` when the latitude is unknown) in a direction set by each pose's unknown heading,
  enters each gyro mean's covariance as ``(Ω_h²/2) S (I − u uᵀ) Sᵀ``, the covariance of a
  horizontal vector of that length in a uniformly random direction. When the gyro's scale
  is unknown (no LSB in the file), so is that length in counts: it is then estimated from
  the data by REML, as the pose scatter is (:mod:`.noise_model`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from canimucal.analysis.candidates import (
    Candidate,
    known_position_candidates,
    scalar_candidates,
    scalar_jacobian,
)
from canimucal.analysis.data import SessionData
from canimucal.model.dcm_stack import dcm_stack
from canimucal.model.frames import EARTH_RATE_RAD_S
from canimucal.model.joint import JointResult, solve_joint, trial_contrast
from canimucal.model.layout import (
    GyroSpec,
    JointSpec,
    ModelContext,
    ParameterLayout,
    angle_error_moments,
    predict,
)
from canimucal.model.positions import PositionAverage
from canimucal.model.scalar import ScalarFit, fit_scalar_averages
from canimucal.model.small_linalg import pivoted_qr, solve_lower
from canimucal.model.vocabulary.effects import ScalarInputs

Array = NDArray[np.float64]


@dataclass(frozen=True)
class PreparedBase:
    """A base fit as the linearised tests need it (rows: position-major, then channel)."""

    method: str
    residual: Array
    jacobian: Array
    covariance: Array
    block: NDArray[np.int64]
    si_scale: Array
    sensor: NDArray[np.str_]
    channels: NDArray[np.int64]
    candidates: tuple[Candidate, ...]
    names: tuple[str, ...]
    values: Array
    sigmas: Array
    residual_table: Array
    residual_labels: tuple[str, ...]
    chi2: float
    dof: int
    within_covariance: Array | None = None
    angle_unit_covariance: Array | None = None
    pose_tolerance: float = 0.0
    earth_unit_covariance: Array | None = None
    """Scalar fits of a gyro of unknown scale: the covariance one count of horizontal Earth
    rate adds (in a random direction); its size is then a variance component estimated by
    REML like the pose scatter (``covariance`` is ``within_covariance`` plus none of it)."""


UNIT_PROBE_RAD = 1e-4
"""Angle scatter at which the per-radian angle covariance is probed (second order negligible)."""

EARTH_RATE_NAMES = tuple(f"gyro.earth_rate_level[{i}]" for i in range(3))
"""Nuisance parameters of a known-position fit: the Earth rate in the level frame (x East,
y Down, z North at the start heading), rad/s; [1] only when no latitude gives it."""
EARTH_RATE_VERTICAL = "gyro.earth_rate_vertical"
"""Nuisance parameter of a scalar fit: the Earth rate along the measured ``f/|f|``, rad/s at
the nominal LSB (counts when the file gives none)."""


def _rows_meta(
    n: int, m: int, lsbs: tuple[float, float]
) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.str_], Array]:
    block = np.repeat(np.arange(n, dtype=np.int64), m)
    channel = np.tile(np.arange(m, dtype=np.int64), n)
    sensor = np.where(channel < 3, "accel", "gyro").astype(np.str_)
    scale = np.where(channel < 3, abs(lsbs[0]), abs(lsbs[1])).astype(float)
    return block, channel, sensor, scale


def fit_known(data: SessionData) -> tuple[PreparedBase, JointResult]:
    """Joint base fit of labelled positions and its linearisation."""
    gyro: GyroSpec = "mems" if data.has_gyro else "none"
    spec = JointSpec(accel_k="diag", tilt="none", gyro=gyro)
    res = solve_joint(
        data.averages,
        spec,
        g=data.g,
        latitude=data.latitude,
        heading=data.heading,
        accel_lsb=data.accel_lsb,
        gyro_lsb=data.gyro_lsb,
    )
    layout = ParameterLayout.of(spec)
    ctx = ModelContext.build(data.g, data.latitude, data.heading, data.gyro_lsb)
    angles = np.array([a.pose.angles for a in data.averages])
    tol = np.array([a.pose.tolerance for a in data.averages])
    moments = angle_error_moments(layout, res.values, angles, ctx, tol)
    n, m = res.residuals.shape
    cov = block_covariance(data, moments.covariance)
    jac = predict(layout, res.values, angles, ctx).d_theta.reshape(n * m, layout.size)
    params = res.accel_params()
    gyro_params = res.gyro_params()
    s = gyro_params.S if gyro_params is not None else np.eye(3) / data.gyro_lsb
    temps = _position_temperatures(data)
    cands = known_position_candidates(
        data.averages,
        g=data.g,
        k_matrix=params.K,
        s_matrix=s,
        w_level=ctx.w_level,
        channels=m,
        temperatures=temps,
    )
    block, channel, sensor, scale = _rows_meta(n, m, (data.accel_lsb, data.gyro_lsb))
    labels = tuple(f"{'accel' if c < 3 else 'gyro'}.{'xyz'[c % 3]}" for c in range(m))
    sig = np.sqrt(np.abs(np.diag(res.covariance)))
    prepared = PreparedBase(
        "joint", res.residuals.ravel(), jac, cov, block, scale, sensor, channel,
        tuple(cands), res.names, res.values, sig, res.residuals, labels, res.chi2, res.dof,
        block_covariance(data, np.zeros_like(moments.covariance)),
        block_covariance(data, unit_angle_covariance(layout, res.values, angles, ctx), False),
        float(np.max(tol)),
    )  # fmt: skip
    if data.trials:
        prepared = with_trial_offsets(prepared, res, data)
    if m == 6 and earth_rate_visible(data):
        # the heading is never trusted (a session's default is 0; wrong by 90°, it faked G
        # and temperature terms on 12 and 9 of 30 clean sessions): the horizontal part is
        # fitted, the vertical too when no latitude gives it
        axes = [0, 2] if data.latitude is not None else [0, 1, 2]
        columns = free_earth_rate(angles, s, m)[:, axes]
        names = tuple(EARTH_RATE_NAMES[i] for i in axes)
        prepared = with_nuisance(prepared, columns, names, ctx.w_level[axes])
    return prepared, res


TRIAL_OFFSET_PREFIX = "trial_offset"
"""Names of the trials' bias offsets in a known-position base fit:
``trial_offset[t].accel.bias[i]`` (and ``.gyro.bias[i]``)."""


def trial_offsets(
    averages: tuple[PositionAverage, ...] | list[PositionAverage], m: int
) -> tuple[tuple[str, ...], Array]:
    """Names and raw columns ``(n·m, (T − 1)·m)`` of the trials' bias offsets.

    The parametrisation ``solve`` uses (:mod:`canimucal.model.joint`): the biases of the base
    model are the trials' mean, trial ``t < T`` adds its offset ``δ_t`` and the last trial
    ``−Σ δ_t``; the offsets are linear, so their columns are the contrast on each bias
    channel. Empty with fewer than two trials.
    """
    ids, contrast = trial_contrast(averages)
    if not ids:
        return (), np.zeros((len(averages) * m, 0))
    n, t = contrast.shape
    columns = np.einsum("nj,cd->ncjd", contrast, np.eye(m)).reshape(n * m, t * m)
    channels = [f"accel.bias[{i}]" for i in range(3)] + [f"gyro.bias[{i}]" for i in range(m - 3)]
    names = tuple(f"{TRIAL_OFFSET_PREFIX}[{ids[j]}].{c}" for j in range(t) for c in channels)
    return names, columns


def trial_biases(
    names: tuple[str, ...], values: Array, trials: tuple[int, ...], sensor: str
) -> Array | None:
    """Each trial's ``sensor`` biases ``(T, 3)`` from a base fit's named values.

    The shared bias is the trials' mean, trial ``t < T`` adds its offset, the last the
    negative sum (docs/design.md §10 *Trials*). None with fewer than two trials or when
    ``sensor``'s biases are not among ``names`` (no gyro data).
    """
    index = {name: k for k, name in enumerate(names)}
    shared_names = [f"{sensor}.bias[{i}]" for i in range(3)]
    if not trials or not all(n in index for n in shared_names):
        return None
    shared = np.array([values[index[n]] for n in shared_names], dtype=float)
    offsets = np.array(
        [
            [values[index[f"{TRIAL_OFFSET_PREFIX}[{t}].{sensor}.bias[{i}]"]] for i in range(3)]
            for t in trials[:-1]
        ],
        dtype=float,
    )
    return np.asarray(shared + np.vstack([offsets, -offsets.sum(axis=0)]), dtype=float)


def with_trial_offsets(prepared: PreparedBase, res: JointResult, data: SessionData) -> PreparedBase:
    """Return ``prepared`` with the trials' bias offsets among its base parameters.

    ``res`` was fitted with them (its residuals are net of the offsets); their values are
    each trial's biases less the shared ones, their σ from the base fit's whitened design.
    """
    m = prepared.residual_table.shape[1]
    names, columns = trial_offsets(data.averages, m)
    assert res.trial_bias is not None
    shared = np.array([res.value(c.split(".", 1)[1]) for c in names[:m]])
    offsets = (res.trial_bias[:-1] - shared).ravel()
    design = np.hstack([prepared.jacobian, columns])
    chol = np.asarray(
        np.linalg.cholesky(0.5 * (prepared.covariance + prepared.covariance.T)), dtype=float
    )
    white = solve_lower(chol, design)
    cov = np.linalg.pinv(white.T @ white, hermitian=True)
    p = prepared.jacobian.shape[1]
    sigmas = np.sqrt(np.abs(np.diag(cov)))[p:]
    return dataclasses.replace(
        prepared,
        jacobian=design,
        names=prepared.names + names,
        values=np.concatenate([prepared.values, offsets]),
        sigmas=np.concatenate([prepared.sigmas, sigmas]),
    )


def earth_rate_visible(data: SessionData) -> bool:
    """Whether the Earth rate can bias the gyro tests: ``Σ_k Ω² / (σ_k² lsb²) ≥ 1``.

    ``σ_k²`` is the mean variance of position k's gyro mean (counts²); ``Ω/lsb`` the Earth
    rate in counts at the nominal scale. Below 1 the Earth rate adds less than one unit of
    non-centrality to any test, and fitting it would only cost degrees of freedom. A file
    without a gyro LSB (``gyro_lsb_known`` false) cannot rule it out.
    """
    if not data.has_gyro:
        return False
    if not data.gyro_lsb_known:
        return True  # its size in counts is unknown: it cannot be ruled out
    counts = EARTH_RATE_RAD_S / abs(data.gyro_lsb)
    variances = np.array([np.trace(np.asarray(a.cov_gyro)) / 3.0 for a in data.averages])
    return bool(np.sum(counts * counts / variances) >= 1.0)


def free_earth_rate(angles: Array, s_matrix: Array, m: int) -> Array:
    """``∂V_i/∂w_L = S C_i`` on each pose's gyro rows ``(n·m, 3)``: the unknown Earth rate."""
    c, _, _ = dcm_stack(angles, 0.0, 0.0, "rigid")
    n = angles.shape[0]
    cols = np.zeros((n, m, 3))
    cols[:, 3:] = s_matrix @ c
    return cols.reshape(n * m, 3)


def with_nuisance(
    prepared: PreparedBase, columns: Array, names: tuple[str, ...], start: Array
) -> PreparedBase:
    """Return the known-position ``prepared`` with the nuisance ``columns`` in its base model.

    ``start`` are the nuisance parameters' values in the base fit as it stands. The columns
    the base model already spans (in the whitened metric) are dropped, so the base Jacobian
    keeps full column rank; the kept ones are fitted with the base parameters by one
    generalised least-squares step, and the residuals, χ² and dof follow.
    """
    chol = np.asarray(
        np.linalg.cholesky(0.5 * (prepared.covariance + prepared.covariance.T)), dtype=float
    )
    jac_w = solve_lower(chol, prepared.jacobian)
    col_w = solve_lower(chol, columns)
    q = np.linalg.qr(jac_w)[0]
    off = col_w - q @ (q.T @ col_w)
    r, order = pivoted_qr(off)
    scale = max(float(np.max(np.linalg.norm(col_w, axis=0))), 1e-300)
    rank = int(np.sum(np.abs(np.diag(r)) > 1e-8 * scale))
    keep = np.sort(order[:rank])
    if rank == 0:
        return prepared
    design = np.hstack([prepared.jacobian, columns[:, keep]])
    design_w = np.hstack([jac_w, col_w[:, keep]])
    resid_w = solve_lower(chol, prepared.residual[:, None])[:, 0]
    step = np.linalg.lstsq(design_w, resid_w, rcond=None)[0]
    residual = prepared.residual - design @ step
    left = resid_w - design_w @ step
    p = prepared.jacobian.shape[1]
    sigmas = np.sqrt(np.abs(np.diag(np.linalg.inv(design_w.T @ design_w))))
    return dataclasses.replace(
        prepared,
        residual=residual,
        jacobian=design,
        names=prepared.names + tuple(names[i] for i in keep),
        values=np.concatenate([prepared.values + step[:p], start[keep] + step[p:]]),
        sigmas=np.concatenate([prepared.sigmas, sigmas[p:]]),
        residual_table=residual.reshape(prepared.residual_table.shape),
        chi2=float(left @ left),
        dof=max(prepared.dof - rank, 0),
    )


def unit_angle_covariance(
    layout: ParameterLayout, theta: Array, angles: Array, ctx: ModelContext
) -> Array:
    """``A_i = J_i J_iᵀ``: each mean's covariance per rad² of angle scatter (noise_model eq. 1)."""
    probe = np.full(angles.shape[0], UNIT_PROBE_RAD)
    cov = angle_error_moments(layout, theta, angles, ctx, probe).covariance
    return np.asarray(cov / UNIT_PROBE_RAD**2, dtype=float)


def block_covariance(data: SessionData, angle_cov: Array, within: bool = True) -> Array:
    """Covariance of the stacked means: within-position scatter plus angle errors (eq. 15)."""
    n, m = angle_cov.shape[:2]
    blocks = angle_cov.copy()
    for k, a in enumerate(data.averages if within else ()):
        blocks[k, :3, :3] += a.cov_accel
        if m == 6 and a.cov_gyro is not None:
            blocks[k, 3:, 3:] += a.cov_gyro
    cov = np.zeros((n * m, n * m))
    for k in range(n):
        cov[k * m : (k + 1) * m, k * m : (k + 1) * m] = blocks[k]
    return cov


def fit_scalar_base(data: SessionData) -> tuple[PreparedBase, ScalarFit]:
    """Scalar ``|f| = g`` base fit (model "6") plus the gyro bias, and its linearisation.

    With trials (docs/design.md §6 *Trials*) each trial has its own accelerometer and gyro
    bias, the trials' mean and ``T − 1`` offsets as in the known-angle fit, K shared: the
    scalar fit's offsets (:mod:`canimucal.model.scalar`, *Trials*) follow the gyro's among
    the base parameters, named as :data:`TRIAL_OFFSET_PREFIX` names them.
    """
    trials = bool(data.trials)
    fit = fit_scalar_averages(
        data.averages, data.g, model="6", accel_lsb=data.accel_lsb, by_trial=trials
    )
    means = np.array([a.mean_accel for a in data.averages])
    temps = _position_temperatures(data)
    dt = None if temps is None else temps - np.mean(temps)
    state = ScalarInputs(means, fit.position_bias, fit.M, data.has_gyro, dt)
    n = means.shape[0]
    jac_a = scalar_jacobian(state)
    f = (means - fit.position_bias) @ fit.M.T
    unit = f / np.linalg.norm(f, axis=1, keepdims=True)
    rows_m = unit @ fit.M
    var_a = np.array([r @ a.cov_accel @ r for r, a in zip(rows_m, data.averages, strict=True)])
    resid_a = data.g - np.linalg.norm(f, axis=1)  # observed g − predicted |f|
    gyro = data.has_gyro
    earth = gyro and earth_rate_visible(data)
    contrast = fit.contrast if trials else np.zeros((n, 0))
    offsets = 3 * contrast.shape[1]
    size = n + (3 * n if gyro else 0)
    p = 6 + (3 + offsets if gyro else 0) + (1 if earth else 0) + offsets
    cov, jac, resid = np.zeros((size, size)), np.zeros((size, p)), np.zeros(size)
    cov[:n, :n] = np.diag(var_a)
    jac[:n, :6] = jac_a
    if offsets:  # the accelerometer's offsets last: ∂|f|/∂δ_t is ∂|f|/∂b on trial t's rows
        jac[:n, p - offsets :] = np.einsum("nt,ni->nti", contrast, jac_a[:, :3]).reshape(n, -1)
    resid[:n] = resid_a
    names = [f"accel.bias[{i}]" for i in range(3)] + [f"accel.K[{i}][{i}]" for i in range(3)]
    values = list(fit.bias) + list(np.diag(fit.K))
    sigmas = list(fit.bias_sigma) + list(np.diag(fit.K_sigma))
    table = resid_a[:, None]
    labels: tuple[str, ...] = ("|f| - g (m/s²)",)
    earth_unit: Array | None = None  # accelerometer only: no gyro rows, no Earth rate
    if gyro:
        est, est_sigma, earth_unit = _scalar_gyro_rows(
            data, unit if earth else None, (cov, jac, resid), contrast
        )
        names += [f"gyro.bias[{i}]" for i in range(3)] + ([EARTH_RATE_VERTICAL] if earth else [])
        names += list(_scalar_offset_names(data.trials, "gyro"))
        values += list(est)
        sigmas += list(est_sigma)
        table = np.column_stack([table, resid[n:].reshape(n, 3)])
        labels += ("gyro.x", "gyro.y", "gyro.z")
    if offsets:
        names += list(_scalar_offset_names(data.trials, "accel"))
        values += list(fit.params[6:])
        sigmas += list(fit.sigma[6:])
    idx = np.arange(n, dtype=np.int64)
    block = np.concatenate([idx, np.repeat(idx, 3)])[:size]
    channel = np.concatenate([np.zeros(n, np.int64), np.tile(np.arange(3, 6), n)])[:size]
    sensor = np.where(channel < 3, "accel", "gyro").astype(np.str_)
    scale = np.where(channel < 3, 1.0, abs(data.gyro_lsb)).astype(float)
    cands = scalar_candidates(state)
    chi2 = float(np.sum(resid_a**2 / var_a))
    prepared = PreparedBase(
        "scalar", resid, jac, cov, block, scale, sensor, channel, tuple(cands),
        tuple(names), np.array(values), np.array(sigmas), table, labels, chi2,
        max(n - 6 - offsets, 0),
        within_covariance=None if earth_unit is None else cov,
        earth_unit_covariance=earth_unit,
    )  # fmt: skip
    return prepared, fit


def _scalar_offset_names(trials: tuple[int, ...], sensor: str) -> tuple[str, ...]:
    """Name the first ``T − 1`` trials' bias offsets of ``sensor`` as the joint fit does."""
    return tuple(
        f"{TRIAL_OFFSET_PREFIX}[{t}].{sensor}.bias[{i}]" for t in trials[:-1] for i in range(3)
    )


def _scalar_gyro_rows(
    data: SessionData,
    unit: Array | None,
    problem: tuple[Array, Array, Array],
    contrast: Array | None = None,
) -> tuple[Array, Array, Array | None]:
    """Fill the gyro rows (after the n accel rows) of the scalar problem ``(cov, jac, resid)``.

    Each gyro mean is ``V_k = B + c S u_k + e_k``, ``u_k = f_k/|f_k|`` (the measured up, the
    accelerometer's), ``S = I/gyro_lsb`` nominal, ``c`` the Earth rate's vertical part (rad/s
    at the nominal scale), and ``e_k`` the within-position noise plus the horizontal Earth
    rate of an unknown heading, ``(Ω_h²/2) S (I − u_k u_kᵀ) Sᵀ`` (module doc). ``B`` and
    ``c`` by generalised least squares (eq. 36 with the vertical term); ``unit`` None leaves
    the Earth rate out. ``contrast`` ``(n, T − 1)`` (trials, docs/design.md §6 *Trials*)
    adds each trial's offset ``δ_t`` to ``B`` (its columns after ``c``). Returns ``(B, c, δ)``
    (or less), their σ, and, for a gyro of unknown scale, the covariance per count² of
    horizontal Earth rate (else None: ``cov`` holds it).
    """
    cov, jac, resid = problem
    n = len(data.averages)
    vg = np.array([a.mean_gyro for a in data.averages], dtype=float)
    cg = np.array([a.cov_gyro for a in data.averages], dtype=float)
    design = np.broadcast_to(np.eye(3), (n, 3, 3))
    horizontal = np.zeros((n, 3, 3))
    if unit is not None:
        s = 1.0 / data.gyro_lsb
        design = np.concatenate([design, s * unit[:, :, None]], axis=2)
        horizontal = 0.5 * (np.eye(3) - np.einsum("ni,nj->nij", unit, unit))
    if contrast is not None and contrast.shape[1]:
        per_trial = np.einsum("nt,ij->nitj", contrast, np.eye(3)).reshape(n, 3, -1)
        design = np.concatenate([design, per_trial], axis=2)
    known = unit is not None and data.gyro_lsb_known
    if known:
        lat = data.latitude
        length = EARTH_RATE_RAD_S * (1.0 if lat is None else float(np.cos(lat)))
        cg = cg + (length / data.gyro_lsb) ** 2 * horizontal
    w = np.linalg.inv(cg)
    normal = np.einsum("nki,nkl,nlj->ij", design, w, design)
    info = np.linalg.pinv(normal, hermitian=True)
    est = info @ np.einsum("nki,nkl,nl->i", design, w, vg)
    earth_unit = None if unit is None or known else np.zeros_like(cov)
    q = design.shape[2]
    for k in range(n):
        rows = slice(n + 3 * k, n + 3 * k + 3)
        cov[rows, rows] = cg[k]
        jac[rows, 6 : 6 + q] = design[k]
        resid[rows] = vg[k] - design[k] @ est
        if earth_unit is not None:
            earth_unit[rows, rows] = horizontal[k]
    return est, np.sqrt(np.abs(np.diag(info))), earth_unit


def _position_temperatures(data: SessionData) -> Array | None:
    """Mean temperature of each position, or None when any position has none."""
    temps = []
    for w in data.windows:
        if w.temp_c is None or not np.any(np.isfinite(w.temp_c)):
            return None
        temps.append(float(np.nanmean(np.asarray(w.temp_c, dtype=np.float64))))
    return np.array(temps)


def temperature_status(data: SessionData) -> tuple[Array | None, str | None]:
    """Per-position temperatures if they can test ``temperature_bias``, else the reason."""
    temps = _position_temperatures(data)
    if temps is None:
        return None, "no temperature column"
    span = float(np.ptp(temps))
    if span < 0.5:
        return None, f"temperature constant within {span:.2f} °C"
    mids = np.array([float(np.mean(w.t_s)) for w in data.windows])
    design = np.column_stack([np.ones_like(mids), mids])
    resid = temps - design @ np.linalg.lstsq(design, temps, rcond=None)[0]
    if float(np.sqrt(np.mean(resid**2))) < 0.02 * span:
        return None, "temperature linear in time (indistinguishable from bias drift)"
    return temps, None


def named_values(prepared: PreparedBase) -> tuple[Mapping[str, float], Mapping[str, float]]:
    """Return the base estimates and σ by parameter name."""
    return (
        dict(zip(prepared.names, map(float, prepared.values), strict=True)),
        dict(zip(prepared.names, map(float, prepared.sigmas), strict=True)),
    )
