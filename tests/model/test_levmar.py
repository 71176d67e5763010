"""model/levmar.py against scipy's MINPACK Levenberg–Marquardt on the same problems.

scipy is a dependency (analyze uses it), so it is the independent reference here: the same
minimum to well inside the problem's own conditioning, and MINPACK's stopping meanings.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest
from scipy.optimize import least_squares

from canimucal.model.levmar import least_squares_lm

Array = np.ndarray
Problem = tuple[Callable[[Array], Array], Callable[[Array], Array], Array]


def _rosenbrock() -> Problem:
    def f(x: Array) -> Array:
        return np.array([10.0 * (x[1] - x[0] ** 2), 1.0 - x[0]])

    def j(x: Array) -> Array:
        return np.array([[-20.0 * x[0], 10.0], [-1.0, 0.0]])

    return f, j, np.array([-1.2, 1.0])


def _decay(seed: int) -> Problem:
    """y = a·exp(−t/τ) + c with noise: a residual that does not vanish at the minimum."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, 10.0, 60)
    y = 3.0 * np.exp(-t / 2.5) + 0.4 + 0.05 * rng.standard_normal(t.size)

    def f(x: Array) -> Array:
        return x[0] * np.exp(-t / x[1]) + x[2] - y

    def j(x: Array) -> Array:
        e = np.exp(-t / x[1])
        return np.column_stack([e, x[0] * e * t / x[1] ** 2, np.ones_like(t)])

    return f, j, np.array([1.0, 1.0, 0.0])


def _badly_scaled(seed: int) -> Problem:
    """Columns 10⁶ apart in size (counts beside counts per m/s²), as the joint fit's are."""
    rng = np.random.default_rng(seed)
    a = rng.standard_normal((40, 4)) * np.array([1e-3, 1.0, 1e3, 1.0])
    truth = np.array([2e3, -1.5, 4e-3, 0.7])
    y = a @ truth + 0.01 * rng.standard_normal(40)

    def f(x: Array) -> Array:
        return a @ x + 0.05 * np.sin(x[1]) - y

    def j(x: Array) -> Array:
        out = a.copy()
        out[:, 1] += 0.05 * np.cos(x[1])
        return out

    return f, j, np.zeros(4)


@pytest.mark.parametrize(
    "problem", [_rosenbrock(), _decay(0), _decay(1), _badly_scaled(0), _badly_scaled(1)]
)
def test_the_minimum_is_minpacks(problem: Problem) -> None:
    f, j, x0 = problem
    ours = least_squares_lm(f, x0, j, xtol=1e-12, ftol=1e-12, gtol=1e-12)
    ref = least_squares(f, x0, jac=j, method="lm", x_scale="jac", xtol=1e-12, ftol=1e-12)
    assert ours.success, ours.message
    # agreement measured in the problem's own σ: the Gauss–Newton covariance at the minimum
    cov = np.linalg.pinv(ref.jac.T @ ref.jac)
    sigma = np.sqrt(np.diag(cov)) * max(np.sqrt(2 * ref.cost / max(ref.fun.size - x0.size, 1)), 1)
    assert np.all(np.abs(ours.x - ref.x) <= 1e-6 * sigma + 1e-12 * np.abs(ref.x))
    assert ours.cost <= ref.cost * (1 + 1e-12) + 1e-30


def test_a_zero_residual_start_stops_on_the_gradient_test() -> None:
    f, j, _ = _rosenbrock()
    result = least_squares_lm(f, np.array([1.0, 1.0]), j)
    assert result.status == 1 and result.nfev == 1
    np.testing.assert_array_equal(result.x, [1.0, 1.0])


def test_the_budget_ends_the_search_unconverged() -> None:
    f, j, x0 = _rosenbrock()
    result = least_squares_lm(f, x0, j, max_nfev=3)
    assert result.status == 0 and not result.success
    assert "maximum number" in result.message
    assert result.nfev <= 4


def test_bad_starting_points_are_refused() -> None:
    f, j, _ = _rosenbrock()
    with pytest.raises(ValueError, match="finite"):
        least_squares_lm(f, np.array([np.nan, 1.0]), j)
    with pytest.raises(ValueError, match="xtol"):
        least_squares_lm(f, np.array([0.0, 1.0]), j, xtol=-1.0)


def test_a_search_that_spends_its_budget_is_redone_by_minpack() -> None:
    """The joint and |f| = g fits' search: an unfinished numpy search goes to MINPACK."""
    f, j, x0 = _decay(2)
    alone = least_squares_lm(f, x0, j, max_nfev=3, xtol=1e-12, ftol=1e-12, gtol=1e-12)
    assert not alone.success  # the budget ends it unconverged ...
    fit = least_squares_lm(
        f, x0, j, max_nfev=3, xtol=1e-12, ftol=1e-12, gtol=1e-12, minpack_if_unfinished=True
    )
    ref = least_squares(f, x0, jac=j, method="lm", x_scale="jac", xtol=1e-12, ftol=1e-12)
    assert fit.success  # ... and MINPACK, from the same start, finishes it
    np.testing.assert_allclose(fit.x, ref.x)
    assert fit.nfev == ref.nfev
