"""Levenberg–Marquardt least squares in numpy, for the fits `solve` runs on every call.

The joint fit (:mod:`canimucal.model.joint`) and the |f| = g fit (:mod:`canimucal.model.scalar`)
are small dense problems (tens of parameters, hundreds of residuals) with an analytic
Jacobian. scipy's MINPACK wrapper solves them in milliseconds but costs about a second of
imports (``scipy.optimize`` pulls scipy.linalg, sparse, spatial and fft): most of `solve`'s
time on a small session (docs/performance.md). This module is the same method without them.

Method (Marquardt 1963; the scaling and stopping tests of Moré 1978, as MINPACK's ``lmder``):
in scaled variables ``s = D·δ``, where ``D`` holds the largest norm each Jacobian column has
had so far (scipy's ``x_scale="jac"``), each step minimises ``‖J D⁻¹ s + r‖² + λ‖s‖²``,
solved through the SVD of ``J D⁻¹`` so that trying another λ costs no factorisation. λ
follows the gain ratio ρ (actual over predicted reduction; Nielsen 1999): accepted steps
shrink it by ``max(1/3, 1 − (2ρ − 1)³)``, rejected ones grow it geometrically.

Stopping, with MINPACK's meanings and status codes:
1. ``gtol``: the largest cosine between a Jacobian column and the residual vector ≤ gtol;
2. ``ftol``: actual and predicted relative reductions of ‖r‖² both ≤ ftol (ρ ≤ 2);
3. ``xtol``: the scaled step ``‖s‖ ≤ xtol·(‖D x‖ + xtol)``; 4: both 2 and 3;
0. the evaluation budget ``max_nfev`` (default ``100·(n + 1)``) is spent.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]

MESSAGES = {
    0: "The maximum number of function evaluations is exceeded.",
    1: "`gtol` termination condition is satisfied.",
    2: "`ftol` termination condition is satisfied.",
    3: "`xtol` termination condition is satisfied.",
    4: "Both `ftol` and `xtol` termination conditions are satisfied.",
}
_FIRST_DAMPING = 1e-3
"""λ of the first step, relative to the scaled Jacobian's largest squared singular value."""


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
) -> LeastSquaresResult:
    """Minimise ``½‖fun(x)‖²`` from ``x0`` with the analytic Jacobian ``jac`` (module doc)."""
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
    damping = -1.0
    status = 0
    while True:
        cost2 = float(r @ r)
        if _gradient_small(j, r, gtol):
            status = 1
            break
        u, sv, vt = np.linalg.svd(j / scale, full_matrices=False)
        ur = u.T @ r
        if damping < 0:
            damping = _FIRST_DAMPING * float(sv[0] ** 2 if sv.size else 1.0)
        growth = 2.0
        while True:
            s = -(vt.T @ (sv / (sv**2 + damping) * ur))
            step = s / scale
            x_new = x + step
            r_new = np.asarray(fun(x_new), dtype=float)
            nfev += 1
            new2 = float(r_new @ r_new) if np.all(np.isfinite(r_new)) else np.inf
            # predicted ‖r + J δ‖² from the SVD: components of r outside J's range stay put
            fitted = sv * (vt @ s) + ur
            predicted = cost2 - (cost2 - float(ur @ ur) + float(fitted @ fitted))
            actual = cost2 - new2
            rho = actual / predicted if predicted > 0 else -1.0
            small_step = float(np.linalg.norm(s)) <= xtol * (
                float(np.linalg.norm(scale * x)) + xtol
            )
            if rho > 0:
                break
            if small_step:
                return _done(x, r, j, 3, nfev, njev)
            if nfev >= budget:
                return _done(x, r, j, 0, nfev, njev)
            damping *= growth
            growth *= 2.0
        small_reduction = (
            cost2 > 0 and abs(actual) <= ftol * cost2 and predicted <= ftol * cost2 and rho <= 2
        )
        damping *= max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3)
        x, r = x_new, r_new
        j = np.asarray(jac(x), dtype=float)
        njev += 1
        scale = _column_norms(j, scale)
        if small_reduction or small_step:
            status = (2 if small_reduction else 0) + (3 if small_step else 0)
            status = 4 if status == 5 else status
            break
        if nfev >= budget:
            status = 0
            break
    return _done(x, r, j, status, nfev, njev)


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
