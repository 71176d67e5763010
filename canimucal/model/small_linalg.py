"""Three dense-matrix tools numpy lacks, for matrices of tens of columns.

numpy has no triangular solve, no column-pivoted QR and no non-negative least squares;
importing ``scipy.linalg`` and ``scipy.optimize`` for them cost `analyze` and `solve` about
half a second on every call (docs/performance.md), for matrices of a few dozen columns.

- :func:`solve_lower`: ``L⁻¹ b`` for a lower-triangular ``L`` (an LU solve: the same answer
  to rounding at these sizes).
- :func:`pivoted_qr`: Householder QR with column pivoting (Businger & Golub 1965): at each
  step the remaining column of largest norm is moved forward, so ``|R₁₁| ≥ |R₂₂| ≥ …`` and
  the rank is read off the diagonal. The column norms are recomputed exactly at every step
  (LAPACK's ``geqp3`` downdates them), so the order is the one exact arithmetic gives.
- :func:`nnls_small`: ``min ‖A x − b‖`` subject to ``x ≥ 0`` for a handful of columns, by
  trying every support: the optimum's free coordinates are the unconstrained solution on its
  support, so the best feasible subset solution is the optimum (exact; 2ⁿ − 1 solves).
"""

from __future__ import annotations

from itertools import combinations
from typing import Any

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]

NNLS_MAX_COLUMNS = 8
""":func:`nnls_small` tries 2ⁿ − 1 supports: beyond a few columns use an iterative method."""


def solve_lower(chol: NDArray[np.floating[Any]], b: NDArray[np.floating[Any]]) -> Array:
    """Return ``L⁻¹ b`` for the lower-triangular ``chol`` (``b`` a vector or a matrix)."""
    return np.asarray(np.linalg.solve(chol, b), dtype=float)


def pivoted_qr(a: Array) -> tuple[Array, NDArray[np.intp]]:
    """Return ``(R, order)`` with ``A[:, order] = Q R``, ``R`` ``(min(m, n), n)`` upper triangular.

    ``|diag(R)|`` is non-increasing (column pivoting); signs of R's rows are not fixed (a
    Householder choice), so use ``|R_kk|`` or scale-free forms of R.
    """
    work = np.array(a, dtype=float)
    m, n = work.shape
    order = np.arange(n)
    steps = min(m, n)
    for k in range(steps):
        norms = np.einsum("ij,ij->j", work[k:, k:], work[k:, k:])
        j = k + int(np.argmax(norms))
        if j != k:
            work[:, [k, j]] = work[:, [j, k]]
            order[[k, j]] = order[[j, k]]
        x = work[k:, k]
        size = float(np.linalg.norm(x))
        if size == 0.0:
            continue
        alpha = -size if x[0] >= 0 else size
        v = x.copy()
        v[0] -= alpha
        vv = float(v @ v)
        if vv > 0.0:
            work[k:, k:] -= np.outer(v, (2.0 / vv) * (v @ work[k:, k:]))
        work[k + 1 :, k] = 0.0
        work[k, k] = alpha
    return np.triu(work[:steps]), order


def nnls_small(a: Array, b: Array) -> tuple[Array, float]:
    """Return ``(x, ‖A x − b‖)`` minimising the residual over ``x ≥ 0`` (module doc)."""
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    n = a.shape[1]
    if n > NNLS_MAX_COLUMNS:
        raise ValueError(f"nnls_small takes at most {NNLS_MAX_COLUMNS} columns, got {n}")
    best_x, best_r = np.zeros(n), float(np.linalg.norm(b))
    for size in range(1, n + 1):
        for support in combinations(range(n), size):
            cols = list(support)
            coef = np.linalg.lstsq(a[:, cols], b, rcond=None)[0]
            if np.any(coef < 0.0):
                continue
            x = np.zeros(n)
            x[cols] = coef
            r = float(np.linalg.norm(a @ x - b))
            if r < best_r:
                best_x, best_r = x, r
    return best_x, best_r
