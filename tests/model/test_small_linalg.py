"""model/small_linalg.py against scipy (a dependency, used here as the independent reference)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import qr, solve_triangular
from scipy.optimize import nnls

from canimucal.model.small_linalg import NNLS_MAX_COLUMNS, nnls_small, pivoted_qr, solve_lower


@pytest.mark.parametrize("seed", range(5))
def test_solve_lower_is_the_triangular_solve(seed: int) -> None:
    rng = np.random.default_rng(seed)
    a = rng.standard_normal((12, 12))
    chol = np.linalg.cholesky(a @ a.T + 12 * np.eye(12))
    b = rng.standard_normal((12, 4))
    np.testing.assert_allclose(solve_lower(chol, b), solve_triangular(chol, b, lower=True))


@pytest.mark.parametrize(("rows", "cols", "rank"), [(30, 6, 6), (30, 6, 4), (4, 12, 4), (9, 9, 3)])
def test_pivoted_qr_matches_lapack(rows: int, cols: int, rank: int) -> None:
    """The same pivot order and |R| as LAPACK's geqp3, and A[:, order] = Q R."""
    rng = np.random.default_rng(rows * cols + rank)
    a = rng.standard_normal((rows, rank)) @ rng.standard_normal((rank, cols))
    a *= rng.uniform(0.1, 10.0, cols)  # columns of different sizes: the pivots matter
    r, order = pivoted_qr(a)
    _q, r_ref, order_ref = qr(a, mode="economic", pivoting=True)
    np.testing.assert_array_equal(order[:rank], order_ref[:rank])
    scale = np.abs(r_ref[0, 0])
    # beyond the rank the order is rounding noise: compare R's rows in the original columns
    mine, ref = (
        np.abs(r[:rank][:, np.argsort(order)]),
        np.abs(r_ref[:rank][:, np.argsort(order_ref)]),
    )
    np.testing.assert_allclose(mine, ref, atol=1e-10 * scale)
    assert np.all(np.abs(np.diag(r))[rank:] <= 1e-10 * scale)  # the rank is on the diagonal
    q = np.linalg.lstsq(r.T, a[:, order].T, rcond=None)[0].T  # Q = A P R⁺ on the rank
    np.testing.assert_allclose(q @ r, a[:, order], atol=1e-9 * scale)


@pytest.mark.parametrize("seed", range(20))
def test_nnls_small_is_scipys(seed: int) -> None:
    rng = np.random.default_rng(seed)
    a = rng.standard_normal((25, 3)) * np.array([1.0, 1e-2, 1e2])
    b = a @ rng.normal(0.0, 1.0, 3) + rng.normal(0.0, 0.5, 25)  # some coefficients < 0
    x, res = nnls_small(a, b)
    x_ref, res_ref = nnls(a, b)
    assert np.all(x >= 0)
    assert res == pytest.approx(res_ref, rel=1e-10, abs=1e-12)
    np.testing.assert_allclose(x, x_ref, rtol=1e-7, atol=1e-10)


def test_nnls_small_refuses_many_columns() -> None:
    n = NNLS_MAX_COLUMNS + 1
    with pytest.raises(ValueError, match="at most"):
        nnls_small(np.eye(n), np.ones(n))
