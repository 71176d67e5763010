"""The noise model of the position means: within-position scatter plus pose-setting scatter.

The residual vector ``r`` of the per-position means (raw units, position-major) is modelled as

    r = X γ + e,    e ~ N(0, V(τ)),    V(τ) = C + τ² A                        (1)

with ``X`` the design (the base fit's Jacobian and the columns of the terms in the model),
``C`` the covariance of the means from the scatter inside each position (and a random walk
when drift was found), and ``A`` the covariance that a 1 rad angle-setting error on every
angle of every position adds, to first order: ``A_i = J_i J_iᵀ`` with ``J_i`` the derivative
of position i's predicted mean with respect to its three angles (errors in variables).
``τ`` (radians, one value for all positions and angles) is the pose-setting scatter, the one
variance component estimated from the data.

With ``L = chol(V)``, ``X_w = L⁻¹X`` and ``r_w = L⁻¹r``, and ``P`` the projection off the
column space of ``X_w`` (rank ``p``):

- profile (maximum) likelihood ``ℓ(τ) = −½ (log|V| + r_wᵀ P r_w)``, and
- restricted (REML) likelihood ``ℓ_R(τ) = ℓ(τ) − ½ log|X_wᵀ X_w|`` (over the ``p``
  non-zero singular values), which accounts for the ``p`` directions the fit uses up
  (Patterson & Thompson 1971; Harville 1977, eq. 2.4).

``τ`` is estimated by maximising ``ℓ_R`` over ``[0, τ_max]`` (``TAU_MAX_RAD`` for a pose
scatter; a log grid over five decades below it, refined by a bounded search), and its 95 %
interval is the profile-likelihood set
``2 (ℓ_R(τ̂) − ℓ_R(τ)) ≤ χ²₁(0.95) = 3.84``. Nested models are compared by an F test with
both models whitened at the REML ``τ̂`` of the larger one and Satterthwaite's denominator
degrees of freedom (:func:`scatter_f_test`), so that a term is not judged against a scatter
it has itself soaked up.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
from numpy.typing import NDArray

from canimucal.model.search1d import maximise_bounded, root_bracketed
from canimucal.model.small_linalg import solve_lower

Array = NDArray[np.float64]

TAU_MAX_RAD = float(np.deg2rad(10.0))
"""Largest pose-setting scatter considered (10°): beyond it the first-order model fails."""

_DECADES = np.concatenate([[0.0], np.geomspace(1e-5, 1.0, 31)])
"""The search grid as fractions of ``τ_max`` (1e-4° to 10° for a pose scatter)."""
_CHI2_95_1 = 3.841458820694124  # χ²₁ 95 % point, scipy.stats.chi2.ppf(0.95, 1)
_RANK_TOL = 1e-9


@dataclass(frozen=True)
class ScatterModel:
    """``V(τ) = base + τ² unit`` of eq. (1); ``fixed`` the τ given by a header or flag.

    ``source`` is ``"estimated"``, ``"header"``, ``"flag"`` or ``"plan"`` (the poses'
    own tolerances, as in simulations).
    """

    base: Array
    unit: Array
    source: str
    fixed: float | None = None
    blocks: NDArray[np.int64] | None = field(default=None, compare=False)
    """Position of each row when ``base`` and ``unit`` are block-diagonal by position (the
    basis is then found block by block); None: dense."""
    tau_max: float = TAU_MAX_RAD
    """Largest τ considered, in τ's own unit (radians for the pose scatter)."""

    def covariance(self, tau: float) -> Array:
        """``V(τ)`` of eq. (1)."""
        return self.base + tau * tau * self.unit

    @cached_property
    def basis(self) -> tuple[Array, Array, float]:
        """``(W, λ, log|C|)`` with ``W V(τ) Wᵀ = I + τ² diag(λ)`` (see :class:`_Rotated`)."""
        size = self.base.shape[0]
        groups = [np.arange(size)] if self.blocks is None else _groups(self.blocks)
        w, lam, logdet = np.zeros((size, size)), np.zeros(size), 0.0
        for rows in groups:
            cell = np.ix_(rows, rows)
            chol = np.asarray(np.linalg.cholesky(0.5 * (self.base[cell] + self.base[cell].T)))
            inv = solve_lower(chol, np.eye(rows.size))
            half = inv @ self.unit[cell] @ inv.T
            lam_b, q = np.linalg.eigh(0.5 * (half + half.T))
            w[cell] = q.T @ inv
            lam[rows] = lam_b
            logdet += 2.0 * float(np.sum(np.log(np.diag(chol))))
        return w, np.maximum(lam, 0.0), logdet


def _groups(blocks: NDArray[np.int64]) -> list[NDArray[np.intp]]:
    return [np.flatnonzero(blocks == b) for b in np.unique(blocks)]


def block_labels(base: Array, unit: Array, blocks: NDArray[np.int64]) -> NDArray[np.int64] | None:
    """Return ``blocks`` when both matrices vanish outside its diagonal blocks, else None."""
    outside = blocks[:, None] != blocks[None, :]
    if np.any(base[outside] != 0.0) or np.any(unit[outside] != 0.0):
        return None
    return blocks


@dataclass(frozen=True)
class ScatterEstimate:
    """The pose-setting scatter (radians) with its 95 % interval and where it came from."""

    value: float
    ci95: tuple[float, float]
    source: str
    loglik: float
    upper84: float = float("nan")
    """One-sided 84 % upper bound (profile likelihood, ``2 Δℓ = 1``); NaN where not computed."""
    dof: float = float("nan")
    """Satterthwaite's dof of ``τ̂²`` (:func:`scatter_dof`); NaN where not computed."""

    @property
    def value_deg(self) -> float:
        """The scatter in degrees."""
        return float(np.rad2deg(self.value))

    @property
    def ci95_deg(self) -> tuple[float, float]:
        """The 95 % interval in degrees."""
        return float(np.rad2deg(self.ci95[0])), float(np.rad2deg(self.ci95[1]))


@dataclass(frozen=True)
class _Rotated:
    """``r`` and ``X`` in the basis where ``V(τ)`` is diagonal: ``W V(τ) Wᵀ = I + τ² diag(λ)``.

    ``W = Qᵀ L⁻¹`` with ``C = L Lᵀ`` and ``L⁻¹ A L⁻ᵀ = Q diag(λ) Qᵀ`` (a generalised
    eigenproblem). ``X = U Σ Vᵀ`` (thin SVD, the ``k`` non-zero singular values) once: a
    row scaling ``S = diag(d^-½)`` keeps the column space, so ``S X`` spans that of ``S U``,
    and the pseudo-determinant ``|Xᵀ S² X|₊ = |Σ|² |Uᵀ S² U|``. Every τ then costs one
    ``k × k`` Cholesky instead of an SVD or a Cholesky of ``V``.
    """

    residual: Array
    basis_u: Array
    log_sv: float
    lam: Array
    logdet_base: float


def _rotate(model: ScatterModel, residual: Array, design: Array) -> _Rotated:
    w, lam, logdet = model.basis
    x = _unit_columns(w @ design)  # the rank must not depend on the columns' units
    if x.shape[1] == 0:
        return _Rotated(w @ residual, x, 0.0, lam, logdet)
    u, s, _vt = np.linalg.svd(x, full_matrices=False)
    keep = s > _RANK_TOL * max(float(s[0]), 1e-300)
    return _Rotated(w @ residual, u[:, keep], float(np.sum(np.log(s[keep]))), lam, logdet)


def _loglik(rot: _Rotated, tau: float) -> float:
    """``ℓ_R(τ)`` of the module doc (constants dropped; the same for every τ).

    One formula for the grid, its refinement and the interval's ends: where λ spans many
    decades (a channel with next to no noise of its own beside a pose term) the projection
    ``‖S r‖² − bᵀ G⁻¹ b`` loses digits, and a second, batched formula for the grid disagreed
    with this one by more than the interval's cut (the root search then had no bracket).
    """
    d = 1.0 + tau * tau * rot.lam
    scale = 1.0 / np.sqrt(d)
    rw = rot.residual * scale
    logdet = rot.logdet_base + float(np.sum(np.log(d)))
    if rot.basis_u.shape[1] == 0:
        return -0.5 * (logdet + float(rw @ rw))
    su = rot.basis_u * scale[:, None]
    gram = su.T @ su
    b = su.T @ rw
    proj = max(float(rw @ rw) - float(b @ np.linalg.solve(gram, b)), 0.0)
    return -0.5 * (logdet + proj) - rot.log_sv - 0.5 * float(np.linalg.slogdet(gram)[1])


def _maximise(rot: _Rotated, tau_max: float) -> tuple[float, float]:
    """``(τ̂, ℓ_R(τ̂))`` over ``[0, tau_max]``: grid, then a bounded search around its best."""

    def f(t: float) -> float:
        return _loglik(rot, t)

    grid = _DECADES * tau_max
    values = np.array([f(t) for t in grid])
    k = int(np.argmax(values))
    best_t, best_v = float(grid[k]), float(values[k])
    lo, hi = float(grid[max(k - 1, 0)]), float(grid[min(k + 1, grid.size - 1)])
    if hi > lo:
        t = maximise_bounded(f, lo, hi, xtol=1e-3 * hi)
        v = f(t)
        if v > best_v:
            best_t, best_v = t, v
    return best_t, best_v


def reml_scatter(model: ScatterModel, residual: Array, design: Array) -> float:
    """REML estimate of τ alone (no interval); a fixed τ as given."""
    if model.fixed is not None:
        return model.fixed
    return _maximise(_rotate(model, residual, design), model.tau_max)[0]


@dataclass(frozen=True)
class ScatterTest:
    """A nested-model test with the scatter estimated: ``F`` on ``(q, nu)`` degrees of freedom.

    ``tau`` is the REML scatter of the larger model at which both models were whitened.
    """

    statistic: float
    q: int
    nu: float
    p_value: float
    tau: float


def scatter_f_test(
    model: ScatterModel, residual: Array, small: Array, big: Array
) -> ScatterTest | None:
    """Test the columns ``big`` adds to ``small`` with τ estimated: Satterthwaite's F test.

    Both models are whitened at the REML τ̂ of the larger one (θ = τ², rotated basis of
    :class:`_Rotated`: ``V(θ) = diag(1 + θ λ)``), and ``F = (RSS_small − RSS_big)/q`` over
    the ``q`` directions ``E`` the term adds (its Wald statistic over q). Along a direction
    ``e`` the variance of the whitened residual is ``Σ e² (1 + θ λ)/(1 + θ̂ λ)``: it moves with
    θ̂ at the rate ``a = eᵀ D e``, ``D = diag(λ/(1 + θ̂ λ))``, and θ̂ has the REML variance
    ``1/I_R``, ``I_R = ½ tr((I − H) D (I − H) D)`` (the REML information ``½ tr(P A P A)``
    in whitened form, H the hat matrix of the larger model). With ``E`` rotated so that
    ``Eᵀ D E`` is diagonal, each direction is a 1-dof test on ``ν_k = 2 I_R / a_k²`` degrees
    of freedom (Satterthwaite 1946), combined into one ν for F(q, ν) as Fai & Cornelius (1996)
    do (:func:`_combined_dof`). When every variance is scatter (``C = 0``) this is the exact
    F test, ``ν = n − p``; when the term's directions see no scatter, ``ν → ∞`` and ``q F``
    is the χ²(q) of a known noise.

    The likelihood ratio of the two profile likelihoods, τ maximised in each model, is not
    used: with the residual degrees of freedom of an 8-position plan (about 12 on the
    accelerometer) it rejects a null term several times more often than its level, because
    the larger model lowers τ̂ with the columns it adds. Returns None when ``big`` adds no
    direction.
    """
    rot = _rotate(model, residual, big)
    tau = _maximise(rot, model.tau_max)[0]
    scale = 1.0 / np.sqrt(1.0 + tau * tau * rot.lam)
    w = model.basis[0]
    rw = rot.residual * scale
    q_big = _orthonormal(rot.basis_u * scale[:, None])
    q_small = (
        _orthonormal(_unit_columns((w @ small) * scale[:, None])) if small.shape[1] else rw[:, :0]
    )
    extra = q_big - q_small @ (q_small.T @ q_big)
    e = _orthonormal(extra)
    q = e.shape[1]
    if q == 0:
        return None
    numerator = float(np.sum((e.T @ rw) ** 2)) / q
    d = rot.lam * scale * scale
    rates = np.maximum(np.linalg.eigvalsh((e.T * d[None, :]) @ e), 0.0)
    info = _reml_information(d, q_big)
    nu = _combined_dof(2.0 * info / np.maximum(rates * rates, 1e-300))
    from scipy import special

    if not np.isfinite(nu) or nu > 1e7:
        p = float(special.chdtrc(q, numerator * q))
    else:
        p = float(special.fdtrc(q, max(nu, 1e-3), numerator))
    return ScatterTest(numerator, q, float(nu), p, tau)


def _reml_information(d: Array, q_big: Array) -> float:
    """REML information of θ = τ²: ``½ tr((I − H) D (I − H) D)`` in the rotated basis.

    ``d = λ/(1 + θλ)`` (:class:`_Rotated`), ``q_big`` an orthonormal basis of the whitened
    design at θ (H its hat matrix).
    """
    m = d[:, None] * np.eye(d.size) - q_big @ (q_big.T * d[None, :])  # (I − H) D
    return 0.5 * float(np.sum(m * m.T))


def scatter_dof(rot: _Rotated, tau: float) -> float:
    """Satterthwaite's degrees of freedom of ``τ̂²``: ``ν = 2 θ̂² I_R(θ̂)`` (0 at ``τ̂ = 0``).

    ``θ̂ ν/χ²_ν`` is then the approximate law of ``θ`` given ``θ̂`` (Satterthwaite 1946):
    a fit with ν = 4 knows its scatter to ±70 %, one with ν = 40 to ±22 %.
    """
    if tau <= 0.0:
        return 0.0
    scale = 1.0 / np.sqrt(1.0 + tau * tau * rot.lam)
    q_big = _orthonormal(rot.basis_u * scale[:, None]) if rot.basis_u.shape[1] else rot.basis_u
    return 2.0 * tau**4 * _reml_information(rot.lam * scale * scale, q_big)


def _combined_dof(nus: Array) -> float:
    """Denominator dof of a q-dof F from its q 1-dof ones (Fai & Cornelius 1996).

    ``E = Σ ν_k/(ν_k − 2)``, ``ν = 2E/(E − q)``; 2 when any ``ν_k ≤ 2``; ∞ when every
    direction is free of scatter (``E = q``).
    """
    if np.any(nus <= 2.0):
        return 2.0
    finite = nus[np.isfinite(nus) & (nus < 1e12)]
    excess = float(np.sum(2.0 / (finite - 2.0)))  # E − q
    return float(np.inf) if excess <= 0.0 else 2.0 * (nus.size + excess) / excess


def _unit_columns(x: Array) -> Array:
    """Scale each non-zero column of ``x`` to unit length (the span is unchanged)."""
    norms = np.linalg.norm(x, axis=0)
    return np.asarray(x[:, norms > 0] / norms[norms > 0], dtype=float)


def _orthonormal(x: Array) -> Array:
    """Return an orthonormal basis of the column space of ``x`` (rank by :data:`_RANK_TOL`)."""
    if x.shape[1] == 0:
        return x
    u, s, _vt = np.linalg.svd(x, full_matrices=False)
    return np.asarray(u[:, s > _RANK_TOL * max(float(s[0]), 1e-300)], dtype=float)


def estimate_scatter(model: ScatterModel, residual: Array, design: Array) -> ScatterEstimate:
    """REML estimate of τ with its profile-likelihood 95 % interval (module doc).

    ``upper84`` is the one-sided 84 % upper bound (the profile set's 1σ end, ``2 Δℓ_R ≤ 1``),
    the value a fit with few residuals prices its σ at (:mod:`canimucal.analysis.pose_scatter`).
    A fixed τ (header or flag) is returned as given, its interval a single point.
    """
    rot = _rotate(model, residual, design)
    if model.fixed is not None:
        ll = _loglik(rot, model.fixed)
        fixed = model.fixed
        return ScatterEstimate(fixed, (fixed, fixed), model.source, ll, upper84=fixed)
    tau, best = _maximise(rot, model.tau_max)

    def g(t: float, chi2: float = _CHI2_95_1) -> float:
        return _loglik(rot, t) - (best - 0.5 * chi2)

    def above(chi2: float) -> float:
        if g(model.tau_max, chi2) >= 0.0:
            return model.tau_max
        return root_bracketed(lambda t: g(t, chi2), tau, model.tau_max, 1e-9 * model.tau_max)

    low = 0.0 if tau <= 0.0 or g(0.0) >= 0.0 else root_bracketed(g, 0.0, tau, 1e-9 * model.tau_max)
    return ScatterEstimate(
        tau, (low, above(_CHI2_95_1)), model.source, best, upper84=above(1.0),
        dof=scatter_dof(rot, tau),
    )  # fmt: skip
