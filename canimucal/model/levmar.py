"""Levenberg–Marquardt least squares in numpy, for the fits `solve` runs on every call.

The joint fit (:mod:`canimucal.model.joint`) and the |f| = g fit (:mod:`canimucal.model.scalar`)
are small dense problems (tens of parameters, hundreds of residuals) with an analytic
Jacobian. scipy's MINPACK wrapper solves them in milliseconds but costs about a second of
imports (``scipy.optimize`` pulls scipy.linalg, sparse, spatial and fft): most of `solve`'s
time on a small session (docs/performance.md). This module is the same method without them.

Method (Marquardt 1963, as a trust region: Moré 1978, MINPACK's ``lmder``): in scaled
variables ``s = D·δ``, where ``D`` holds the largest norm each Jacobian column has had so far
(scipy's ``x_scale="jac"``), each step minimises ``‖J D⁻¹ s + r‖`` within ``‖s‖ ≤ Δ``: the
Gauss–Newton step when it fits, else the damped step ``(JᵀJ + λI)⁻¹`` on the boundary, both
through the SVD of ``J D⁻¹`` (another λ costs no factorisation). Δ starts at ``100·‖D x₀‖``
and follows the gain ratio ρ (actual over predicted reduction): shrunk below 0.25, grown to
twice the step above 0.75; a step is taken when ρ ≥ 10⁻⁴.

Stopping, with MINPACK's meanings and status codes:
1. ``gtol``: the largest cosine between a Jacobian column and the residual vector ≤ gtol;
2. ``ftol``: actual and predicted relative reductions of ‖r‖² both ≤ ftol (ρ ≤ 2), tested
   on every trial step as MINPACK does (a rejected step at the minimum ends the search);
3. ``xtol``: the trust region ``Δ ≤ xtol·‖D x‖``; 4: both 2 and 3;
0. the evaluation budget ``max_nfev`` (default ``100·(n + 1)``) is spent.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]

MESSAGES = {
    -1: "Improper input parameters status returned from MINPACK.",
    0: "The maximum number of function evaluations is exceeded.",
    1: "`gtol` termination condition is satisfied.",
    2: "`ftol` termination condition is satisfied.",
    3: "`xtol` termination condition is satisfied.",
    4: "Both `ftol` and `xtol` termination conditions are satisfied.",
}
_INITIAL_RADIUS = 100.0
"""The first trust region, times ‖D x₀‖ (MINPACK's ``factor``)."""
_ACCEPT = 1e-4
"""Gain ratio from which a step is taken (MINPACK's)."""
_RANK_EPS = float(np.finfo(float).eps)


@dataclass(frozen=True)
class LeastSquaresResult:
    """The solution ``x``, its residuals and Jacobian there, and how the search ended."""

    x: Array
    fun: Array
    jac: Array
    cost: float
    """½‖r(x)‖²."""
    status: int
    nfev: int
    njev: int

    @property
    def success(self) -> bool:
        """Whether a stopping test (not the evaluation budget) ended the search."""
        return self.status > 0

    @property
    def message(self) -> str:
        """Why the search ended, in words."""
        return MESSAGES[self.status]


def least_squares_lm(
    fun: Callable[[Array], Array],
    x0: Array,
    jac: Callable[[Array], Array],
    *,
    xtol: float = 1e-8,
    ftol: float = 1e-8,
    gtol: float = 1e-8,
    max_nfev: int | None = None,
    minpack_if_unfinished: bool = False,
) -> LeastSquaresResult:
    """Minimise ``½‖fun(x)‖²`` from ``x0`` with the analytic Jacobian ``jac`` (module doc).

    With ``minpack_if_unfinished`` a search that spends its evaluation budget is redone by
    MINPACK from ``x0`` (scipy imported then, tolerances the smallest of the three), so an
    unfinished search never passes for converged: the joint and |f| = g fits ask for it.
    """
    x = np.array(x0, dtype=float)
    if x.ndim != 1 or not np.all(np.isfinite(x)):
        raise ValueError("x0 must be a finite one-dimensional array")
    for name, tol in (("xtol", xtol), ("ftol", ftol), ("gtol", gtol)):
        if not tol >= 0:
            raise ValueError(f"{name} must be ≥ 0, got {tol!r}")
    budget = 100 * (x.size + 1) if max_nfev is None else int(max_nfev)
    r = np.asarray(fun(x), dtype=float)
    j = np.asarray(jac(x), dtype=float)
    nfev, njev = 1, 1
    if not np.all(np.isfinite(r)):
        raise ValueError("the residuals are not finite at the starting point")
    scale = _column_norms(j, None)
    radius = _INITIAL_RADIUS * (float(np.linalg.norm(scale * x)) or 1.0)
    while True:
        cost2 = float(r @ r)
        if _gradient_small(j, r, gtol):
            return _done(x, r, j, 1, nfev, njev)
        u, sv, vt = np.linalg.svd(j / scale, full_matrices=False)
        ur = u.T @ r
        while True:
            s = _step_within(sv, vt, ur, radius)
            x_new = x + s / scale
            r_new = np.asarray(fun(x_new), dtype=float)
            nfev += 1
            new2 = float(r_new @ r_new) if np.all(np.isfinite(r_new)) else np.inf
            # predicted ‖r + J δ‖² from the SVD: components of r outside J's range stay put
            fitted = sv * (vt @ s) + ur
            predicted = float(ur @ ur) - float(fitted @ fitted)
            actual = cost2 - new2
            rho = actual / predicted if predicted > 0 else -1.0
            step = float(np.linalg.norm(s))
            if rho < 0.25:  # Moré (1978) §4: shrink to the step's scale
                radius = 0.5 * min(radius, 10.0 * step) if rho >= 0 else 0.25 * min(radius, step)
            elif rho >= 0.75:
                radius = max(radius, 2.0 * step)
            small_reduction = cost2 == 0 or (
                abs(actual) <= ftol * cost2 and predicted <= ftol * cost2 and rho <= 2.0
            )
            xnorm = float(np.linalg.norm(scale * (x_new if rho >= _ACCEPT else x)))
            small_radius = radius <= xtol * xnorm
            if rho >= _ACCEPT:
                x, r = x_new, r_new
                j = np.asarray(jac(x), dtype=float)
                njev += 1
                scale = _column_norms(j, scale)
            if small_reduction or small_radius:
                status = 4 if small_reduction and small_radius else (2 if small_reduction else 3)
                return _done(x, r, j, status, nfev, njev)
            if nfev >= budget:
                if minpack_if_unfinished:
                    return _minpack(fun, np.array(x0, dtype=float), jac, min(xtol, ftol, gtol))
                return _done(x, r, j, 0, nfev, njev)
            if rho >= _ACCEPT:
                break


def _minpack(
    fun: Callable[[Array], Array], x0: Array, jac: Callable[[Array], Array], tol: float
) -> LeastSquaresResult:
    """MINPACK's ``lmder`` (scipy, imported only here) from ``x0`` with every tolerance ``tol``."""
    from scipy.optimize import least_squares

    ref = least_squares(fun, x0, jac=jac, method="lm", x_scale="jac", xtol=tol, ftol=tol, gtol=tol)
    return LeastSquaresResult(
        x=np.asarray(ref.x, dtype=float),
        fun=np.asarray(ref.fun, dtype=float),
        jac=np.asarray(ref.jac, dtype=float),
        cost=float(ref.cost),
        status=int(ref.status),
        nfev=int(ref.nfev),
        njev=int(ref.njev or 0),
    )


def _step_within(sv: Array, vt: Array, ur: Array, radius: float) -> Array:
    """Return the scaled step ``s`` minimising ``‖J_s s + r‖`` within ``‖s‖ ≤ radius``.

    The Gauss–Newton step (pseudo-inverse: singular values below ``ε·n·σ₁`` are dropped)
    when it fits; otherwise the Levenberg–Marquardt step whose λ puts it on the boundary,
    ``‖s(λ)‖ = radius`` to 1 %, found by bisection on log λ (each try costs a few vector
    operations: the SVD is not redone).
    """
    keep = sv > _RANK_EPS * max(sv.size, 1) * (float(sv[0]) if sv.size else 0.0)
    gn = np.where(keep, ur / np.where(keep, sv, 1.0), 0.0)
    if float(np.linalg.norm(gn)) <= radius:
        return -(vt.T @ gn)

    def length(lam: float) -> float:
        return float(np.linalg.norm(sv / (sv**2 + lam) * ur))

    hi = float(sv[0]) ** 2 if sv.size else 1.0
    while length(hi) > radius:
        hi *= 10.0
    lo = hi
    while length(lo) <= radius and lo > 1e-300:
        lo *= 0.1
    lam = hi
    for _ in range(100):  # bisection on log λ: ‖s(λ)‖ falls as λ grows
        if abs(length(lam) - radius) <= 0.01 * radius or hi <= lo * (1.0 + 1e-12):
            break
        lam = float(np.sqrt(lo * hi)) if lo > 0.0 else 0.5 * hi
        if length(lam) > radius:
            lo = lam
        else:
            hi = lam
    lam = hi if length(lam) > radius else lam  # never a step outside the region
    return -(vt.T @ (sv / (sv**2 + lam) * ur))


def _column_norms(j: Array, previous: Array | None) -> Array:
    """Return the scaling ``D``: each column's largest norm so far (1 for a column never seen)."""
    norms = np.linalg.norm(j, axis=0)
    if previous is not None:
        norms = np.maximum(norms, previous)
    return np.where(norms > 0, norms, 1.0)


def _gradient_small(j: Array, r: Array, gtol: float) -> bool:
    """MINPACK's gradient test: max |cos(Jⱼ, r)| ≤ gtol (true at a zero residual)."""
    rnorm = float(np.linalg.norm(r))
    if rnorm == 0:
        return True
    cols = np.linalg.norm(j, axis=0)
    seen = cols > 0
    if not np.any(seen):
        return True
    cos = np.abs(j[:, seen].T @ r) / (cols[seen] * rnorm)
    return bool(np.max(cos) <= gtol)


def _done(x: Array, r: Array, j: Array, status: int, nfev: int, njev: int) -> LeastSquaresResult:
    return LeastSquaresResult(
        x=x, fun=r, jac=j, cost=0.5 * float(r @ r), status=status, nfev=nfev, njev=njev
    )
