"""The base fits of the discrepancy loop, prepared for the linearised candidate tests.

Known positions: ``solve_joint`` with bias + diagonal K, no tilt, and the gyro bias with the
Earth rate through the nominal S (DESIGN §6). Unknown positions: the scalar ``|f| = g`` fit,
model "6" (bias + diagonal K), and the gyro bias. Each gives the raw residuals, the raw
Jacobian of the prediction, the covariance of the residual vector (within-position scatter,
angle tolerances, and a random-walk term when drift was found) and the candidates' columns.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from canimucal.analysis.candidates import (
    Candidate,
    ScalarState,
    known_position_candidates,
    scalar_candidates,
    scalar_jacobian,
)
from canimucal.analysis.data import SessionData
from canimucal.model.joint import JointResult, solve_joint
from canimucal.model.layout import (
    GyroSpec,
    JointSpec,
    ModelContext,
    ParameterLayout,
    angle_error_moments,
    predict,
)
from canimucal.model.scalar import ScalarFit, fit_scalar_averages

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


UNIT_PROBE_RAD = 1e-4
"""Angle scatter at which the per-radian angle covariance is probed (second order negligible)."""


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
    cov = _block_covariance(data, moments.covariance)
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
        _block_covariance(data, np.zeros_like(moments.covariance)),
        _block_covariance(data, _unit_angle_covariance(layout, res.values, angles, ctx), False),
        float(np.max(tol)),
    )  # fmt: skip
    return prepared, res


def _unit_angle_covariance(
    layout: ParameterLayout, theta: Array, angles: Array, ctx: ModelContext
) -> Array:
    """``A_i = J_i J_iᵀ``: each mean's covariance per rad² of angle scatter (noise_model eq. 1)."""
    probe = np.full(angles.shape[0], UNIT_PROBE_RAD)
    cov = angle_error_moments(layout, theta, angles, ctx, probe).covariance
    return np.asarray(cov / UNIT_PROBE_RAD**2, dtype=float)


def _block_covariance(data: SessionData, angle_cov: Array, within: bool = True) -> Array:
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
    """Scalar ``|f| = g`` base fit (model "6") plus the gyro bias, and its linearisation."""
    fit = fit_scalar_averages(data.averages, data.g, model="6", accel_lsb=data.accel_lsb)
    means = np.array([a.mean_accel for a in data.averages])
    state = ScalarState(means, fit.bias, fit.M, 3 if data.has_gyro else 0)
    n = means.shape[0]
    jac_a = scalar_jacobian(state)
    f = (means - fit.bias) @ fit.M.T
    unit = f / np.linalg.norm(f, axis=1, keepdims=True)
    rows_m = unit @ fit.M
    var_a = np.array([r @ a.cov_accel @ r for r, a in zip(rows_m, data.averages, strict=True)])
    resid_a = data.g - np.linalg.norm(f, axis=1)  # observed g − predicted |f|
    gyro = data.has_gyro
    size = n + (3 * n if gyro else 0)
    p = 6 + (3 if gyro else 0)
    cov, jac, resid = np.zeros((size, size)), np.zeros((size, p)), np.zeros(size)
    cov[:n, :n] = np.diag(var_a)
    jac[:n, :6] = jac_a
    resid[:n] = resid_a
    names = [f"accel.bias[{i}]" for i in range(3)] + [f"accel.K[{i}][{i}]" for i in range(3)]
    values = list(fit.bias) + list(np.diag(fit.K))
    sigmas = list(fit.bias_sigma) + list(np.diag(fit.K_sigma))
    table = resid_a[:, None]
    labels: tuple[str, ...] = ("|f| - g (m/s²)",)
    if gyro:
        bias, bias_sigma = _gyro_bias_rows(data, cov, jac, resid)
        names += [f"gyro.bias[{i}]" for i in range(3)]
        values += list(bias)
        sigmas += list(bias_sigma)
        table = np.column_stack([table, resid[n:].reshape(n, 3)])
        labels += ("gyro.x", "gyro.y", "gyro.z")
    idx = np.arange(n, dtype=np.int64)
    block = np.concatenate([idx, np.repeat(idx, 3)])[:size]
    channel = np.concatenate([np.zeros(n, np.int64), np.tile(np.arange(3, 6), n)])[:size]
    sensor = np.where(channel < 3, "accel", "gyro").astype(np.str_)
    scale = np.where(channel < 3, 1.0, abs(data.gyro_lsb)).astype(float)
    cands = scalar_candidates(state, _position_temperatures(data), gyro)
    chi2 = float(np.sum(resid_a**2 / var_a))
    prepared = PreparedBase(
        "scalar", resid, jac, cov, block, scale, sensor, channel, tuple(cands),
        tuple(names), np.array(values), np.array(sigmas), table, labels, chi2, max(n - 6, 0),
    )  # fmt: skip
    return prepared, fit


def _gyro_bias_rows(data: SessionData, cov: Array, jac: Array, resid: Array) -> tuple[Array, Array]:
    """Fill the gyro rows (after the n accel rows) of the scalar problem; bias and its σ."""
    n = len(data.averages)
    vg = np.array([a.mean_gyro for a in data.averages], dtype=float)
    cg = np.array([a.cov_gyro for a in data.averages], dtype=float)
    w = np.linalg.inv(cg)
    bias = np.linalg.solve(w.sum(axis=0), np.einsum("nij,nj->i", w, vg))  # eq. (36), weighted
    for k in range(n):
        rows = slice(n + 3 * k, n + 3 * k + 3)
        cov[rows, rows] = cg[k]
        jac[rows, 6:] = np.eye(3)
        resid[rows] = vg[k] - bias
    return bias, np.sqrt(np.diag(np.linalg.inv(w.sum(axis=0))))


def _position_temperatures(data: SessionData) -> Array | None:
    """Mean temperature of each position, or None when any position has none."""
    temps = []
    for w in data.windows:
        if w.temp_c is None or not np.any(np.isfinite(w.temp_c)):
            return None
        temps.append(float(np.nanmean(w.temp_c)))
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
