"""Accelerometer calibration without angle labels: fit ``|K⁻¹ (U_i − b)| = g``.

Data: the means ``U_i`` (counts) of static positions in unknown orientations, and the local
gravity ``g``. The model ``U = b + K f`` (docs/design.md §2) is inverted as ``f = M (U − b)`` with
``M = K⁻¹`` (m/s² per count), and the fit asks every corrected mean to have norm g.

**What |f| can see.** ``|R M (U − b)| = |M (U − b)|`` for every orthogonal R (rotations and
reflections), so only ``MᵀM`` is observable: 6 numbers, plus the 3 biases. Hence

- model ``"6"``: bias + diagonal M (diagonal K), 6 parameters;
- model ``"9"``: bias + **lower-triangular** M (so K = M⁻¹ is lower triangular too), 9
  parameters. Any M factors as ``M = R·L`` (R orthogonal, L lower triangular; a QL-type
  factorisation), so this is the whole observable family: the corrected x axis lies along the
  sensor's x axis and the corrected y axis in the sensor's x–y plane. A full 12-parameter
  (bias + 9 entries) fit is not identifiable: the 3 rotation angles of R leave |f| unchanged.
- The **sign** of each row of M (an inverted axis) is also invisible to |f|: the diagonal is
  given the sign of ``accel_lsb`` (positive when it is None). ``axis_sign`` is therefore
  untestable in scalar fits (docs/design.md §5).

**Trials** (several mountings of the unit in one recording, docs/design.md §6 *Trials*): a
unit taken off and fastened again keeps its scale and moves its bias, so with ``trials``
(one key per mean) each trial has its own bias and M is shared. As in the known-angle fit
(§10 *Trials*) the bias ``b`` is the trials' mean and the first ``T − 1`` trials add an offset
``δ_t``, the last ``−Σ δ_t``: ``f_i = M (U_i − b − c_iᵀ δ)`` with ``c_i`` the position's row of
the contrast (:func:`~canimucal.model.plan.offset_contrast`). The offsets follow the free
entries of M (of K in the reported parameters).

Reported parameters: the bias (counts) and the free entries of K (counts per m/s²), then the
trials' offsets, with their covariance propagated from that of (b, M, δ) through
``dK = −K dM K``. Covariance: from
the given per-mean ``weights`` (inverse variances of each mean's norm, (m/s²)⁻²), else from
the residual scatter, ``s²(JᵀJ)⁻¹`` with ``s² = RSS/dof``.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from canimucal.errors import ModelError
from canimucal.model.levmar import least_squares_lm
from canimucal.model.plan import offset_contrast
from canimucal.model.positions import PositionAverage

logger = logging.getLogger(__name__)

ScalarModel = Literal["6", "9"]
Array = NDArray[np.float64]

NOT_IDENTIFIABLE = 1e-10
"""Information eigenvalue ratio below which the fit is refused (docs/design.md §3)."""

POORLY_SEPARABLE = 1e-4
"""Information eigenvalue ratio below which a warning is logged (docs/design.md §3)."""

_FREE = {
    "6": ((0, 0), (1, 1), (2, 2)),
    "9": ((0, 0), (1, 0), (1, 1), (2, 0), (2, 1), (2, 2)),
}


@dataclass(frozen=True)
class ScalarFit:
    """Result of :func:`fit_scalar`.

    ``params`` = ``[bias (3), free entries of K, trial offsets]`` in the order of
    ``param_names``; ``covariance`` their covariance; ``residuals_mps2`` =
    ``|M (U_i − b_i)| − g`` per mean (``b_i`` its trial's bias); ``rms_mps2`` their root mean
    square; ``dof`` = means − parameters; ``reduced_chi2`` the weighted RSS over dof (1 when
    the covariance comes from the scatter). ``trials`` the trials, ascending (empty: one),
    and ``contrast`` ``(n, T − 1)`` the offsets' map to the means (module doc).
    """

    model: ScalarModel
    bias: Array
    K: Array
    M: Array
    params: Array
    param_names: tuple[str, ...]
    covariance: Array
    residuals_mps2: Array
    dof: int
    rms_mps2: float
    reduced_chi2: float
    converged: bool
    message: str
    trials: tuple[int, ...] = ()
    contrast: Array = field(default_factory=lambda: np.zeros((0, 0)))

    @property
    def sigma(self) -> Array:
        """Standard deviation of each parameter."""
        return np.sqrt(np.diag(self.covariance))

    @property
    def bias_sigma(self) -> Array:
        """σ of the bias (counts)."""
        return self.sigma[:3]

    @property
    def K_sigma(self) -> Array:
        """σ of K (counts per m/s²); NaN where the entry is not a parameter of the model."""
        out = np.full((3, 3), np.nan)
        free = _FREE[self.model]
        for (i, j), s in zip(free, self.sigma[3 : 3 + len(free)], strict=True):
            out[i, j] = s
        return out

    @property
    def position_bias(self) -> Array:
        """Each mean's bias ``(n, 3)`` (its trial's), or the one bias ``(3,)``."""
        return _row_bias(self.bias, self._offsets, self.contrast)

    @property
    def trial_bias(self) -> Array | None:
        """``(T, 3)`` each trial's bias (counts), the trials' order; None: one trial."""
        if not self.trials:
            return None
        return self.bias + _trial_map(len(self.trials)) @ self._offsets.reshape(-1, 3)

    @property
    def trial_bias_sigma(self) -> Array | None:
        """``(T, 3)`` σ of each trial's bias (counts); None: one trial."""
        if not self.trials:
            return None
        t = len(self.trials)
        # b_t = b + Σ_s A_ts δ_s on each channel: the covariance of (b, δ) mapped per channel
        cols = [0, 1, 2] + list(range(3 + len(_FREE[self.model]), self.params.size))
        cov = self.covariance[np.ix_(cols, cols)]
        out = np.zeros((t, 3))
        for i in range(3):
            rows = [i] + [3 + 3 * s + i for s in range(t - 1)]
            a = np.hstack([np.ones((t, 1)), _trial_map(t)])
            out[:, i] = np.sqrt(np.abs(np.einsum("tj,jk,tk->t", a, cov[np.ix_(rows, rows)], a)))
        return out

    @property
    def _offsets(self) -> Array:
        return self.params[3 + len(_FREE[self.model]) :]


def _trial_map(t: int) -> Array:
    """``(T, T − 1)``: trial ``s < T − 1`` adds ``δ_s``, the last ``−Σ δ_s`` (module doc)."""
    return np.vstack([np.eye(t - 1), -np.ones((1, t - 1))])


def fit_scalar(
    means: ArrayLike,
    g: float,
    *,
    model: ScalarModel = "6",
    weights: ArrayLike | None = None,
    accel_lsb: float | None = None,
    trials: Sequence[int | None] | None = None,
) -> ScalarFit:
    """Fit bias and K to static means ``(n, 3)`` (counts) so that ``|K⁻¹(U − b)| = g``.

    ``weights``: inverse variances of each mean's norm, (m/s²)⁻² (module doc). ``trials``:
    each mean's trial (None: one trial for all); two or more give each trial its own bias,
    M shared (module doc, *Trials*). Raises ModelError with fewer than parameters + 1 means,
    or when the orientations do not span enough directions (a rank-deficient linear
    ellipsoid fit or information matrix; a trial whose poses cannot fix its bias too).
    """
    ids, contrast = offset_contrast(list(trials) if trials is not None else [])
    if not ids:
        contrast = np.zeros((np.shape(means)[0] if np.ndim(means) == 2 else 0, 0))
    u, w, g_val = _validate(means, g, model, weights, 3 * contrast.shape[1])
    absolute = weights is not None
    sign = _lsb_sign(accel_lsb)
    theta0 = np.concatenate(
        [_pack(*_initial_guess(u, g_val, model, sign), model), np.zeros(3 * contrast.shape[1])]
    )
    sqrt_w = np.sqrt(w)

    def fun(theta: Array) -> Array:
        return sqrt_w * _residuals(theta, u, g_val, model, contrast)

    def jac(theta: Array) -> Array:
        return sqrt_w[:, None] * _jacobian(theta, u, model, contrast)

    # scipy's lm tolerances (1e-8); MINPACK only if the numpy search spends its budget
    sol = least_squares_lm(fun, theta0, jac, minpack_if_unfinished=True)
    bias, m, offsets = _unpack(sol.x, model)
    m = _fix_signs(m, sign)
    theta = np.concatenate([_pack(bias, m, model), offsets])
    status = (bool(sol.success), str(sol.message))
    return _result(theta, u, w, g_val, model, absolute, status, (ids, contrast))


def fit_scalar_averages(
    averages: Sequence[PositionAverage],
    g: float,
    *,
    model: ScalarModel = "6",
    accel_lsb: float | None = None,
    by_trial: bool = False,
) -> ScalarFit:
    """:func:`fit_scalar` on position averages, weighted by their covariances of the mean.

    An unweighted fit gives M; each mean's norm then has variance ``nᵀ M C Mᵀ n`` (n the unit
    direction of ``M (U − b)``, C its ``cov_accel``), and the fit is repeated with those weights.
    ``by_trial``: each average's ``trial`` gets its own bias (module doc, *Trials*).
    """
    means = np.array([a.mean_accel for a in averages])
    trials = [a.trial for a in averages] if by_trial else None
    first = fit_scalar(means, g, model=model, accel_lsb=accel_lsb, trials=trials)
    f = (means - first.position_bias) @ first.M.T
    n = f / np.linalg.norm(f, axis=1, keepdims=True)
    rows = n @ first.M
    var = np.array([r @ a.cov_accel @ r for r, a in zip(rows, averages, strict=True)])
    if np.any(~(var > 0.0)):
        raise ModelError("every average needs a positive-definite cov_accel for weighting")
    return fit_scalar(means, g, model=model, weights=1.0 / var, accel_lsb=accel_lsb, trials=trials)


def _lsb_sign(accel_lsb: float | None) -> float:
    if accel_lsb is None:
        return 1.0
    lsb = float(accel_lsb)
    if not np.isfinite(lsb) or lsb == 0.0:
        raise ModelError(f"accel_lsb must be finite and non-zero, got {accel_lsb!r}")
    return 1.0 if lsb > 0.0 else -1.0


def _validate(
    means: ArrayLike, g: float, model: str, weights: ArrayLike | None, offsets: int = 0
) -> tuple[Array, Array, float]:
    if model not in _FREE:
        raise ModelError(f"model must be '6' or '9', got {model!r}")
    u = np.asarray(means, dtype=float)
    if u.ndim != 2 or u.shape[1] != 3:
        raise ModelError(f"means must be an (n, 3) array, got shape {u.shape}")
    if not np.all(np.isfinite(u)):
        raise ModelError("means contain NaN or infinite values")
    p = 3 + len(_FREE[model]) + offsets
    if u.shape[0] < p + 1:
        raise ModelError(f"scalar model '{model}' needs at least {p + 1} means, got {u.shape[0]}")
    g_val = float(g)
    if not np.isfinite(g_val) or g_val <= 0.0:
        raise ModelError(f"g must be positive, got {g!r}")
    if weights is None:
        return u, np.ones(u.shape[0]), g_val
    w = np.broadcast_to(np.asarray(weights, dtype=float), (u.shape[0],)).copy()
    if np.any(~np.isfinite(w)) or np.any(w <= 0.0):
        raise ModelError("weights must be positive and finite")
    return u, w, g_val


def _initial_guess(u: Array, g: float, model: str, sign: float) -> tuple[Array, Array]:
    """Linear ellipsoid fit in normalised coordinates, then ``M`` with ``MᵀM = A``.

    ``uᵀAu + 2hᵀu = 1`` (A diagonal for model 6) is linear in (A, h): least squares. The
    centre is ``−A⁻¹h``; A must come out positive definite.
    """
    c0 = u.mean(axis=0)
    s0 = float(np.sqrt(np.mean(np.sum((u - c0) ** 2, axis=1))))
    if s0 == 0.0:
        raise ModelError("all means are equal: the orientations do not span any direction")
    x = (u - c0) / s0
    quad = [x[:, 0] ** 2, x[:, 1] ** 2, x[:, 2] ** 2]
    if model == "9":
        quad += [2 * x[:, 0] * x[:, 1], 2 * x[:, 0] * x[:, 2], 2 * x[:, 1] * x[:, 2]]
    design = np.column_stack(quad + [2 * x[:, 0], 2 * x[:, 1], 2 * x[:, 2]])
    sv = np.linalg.svd(design, compute_uv=False)
    if sv[-1] <= 1e-9 * sv[0]:
        raise ModelError(
            f"the orientations do not span enough directions for scalar model '{model}' "
            f"(ellipsoid design rank {int(np.sum(sv > 1e-9 * sv[0]))} < {design.shape[1]})"
        )
    p, *_ = np.linalg.lstsq(design, np.ones(u.shape[0]), rcond=None)
    a = np.diag(p[:3])
    if model == "9":
        a[0, 1] = a[1, 0] = p[3]
        a[0, 2] = a[2, 0] = p[4]
        a[1, 2] = a[2, 1] = p[5]
    h = p[-3:]
    try:
        centre = -np.linalg.solve(a, h)
        rho = 1.0 + centre @ a @ centre
        m_norm = _lower_root(g**2 * a / rho)
    except np.linalg.LinAlgError:
        logger.warning("ellipsoid initial guess failed; starting from the data's centre")
        return c0, sign * np.eye(3) * g / s0
    return c0 + s0 * centre, _fix_signs(m_norm / s0, sign)


def _lower_root(a: Array) -> Array:
    """Lower-triangular L with ``LᵀL = a`` (a positive definite): ``J chol(J a J)ᵀ J``."""
    j = np.eye(3)[::-1]
    return j @ np.linalg.cholesky(j @ a @ j).T @ j


def _fix_signs(m: Array, sign: float) -> Array:
    """Flip rows so that every diagonal entry has ``sign`` (a reflection |f| cannot see)."""
    flip = np.where(np.sign(np.diag(m)) == sign, 1.0, -1.0)
    return flip[:, None] * m


def _pack(bias: Array, m: Array, model: str) -> Array:
    return np.concatenate((bias, [m[i, j] for i, j in _FREE[model]]))


def _unpack(theta: Array, model: str) -> tuple[Array, Array, Array]:
    """Return the bias (the trials' mean), M and the trials' offsets ``δ`` (flat)."""
    free = _FREE[model]
    m = np.zeros((3, 3))
    for (i, j), v in zip(free, theta[3 : 3 + len(free)], strict=True):
        m[i, j] = v
    return theta[:3], m, theta[3 + len(free) :]


def _row_bias(bias: Array, offsets: Array, contrast: Array) -> Array:
    """Each mean's bias: the trials' mean plus its trial's offset (module doc, *Trials*)."""
    if contrast.shape[1] == 0:
        return bias
    return np.asarray(bias + contrast @ offsets.reshape(-1, 3))


def _residuals(theta: Array, u: Array, g: float, model: str, contrast: Array) -> Array:
    bias, m, offsets = _unpack(theta, model)
    return np.linalg.norm((u - _row_bias(bias, offsets, contrast)) @ m.T, axis=1) - g


def _jacobian(theta: Array, u: Array, model: str, contrast: Array) -> Array:
    """``∂r/∂b = −nᵀM``, ``∂r/∂M_jk = n_j (U − b)_k`` with ``n = f/|f|``; ``∂r/∂δ``.

    ``∂r/∂δ_t`` is ``∂r/∂b`` times the mean's contrast entry for trial ``t`` (module doc,
    *Trials*).
    """
    bias, m, offsets = _unpack(theta, model)
    d = u - _row_bias(bias, offsets, contrast)
    f = d @ m.T
    n = f / np.linalg.norm(f, axis=1, keepdims=True)
    back = -(n @ m)
    cols = [back] + [(n[:, i] * d[:, j])[:, None] for i, j in _FREE[model]]
    if contrast.shape[1]:
        cols.append(np.einsum("nt,ni->nti", contrast, back).reshape(u.shape[0], -1))
    return np.hstack(cols)


def _result(
    theta: Array,
    u: Array,
    w: Array,
    g: float,
    model: ScalarModel,
    absolute: bool,
    status: tuple[bool, str],
    trials: tuple[tuple[int, ...], Array],
) -> ScalarFit:
    ids, contrast = trials
    bias, m, offsets = _unpack(theta, model)
    resid = _residuals(theta, u, g, model, contrast)
    jac = np.sqrt(w)[:, None] * _jacobian(theta, u, model, contrast)
    dof = u.shape[0] - theta.size
    chi2 = float(np.sum(w * resid**2)) / dof
    names = _names(model) + _offset_names(ids)
    cov_internal = _covariance(jac, model, _internal_names(model) + _offset_names(ids))
    if not absolute:
        cov_internal = cov_internal * chi2
    k: Array = np.asarray(np.linalg.inv(m), dtype=float)
    transform = _to_k_params(k, model, offsets.size)
    return ScalarFit(
        model=model,
        bias=bias.copy(),
        K=k,
        M=m,
        params=np.concatenate([_pack(bias, k, model), offsets]),
        param_names=names,
        covariance=transform @ cov_internal @ transform.T,
        residuals_mps2=resid,
        dof=dof,
        rms_mps2=float(np.sqrt(np.mean(resid**2))),
        reduced_chi2=chi2 if absolute else 1.0,
        converged=status[0],
        message=status[1],
        trials=ids,
        contrast=contrast,
    )


def _covariance(jac: Array, model: str, names: tuple[str, ...]) -> Array:
    """``(JᵀJ)⁻¹`` with column scaling; refuses a rank-deficient information matrix."""
    scale = np.linalg.norm(jac, axis=0)
    scale[scale == 0.0] = 1.0
    info = (jac / scale).T @ (jac / scale)
    eig, vec = np.linalg.eigh(info)
    ratio = eig[0] / eig[-1]
    if ratio < NOT_IDENTIFIABLE:
        raise ModelError(
            f"the orientations do not span enough directions for scalar model '{model}' "
            f"(information eigenvalue ratio {ratio:.1e})"
        )
    if ratio < POORLY_SEPARABLE:
        worst = np.argsort(-(vec[:, 0] ** 2))[:3]
        worst_names = [names[i] for i in worst]
        logger.warning(
            "scalar fit poorly separable (ratio %.1e): %s", ratio, ", ".join(worst_names)
        )
    inv = (vec / eig) @ vec.T
    return inv / np.outer(scale, scale)


def _to_k_params(k: Array, model: str, offsets: int = 0) -> Array:
    """Jacobian of (b, free K, δ) with respect to (b, free M, δ): ``dK = −K dM K``."""
    free = _FREE[model]
    t = np.eye(3 + len(free) + offsets)
    for col, (i, j) in enumerate(free):
        unit = np.zeros((3, 3))
        unit[i, j] = 1.0
        dk = -k @ unit @ k
        t[3 : 3 + len(free), 3 + col] = [dk[a, b] for a, b in free]
    return t


def _names(model: str) -> tuple[str, ...]:
    return tuple(f"bias[{i}]" for i in range(3)) + tuple(f"K[{i}][{j}]" for i, j in _FREE[model])


def _internal_names(model: str) -> tuple[str, ...]:
    return tuple(f"bias[{i}]" for i in range(3)) + tuple(f"M[{i}][{j}]" for i, j in _FREE[model])


def _offset_names(ids: tuple[int, ...]) -> tuple[str, ...]:
    """``trial_offset[t].bias[i]`` of the first ``T − 1`` trials (module doc, *Trials*)."""
    return tuple(f"trial_offset[{t}].bias[{i}]" for t in ids[:-1] for i in range(3))
