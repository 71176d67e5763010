"""The χ² upper tail P(χ²_ν > x), in plain Python, for the fit checks `solve` prints.

``P(χ²_ν > x) = Q(ν/2, x/2)``, the regularised upper incomplete gamma function. Q is
computed as 1 − P from the power series of P when ``x/2 < ν/2 + 1`` and from Legendre's
continued fraction for Q otherwise (evaluated by the modified Lentz method), the standard
split that keeps both in their fast-converging regions (Press et al., *Numerical Recipes*,
§6.2; Abramowitz & Stegun 6.5.29 and 6.5.31). Relative accuracy against
``scipy.special.chdtrc`` (tests/model/test_chi2_tail.py): 1e-13 for ν ≤ 1000, 1e-10 at
ν = 10⁵ (the logarithm of the prefactor cancels there), in either tail down to 1e-300 — far
inside what the acceptance's ``min_fit_p`` and the lack-of-fit warning need; importing scipy
for it cost `solve` half a second (docs/performance.md).
"""

from __future__ import annotations

import math

_EPS = 1e-16
_TINY = 1e-300
_MAX_TERMS = 10_000


def chi2_sf(dof: float, x: float) -> float:
    """Return P(χ²_dof > x) for ``dof`` > 0 (NaN for a non-finite or non-positive dof)."""
    if not (math.isfinite(dof) and dof > 0) or math.isnan(x):
        return math.nan
    if x <= 0:
        return 1.0
    if math.isinf(x):
        return 0.0
    a, z = 0.5 * dof, 0.5 * x
    if z < a + 1.0:
        return max(0.0, 1.0 - _lower_series(a, z))
    return _upper_fraction(a, z)


def _prefactor(a: float, z: float) -> float:
    """``z^a e^(−z) / Γ(a)``, through logarithms (no overflow)."""
    return math.exp(a * math.log(z) - z - math.lgamma(a))


def _lower_series(a: float, z: float) -> float:
    """P(a, z) = z^a e^(−z)/Γ(a+1) · Σ z^n / ((a+1)…(a+n))."""
    term = total = 1.0 / a
    ap = a
    for _ in range(_MAX_TERMS):
        ap += 1.0
        term *= z / ap
        total += term
        if abs(term) < abs(total) * _EPS:
            break
    return total * _prefactor(a, z)


def _upper_fraction(a: float, z: float) -> float:
    """Q(a, z) = z^a e^(−z)/Γ(a) · 1/(z+1−a− 1·(1−a)/(z+3−a− 2·(2−a)/(z+5−a− …)))."""
    b = z + 1.0 - a
    c = 1.0 / _TINY
    d = 1.0 / b
    h = d
    for i in range(1, _MAX_TERMS):
        an = -i * (i - a)
        b += 2.0
        d = an * d + b
        d = _TINY if abs(d) < _TINY else d
        c = b + an / c
        c = _TINY if abs(c) < _TINY else c
        d = 1.0 / d
        delta = d * c
        h *= delta
        if abs(delta - 1.0) < _EPS:
            break
    return h * _prefactor(a, z)
