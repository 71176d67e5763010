"""Joint least-squares calibration of bias, K, base tilt and gyro terms, with uncertainty.

All positions and channels are fitted at once with ``scipy.optimize.least_squares`` on
residuals whitened by each position's covariance. The angle-setting tolerances enter that
covariance (errors in variables): ``Σ_i = cov_i + J_i diag(tol²) J_iᵀ`` with ``J_i`` the
derivative of the predicted mean with respect to the position's angles, plus the
second-order terms (a mean shift and a covariance ``½ tr(H_a T H_b T)``) that matter at
tolerances near 1°; all re-evaluated at the estimate over a few passes. The forward model
lives in :mod:`canimucal.model.layout`; the information analysis in :mod:`.plan`.

A prior (a factory K with its σ, for plans that cannot separate K from the biases) enters
as one pseudo-observation per parameter, ``(θ_j − μ_j)/σ_j`` appended to the whitened
residuals: the maximum a posteriori estimate under a Gaussian prior, whose information
``diag(1/σ²)`` adds to the data's (Tarantola, *Inverse Problem Theory*, 2005, eq. 3.37;
Bar-Shalom et al., *Estimation with Applications to Tracking*, 2001, §3.4).

Without a latitude the gyro's Earth-rate term is not known, yet it is there in every static
gyro mean (up to 7.3e-5 rad/s, a few hundredths of a count at 120 s averages: many σ). Left
out, it fails the fit's χ² on a clean unit whose poses turn (docs/design.md §3). With
``unknown_earth_rate`` (what :func:`~canimucal.analysis.calibrate.solve_positions` asks) it enters
as a nuisance: the Earth rate in the level frame, three parameters ``w_L`` with the prior
``N(0, Ω²/3·I)`` (the second moment of a rate of magnitude Ω in an unknown direction), fitted
with the rest and then marginalised (the Schur complement of the information); χ² counts
their prior rows and the dof does not change (three rows, three parameters). The gyro biases
then carry the part of the Earth rate the poses cannot tell from them.

Trials (several mountings of one unit, ``PositionAverage.trial``): each trial has its own
biases (accelerometer, and gyro when fitted), K, S, G and the tilt shared. The layout's
biases are then the trials' mean, and ``T − 1`` offsets per bias channel ride along
(``δ_t`` for the first ``T − 1`` trials, ``δ_T = −Σ δ_t``: offsets summing to zero). They
are linear and enter no angle derivative; the theta covariance and rank marginalise them,
the dof count them, and ``JointResult.trial_bias`` holds each trial's biases with their
covariance.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray

from canimucal.errors import ModelError
from canimucal.model.frames import EARTH_RATE_RAD_S, body_vectors
from canimucal.model.layout import (
    JointSpec,
    ModelContext,
    ModelParams,
    ParameterLayout,
    angle_error_moments,
    nominal_theta,
    predict,
)
from canimucal.model.levmar import LeastSquaresResult, least_squares_lm
from canimucal.model.plan import (
    NOT_IDENTIFIABLE_RATIO,
    Separability,
    analyse_information,
    offset_contrast,
)
from canimucal.model.positions import PositionAverage
from canimucal.model.sensor import DEFAULT_ACCEL_LSB, DEFAULT_GYRO_LSB, AccelParams, GyroParams
from canimucal.model.small_linalg import pivoted_qr

log = logging.getLogger(__name__)

Array = NDArray[np.float64]


@dataclass(frozen=True)
class JointResult:
    """Frozen result of :func:`solve_joint` (units: counts, counts per m/s², radians).

    ``values`` and ``covariance`` follow ``names``; undetermined parameters are NaN there and
    listed with their reason in ``undetermined``. ``residuals`` are observed − predicted,
    ``(n_positions, channels)`` counts; ``jacobian`` is that of the whitened residuals.
    """

    names: tuple[str, ...]
    values: Array
    covariance: Array
    residuals: Array
    whitened_residuals: Array
    jacobian: Array
    dof: int
    chi2: float
    converged: bool
    message: str
    rms_accel_ms2: float
    separability: Separability
    spec: JointSpec
    accel_lsb: float = DEFAULT_ACCEL_LSB
    gyro_lsb: float = DEFAULT_GYRO_LSB
    undetermined: Mapping[str, str] = field(default_factory=dict)
    trials: tuple[int, ...] = ()
    """The trial of each row of ``trial_bias`` (empty without trials)."""
    trial_bias: Array | None = None
    """``(n_trials, channels)``: each trial's biases (accelerometer, then gyro), counts."""
    trial_bias_cov: Array | None = None
    """``(n_trials, channels, channels)``: the covariance of each trial's biases."""

    def value(self, name: str) -> float:
        """Return the estimate of parameter ``name`` (NaN when undetermined)."""
        return float(self.values[self._index(name)])

    def sigma(self, name: str) -> float:
        """Return the standard deviation of parameter ``name`` (NaN when undetermined)."""
        k = self._index(name)
        return float(np.sqrt(self.covariance[k, k]))

    def _index(self, name: str) -> int:
        if name not in self.names:
            raise ModelError(f"no parameter {name!r} in this result")
        return self.names.index(name)

    def _params(self) -> ModelParams:
        layout = ParameterLayout.of(self.spec)
        nominal = nominal_theta(layout, self.accel_lsb, self.gyro_lsb)
        theta = np.where(np.isnan(self.values), nominal, self.values)
        return layout.unpack(theta, self.gyro_lsb)

    def accel_params(self) -> AccelParams:
        """Accelerometer bias and K (undetermined entries at their nominal values)."""
        p = self._params()
        return AccelParams(p.accel_bias, p.K)

    def gyro_params(self) -> GyroParams | None:
        """Gyro bias, S and G, or None when no gyro was fitted (nominal where not estimated)."""
        if self.spec.gyro == "none":
            return None
        p = self._params()
        return GyroParams(p.gyro_bias, p.S, p.G)

    @property
    def tilt(self) -> tuple[float, float]:
        """Base tilt ``(alpha0, beta0)`` in radians (zeros when not estimated)."""
        p = self._params()
        return p.alpha0, p.beta0

    @property
    def trim(self) -> NDArray[np.float64]:
        """Mounting trim ``(alpha_m, beta_m, psi_m)`` in radians (zeros when not estimated)."""
        return np.asarray(self._params().trim, dtype=float)


@dataclass(frozen=True)
class _Data:
    """Validated input arrays: angles ``(n, 3)``, observations ``(n, m)``, covariances."""

    angles: Array
    observed: Array
    base_cov: Array
    tolerances: Array
    prior: _Prior
    earth_sigma: float = 0.0
    """Prior σ (rad/s, each level axis) of the unknown Earth rate; 0: known or not seen."""
    contrast: Array = field(default_factory=lambda: np.zeros((0, 0)))
    """``(n, T − 1)``: each position's row of the trials' offset contrast (module doc)."""
    trial_ids: tuple[int, ...] = ()

    @property
    def nuisance(self) -> int:
        """How many nuisance parameters (the unknown Earth rate) ride along with theta."""
        return 3 if self.earth_sigma > 0 else 0

    @property
    def offsets(self) -> int:
        """How many trial offsets ride along with theta (``(T − 1)·channels``)."""
        return self.contrast.shape[1] * self.observed.shape[1]

    def offset_columns(self) -> Array:
        """d(predicted means)/d(trial offsets), ``(n, m, offsets)``."""
        m = self.observed.shape[1]
        n, t = self.contrast.shape
        return np.einsum("nj,cd->ncjd", self.contrast, np.eye(m)).reshape(n, m, t * m)

    def offset_means(self, d: Array) -> Array:
        """Return the trial offsets ``d`` as each position's ``(n, m)`` shift of its means."""
        if self.offsets == 0:
            return np.zeros_like(self.observed)
        return self.contrast @ d.reshape(self.contrast.shape[1], self.observed.shape[1])


@dataclass(frozen=True)
class _Prior:
    """Pseudo-observations: parameter indices, prior means and σ (empty without a prior)."""

    index: NDArray[np.intp]
    mean: Array
    sigma: Array

    def rows(self, theta: Array, free: NDArray[np.bool_]) -> Array:
        """Whitened prior residuals ``(θ_j − μ_j)/σ_j`` of the free parameters."""
        keep = free[self.index]
        return (theta[self.index[keep]] - self.mean[keep]) / self.sigma[keep]

    def jacobian(self, free: NDArray[np.bool_]) -> Array:
        """d(prior rows)/d(free parameters)."""
        keep = free[self.index]
        columns = np.cumsum(free) - 1
        out = np.zeros((int(np.sum(keep)), int(np.sum(free))))
        out[np.arange(out.shape[0]), columns[self.index[keep]]] = 1.0 / self.sigma[keep]
        return out

    def information(self, size: int) -> Array:
        """``diag(1/σ²)`` over the parameters the prior holds."""
        out = np.zeros((size, size))
        out[self.index, self.index] = 1.0 / self.sigma**2
        return out


def solve_joint(
    averages: Sequence[PositionAverage],
    spec: JointSpec,
    *,
    g: float,
    latitude: float | None = None,
    heading: float = 0.0,
    accel_lsb: float = DEFAULT_ACCEL_LSB,
    gyro_lsb: float = DEFAULT_GYRO_LSB,
    initial: Mapping[str, float] | None = None,
    allow_undetermined: bool = False,
    passes: int = 3,
    prior: Mapping[str, tuple[float, float]] | None = None,
    unknown_earth_rate: bool = False,
) -> JointResult:
    """Fit ``spec`` to the position averages by whitened nonlinear least squares.

    ``g`` m/s², ``latitude``/``heading`` radians (the Earth-rate term of the gyro model).
    ``initial`` overrides starting values by parameter name. A plan that cannot determine
    some parameters raises :class:`ModelError`, or with ``allow_undetermined`` holds them at
    their starting values and reports them in ``JointResult.undetermined`` (values NaN).
    ``prior`` maps parameter names to ``(mean, σ)``: each is a pseudo-observation (module
    docstring), its residual counted in χ² and dof; the prior mean is also the start.
    ``unknown_earth_rate`` with a gyro model and no ``latitude``: the Earth rate is a fitted
    and marginalised nuisance (module docstring; what a calibration does); without it the
    gyro model has no Earth-rate term (the discrepancy analysis tests that term itself).
    """
    layout = ParameterLayout.of(spec)
    data = _validate(averages, spec, g, latitude, allow_undetermined, _prior(layout, prior))
    if not unknown_earth_rate:
        data = replace(data, earth_sigma=0.0)
    ctx = ModelContext.build(g, latitude, heading, gyro_lsb)
    theta = _initial_guess(layout, data, ctx, accel_lsb, gyro_lsb)
    theta[data.prior.index] = data.prior.mean
    for name, value in (initial or {}).items():
        theta[layout.index(name)] = float(value)
    omega = np.zeros(data.nuisance)
    offsets = np.zeros(data.offsets)
    info = _marginal(_whitened_information(layout, theta, omega, data, ctx), layout.size)
    scales = rank_scales(info, layout.effect_scales(g, 1.0 / accel_lsb))
    check = analyse_information(info, layout.names, scales)
    free = _free_mask(layout, check, allow_undetermined)
    message, converged = "", True
    for _ in range(max(1, passes)):
        weights = _weights(layout, theta, data, _with_rate(ctx, omega))
        problem = _Problem(layout, theta, omega, free, weights, data, ctx, offsets)
        fit = _least_squares(problem)
        problem.split(fit.x)
        theta, omega, offsets = problem.theta.copy(), problem.omega.copy(), problem.offsets.copy()
        message, converged = str(fit.message), bool(fit.status > 0)
    return _result(
        layout,
        theta,
        free,
        data,
        _with_rate(ctx, omega),
        (converged, message),
        (accel_lsb, gyro_lsb),
        offsets,
    )


def _prior(layout: ParameterLayout, prior: Mapping[str, tuple[float, float]] | None) -> _Prior:
    items = list((prior or {}).items())
    for name, (value, spread) in items:
        if not (np.isfinite(value) and np.isfinite(spread) and spread > 0):
            raise ModelError(
                f"prior of {name}: mean must be finite and σ > 0, got {value}, {spread}"
            )
    index = np.array([layout.index(name) for name, _ in items], dtype=np.intp)
    means = np.array([float(m) for _, (m, _s) in items], dtype=float)
    sigmas = np.array([float(s) for _, (_m, s) in items], dtype=float)
    return _Prior(index, means, sigmas)


def _validate(
    averages: Sequence[PositionAverage],
    spec: JointSpec,
    g: float,
    latitude: float | None,
    allow_undetermined: bool,
    prior: _Prior,
) -> _Data:
    if not np.isfinite(g) or g <= 0:
        raise ModelError(f"g must be a positive finite number, got {g!r}")
    if spec.gyro == "nav" and latitude is None:
        raise ModelError("gyro model 'nav' needs a latitude (its scale comes from Earth rate)")
    n, m = len(averages), spec.channels
    p = ParameterLayout.of(spec).size
    if n == 0:
        raise ModelError("no positions given")
    if n * m + prior.index.size < p and not allow_undetermined:
        need = -(-p // m)
        raise ModelError(
            f"the model has {p} parameters but {n} positions give only {n * m} equations; "
            f"need at least {need} positions"
        )
    obs, cov = np.zeros((n, m)), np.zeros((n, m, m))
    for k, a in enumerate(averages):
        obs[k, :3], cov[k, :3, :3] = _checked(k, "accel", a.mean_accel, a.cov_accel)
        if m == 6:
            if a.mean_gyro is None or a.cov_gyro is None:
                raise ModelError(f"gyro model {spec.gyro!r} needs gyro data; position {k} has none")
            obs[k, 3:], cov[k, 3:, 3:] = _checked(k, "gyro", a.mean_gyro, a.cov_gyro)
    angles = np.array([a.pose.angles for a in averages], dtype=float)
    tol = np.array([a.pose.tolerances for a in averages], dtype=float)
    if not (np.all(np.isfinite(angles)) and np.all(np.isfinite(tol)) and np.all(tol >= 0)):
        raise ModelError("position angles and tolerances must be finite (tolerance >= 0)")
    unknown_rate = m == 6 and latitude is None  # the module docstring: a nuisance
    earth_sigma = EARTH_RATE_RAD_S / np.sqrt(3.0) if unknown_rate else 0.0
    ids, contrast = trial_contrast(averages)
    return _Data(angles, obs, cov, tol, prior, float(earth_sigma), contrast, ids)


def trial_contrast(averages: Sequence[PositionAverage]) -> tuple[tuple[int, ...], Array]:
    """Return the trials of ``averages`` and the contrast of their offsets (module doc).

    Trials ascending (a position without one is trial -1); the ``(n, T − 1)`` contrast maps
    the offsets to positions (:func:`~canimucal.model.plan.offset_contrast`). ``((), (n, 0))``
    with fewer than two trials.
    """
    return offset_contrast([a.trial for a in averages])


def _checked(k: int, what: str, mean: object, cov: object) -> tuple[Array, Array]:
    mu = np.asarray(mean, dtype=float)
    c = np.asarray(cov, dtype=float)
    if mu.shape != (3,) or c.shape != (3, 3):
        raise ModelError(f"position {k}: {what} mean must be (3,) and covariance (3, 3)")
    if not (np.all(np.isfinite(mu)) and np.all(np.isfinite(c))):
        raise ModelError(f"position {k}: {what} mean or covariance has NaN/infinite values")
    try:
        np.linalg.cholesky(0.5 * (c + c.T))
    except np.linalg.LinAlgError:
        raise ModelError(f"position {k}: {what} covariance is not positive definite") from None
    return mu, c


def _initial_guess(
    layout: ParameterLayout, data: _Data, ctx: ModelContext, accel_lsb: float, gyro_lsb: float
) -> Array:
    """Nominal K and S (sign kept), biases (and K, S, G where possible) from a linear fit.

    The fit assumes zero base tilt: ``U_i = b_i + Σ_j K_ij f_j`` per channel (eq. 8).
    """
    nominal = layout.unpack(nominal_theta(layout, accel_lsb, gyro_lsb), gyro_lsb)
    f = body_vectors(data.angles, ctx.f_level)
    w = body_vectors(data.angles, ctx.w_level)
    u, v = data.observed[:, :3], data.observed[:, 3:]
    bias, k = _linear_rows(u, f, nominal.K, layout.k_entries)
    gb, s, gg = nominal.gyro_bias, nominal.S, nominal.G
    if layout.spec.gyro != "none":
        gb, s = _linear_rows(v - f @ gg.T, w, nominal.S, layout.s_entries)
        if layout.g_entries:
            gb, gg = _linear_rows(v - w @ s.T, f, gg, layout.g_entries)
    return layout.pack(ModelParams(bias, k, 0.0, 0.0, gb, s, gg))


def _linear_rows(
    y: Array, x: Array, nominal: Array, entries: Sequence[tuple[int, int]]
) -> tuple[Array, Array]:
    """Per-row linear fit ``y_i = c_i + Σ_j M_ij x_j`` over ``entries``; nominal if singular."""
    mat = nominal.copy()
    offset = np.zeros(3)
    for i in range(3):
        cols = [j for r, j in entries if r == i]
        fixed = [j for j in range(3) if j not in cols]
        target = y[:, i] - x[:, fixed] @ nominal[i, fixed]
        design = np.column_stack([np.ones(len(y)), x[:, cols]])
        norms = np.linalg.norm(design, axis=0)
        norms[norms == 0] = 1.0
        sol, _res, rank, _sv = np.linalg.lstsq(design / norms, target, rcond=None)
        if rank < design.shape[1]:
            offset[i] = float(np.mean(y[:, i] - x @ nominal[i]))
            continue
        sol = sol / norms
        offset[i] = sol[0]
        mat[i, cols] = sol[1:]
    return offset, mat


@dataclass(frozen=True)
class _Weights:
    """Whitening of one pass: ``L_i⁻¹`` of each position's covariance, and the mean shift.

    Both come from the angle errors' moments at one estimate and are held over a pass.
    """

    whitener: Array
    shift: Array


def _weights(layout: ParameterLayout, theta: Array, data: _Data, ctx: ModelContext) -> _Weights:
    moments = angle_error_moments(layout, theta, data.angles, ctx, data.tolerances)
    covs = data.base_cov + moments.covariance
    chol = np.linalg.cholesky(0.5 * (covs + np.swapaxes(covs, 1, 2)))
    return _Weights(np.linalg.inv(chol), moments.shift)


def _with_rate(ctx: ModelContext, omega: Array) -> ModelContext:
    """``ctx`` with the nuisance Earth rate ``omega`` (rad/s in L) when one is fitted."""
    return ctx if omega.size == 0 else replace(ctx, w_level=np.asarray(omega, dtype=float))


def _rate_columns(layout: ParameterLayout, theta: Array, data: _Data, ctx: ModelContext) -> Array:
    """d(predicted means)/d(Earth rate in L), ``(n, m, 3)``: the model is linear in it."""
    zero = predict(layout, theta, data.angles, _with_rate(ctx, np.zeros(3))).mean
    columns = [
        predict(layout, theta, data.angles, _with_rate(ctx, e)).mean - zero for e in np.eye(3)
    ]
    return np.stack(columns, axis=2)


def _marginal(info: Array, p: int) -> Array:
    """Return the information of the first ``p`` parameters, the others marginalised."""
    if info.shape[0] == p:
        return info
    own, cross = info[:p, :p], info[:p, p:]
    return own - cross @ np.linalg.solve(info[p:, p:], cross.T)


def _whitened_information(
    layout: ParameterLayout, theta: Array, omega: Array, data: _Data, ctx: ModelContext
) -> Array:
    """Return the information of theta, the trial offsets and the Earth rate, in that order.

    The prior's information and the Earth rate's prior are included.
    """
    ctx = _with_rate(ctx, omega)
    pred = predict(layout, theta, data.angles, ctx)
    d_theta = np.concatenate([pred.d_theta, data.offset_columns()], axis=2)
    if data.nuisance:
        d_theta = np.concatenate([d_theta, _rate_columns(layout, theta, data, ctx)], axis=2)
    jw = np.einsum("nij,njp->nip", _weights(layout, theta, data, ctx).whitener, d_theta)
    jw = jw.reshape(-1, d_theta.shape[2])
    info = jw.T @ jw
    p = layout.size
    info[:p, :p] += data.prior.information(p)
    if data.nuisance:
        info[-data.nuisance :, -data.nuisance :] += np.eye(data.nuisance) / data.earth_sigma**2
    return info


UNSEEN_INFORMATION = 1e-20
"""A parameter whose information (at its effect at 1 g) is below this × the best-seen one's is
not seen at all by the data: its rank is judged at that effect, not at its own precision."""


def rank_scales(info: Array, effect: Array) -> Array:
    """Scales for the fit's rank decision: each parameter at its own precision, ``√F_jj``.

    A fit's information mixes precisions many decades apart: the gyro's biases against the
    accelerometer's terms, and within the accelerometer the directions along gravity (noise
    only) against those the pose scatter blurs (``(τ g)²``). Normalised by the effects at 1 g
    (the plan table's yardstick, docs/design.md §3), a large estimated scatter or a precise
    gyro pushed the accelerometer's weakest combinations below the 1e-10 rank threshold, and
    the fit held every bias and K entry at nominal though the accelerometer's own fit
    determines them (issue 21: the five-position plan, full K, the scatter's bound 0.6°).
    Scaled to unit diagonal (Jacobi's scaling, the best diagonal one for a matrix's
    condition: van der Sluis 1969), the eigenvalues measure collinearity alone. A parameter
    the data do not see at all (information below :data:`UNSEEN_INFORMATION` of the best
    seen, at the effect scales) keeps its effect scale, so it stays undetermined.
    """
    diag = np.clip(np.diag(info), 0.0, None)
    seen = diag / effect**2
    top = float(np.max(seen)) if seen.size else 0.0
    own = np.sqrt(diag)
    unseen = seen <= UNSEEN_INFORMATION * top
    return np.where(unseen, effect * np.sqrt(max(top, 1e-300)), own)


def _free_mask(layout: ParameterLayout, check: Separability, allow: bool) -> NDArray[np.bool_]:
    """Parameters to fit; with ``allow``, hold enough undetermined ones to restore the rank."""
    free = np.ones(layout.size, dtype=bool)
    if not check.undetermined:
        return free
    if not allow:
        raise ModelError(
            "the plan cannot determine "
            + ", ".join(check.undetermined)
            + f" for this model ({check.findings[0].message})"
        )
    null_vectors = check.eigenvectors[:, check.eigenvalue_ratios < NOT_IDENTIFIABLE_RATIO]
    _r, pivots = pivoted_qr(null_vectors.T)
    free[pivots[: null_vectors.shape[1]]] = False
    log.warning(
        "holding %s at their starting values", [layout.names[k] for k in np.flatnonzero(~free)]
    )
    return free


class _Problem:
    """Whitened residuals and Jacobian of the free parameters, sharing one model evaluation."""

    def __init__(
        self,
        layout: ParameterLayout,
        theta: Array,
        omega: Array,
        free: NDArray[np.bool_],
        weights: _Weights,
        data: _Data,
        ctx: ModelContext,
        offsets: Array,
    ) -> None:
        self.layout, self.theta, self.free = layout, theta.copy(), free
        self.omega, self.offsets = omega.copy(), offsets.copy()
        self.whitener, self.data, self.ctx = weights.whitener, data, ctx
        self.target = data.observed - weights.shift
        self._key: bytes | None = None
        self._pred = predict(layout, theta, data.angles, _with_rate(ctx, omega))
        self._rate = _rate_columns(layout, theta, data, ctx) if data.nuisance else None
        self._offset_columns = data.offset_columns()

    def split(self, x: Array) -> None:
        """Set the free parameters, the trial offsets and the Earth rate from ``x``."""
        n_free, q = int(np.sum(self.free)), self.data.offsets
        self.theta[self.free] = x[:n_free]
        self.offsets, self.omega = x[n_free : n_free + q], x[n_free + q :]

    def _update(self, x: Array) -> None:
        key = x.tobytes()
        if key != self._key:
            self.split(x)
            ctx = _with_rate(self.ctx, self.omega)
            self._pred = predict(self.layout, self.theta, self.data.angles, ctx)
            if self._rate is not None:
                self._rate = _rate_columns(self.layout, self.theta, self.data, self.ctx)
            self._key = key

    def residuals(self, x: Array) -> Array:
        """Whitened predicted − observed, flattened by position then channel; prior rows."""
        self._update(x)
        r = self._pred.mean + self.data.offset_means(self.offsets) - self.target
        rows = np.einsum("nij,nj->ni", self.whitener, r).ravel()
        nuisance = self.omega / self.data.earth_sigma if self.data.nuisance else self.omega
        return np.concatenate([rows, self.data.prior.rows(self.theta, self.free), nuisance])

    def jacobian(self, x: Array) -> Array:
        """d(whitened residuals)/d(free parameters, then the nuisance ones)."""
        self._update(x)
        d_theta = np.concatenate([self._pred.d_theta[:, :, self.free], self._offset_columns], 2)
        if self._rate is not None:
            d_theta = np.concatenate([d_theta, self._rate], axis=2)
        jw = np.einsum("nij,njp->nip", self.whitener, d_theta)
        rows = jw.reshape(-1, d_theta.shape[2])
        prior = self.data.prior.jacobian(self.free)
        k, q = self.data.nuisance, self.data.offsets
        prior = np.hstack([prior, np.zeros((prior.shape[0], q + k))])
        nuisance = np.hstack([np.zeros((k, int(np.sum(self.free)) + q)), np.eye(k)])
        if k:
            nuisance[:, -k:] /= self.data.earth_sigma
        return np.vstack([rows, prior, nuisance])

    @property
    def start(self) -> Array:
        """The free parameters' starting values, the trial offsets, then the nuisance ones."""
        return np.concatenate([self.theta[self.free], self.offsets, self.omega])


def _least_squares(problem: _Problem) -> LeastSquaresResult:
    """Levenberg–Marquardt with Jacobian scaling, in numpy (model/levmar.py).

    No scipy import unless the search spends its budget, when MINPACK redoes it.
    """
    return least_squares_lm(
        problem.residuals, problem.start, problem.jacobian,
        xtol=1e-12, ftol=1e-12, gtol=1e-12, minpack_if_unfinished=True,
    )  # fmt: skip


def _rate_of(ctx: ModelContext, data: _Data) -> Array:
    """Return the fitted nuisance Earth rate (empty when none is fitted)."""
    return np.asarray(ctx.w_level, dtype=float) if data.nuisance else np.zeros(0)


def _result(
    layout: ParameterLayout,
    theta: Array,
    free: NDArray[np.bool_],
    data: _Data,
    ctx: ModelContext,
    status: tuple[bool, str],
    lsbs: tuple[float, float],
    offsets: Array,
) -> JointResult:
    pred = predict(layout, theta, data.angles, ctx)
    weights = _weights(layout, theta, data, ctx)
    residuals = data.observed - weights.shift - pred.mean - data.offset_means(offsets)
    whitened = np.einsum("nij,nj->ni", weights.whitener, residuals)
    jac = np.einsum("nij,njp->nip", weights.whitener, pred.d_theta).reshape(-1, layout.size)
    full = _whitened_information(layout, theta, _rate_of(ctx, data), data, ctx)
    info = _marginal(full, layout.size)
    scales = rank_scales(info, layout.effect_scales(ctx.g, 1 / lsbs[0]))
    sep = analyse_information(info, layout.names, scales)
    values = theta.copy()
    undetermined = dict(sep.undetermined)
    for name in layout.names:
        if not free[layout.index(name)] and name not in undetermined:
            undetermined[name] = "held at its starting value to restore the rank"
    values[[layout.index(n) for n in undetermined]] = np.nan
    biases, covariances = _trial_biases(layout, values, offsets, full, data)
    rank = int(np.sum(sep.eigenvalue_ratios >= NOT_IDENTIFIABLE_RATIO))
    k_matrix = layout.unpack(theta, lsbs[1]).K
    rms = float(np.sqrt(np.mean(np.linalg.solve(k_matrix, residuals[:, :3].T) ** 2)))
    return JointResult(
        names=layout.names,
        values=values,
        covariance=sep.covariance,
        residuals=residuals,
        whitened_residuals=whitened,
        jacobian=jac,
        dof=int(residuals.size + np.sum(free[data.prior.index]) - rank - data.offsets),
        chi2=float(
            np.sum(whitened**2)
            + np.sum(data.prior.rows(theta, free) ** 2)
            + np.sum((_rate_of(ctx, data) / max(data.earth_sigma, 1e-300)) ** 2)
        ),
        converged=status[0],
        message=status[1],
        rms_accel_ms2=rms,
        separability=sep,
        spec=layout.spec,
        accel_lsb=lsbs[0],
        gyro_lsb=lsbs[1],
        undetermined=undetermined,
        trials=data.trial_ids,
        trial_bias=biases,
        trial_bias_cov=covariances,
    )


def _trial_biases(
    layout: ParameterLayout, values: Array, offsets: Array, full: Array, data: _Data
) -> tuple[Array | None, Array | None]:
    """Return each trial's biases and their covariance: the shared biases plus its offsets.

    The covariance inverts the information of the determined theta and the offsets (the
    Earth rate marginalised); a bias the fit did not determine is NaN in every trial.
    """
    if data.offsets == 0:
        return None, None
    p, q = layout.size, data.offsets
    m = data.observed.shape[1]
    sensors = ["accel"] + (["gyro"] if m == 6 else [])
    bias_index = [layout.index(f"{s}.bias[{i}]") for s in sensors for i in range(3)]
    known = np.flatnonzero(np.isfinite(values))
    keep = np.concatenate([known, p + np.arange(q)])
    inner = _marginal(full, p + q)[np.ix_(keep, keep)]
    cov = np.linalg.pinv(0.5 * (inner + inner.T), hermitian=True)
    t = data.contrast.shape[1] + 1
    contrast = np.vstack([np.eye(t - 1), -np.ones((1, t - 1))])
    biases, covariances = np.zeros((t, m)), np.zeros((t, m, m))
    shared = values[bias_index]
    d = offsets.reshape(t - 1, m)
    for trial in range(t):
        biases[trial] = shared + contrast[trial] @ d
        rows = np.zeros((m, keep.size))
        for c, k in enumerate(bias_index):
            hit = np.flatnonzero(known == k)
            if hit.size:
                rows[c, hit[0]] = 1.0
            rows[c, known.size + c + m * np.arange(t - 1)] = contrast[trial]
        covariances[trial] = rows @ cov @ rows.T
    undetermined = ~np.isfinite(shared)
    biases[:, undetermined] = np.nan
    return biases, covariances
