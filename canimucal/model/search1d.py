"""One-dimensional searches in plain Python: a bounded maximum and a bracketed root.

The pose-scatter REML (:mod:`canimucal.analysis.noise_model`) needs the maximum of a smooth
profile likelihood ℓ(τ) on a short interval and the two ends of its likelihood interval
(roots of ``ℓ(τ) − ℓ̂ + χ²/2``). Both run in every `solve`; importing ``scipy.optimize`` for
them cost more than the fit (docs/performance.md). Brent's minimiser (golden section with
parabolic steps) and the Illinois variant of regula falsi (Dowell & Jarratt 1971) need
neither derivatives nor scipy, and converge to the tolerances asked (an interval, not a
digit count).
"""

from __future__ import annotations

import math
from collections.abc import Callable

_GOLDEN = (3.0 - math.sqrt(5.0)) / 2.0
"""The golden section's smaller part, 0.381966…"""
_SQRT_EPS = math.sqrt(2.2e-16)
_MAX_STEPS = 500


def maximise_bounded(f: Callable[[float], float], lo: float, hi: float, xtol: float) -> float:
    """Return ``x`` in ``[lo, hi]`` maximising a unimodal ``f`` to within about ``xtol``.

    Brent's method (Brent 1973, ch. 5): a parabola through the three best points when it
    falls inside the bracket and moves less than half the step before last, a golden-section
    step otherwise; stops when the bracket around the best point is within ``2·tol`` of it,
    ``tol = √ε·|x| + xtol/3``. A smooth ``f`` takes about ten evaluations where golden
    section alone takes fifteen at ``xtol`` = 10⁻³ of the interval.
    """
    if not hi >= lo:
        raise ValueError(f"empty interval [{lo}, {hi}]")
    a, b = lo, hi
    x = w = v = a + _GOLDEN * (b - a)
    fx = fw = fv = -f(x)
    d = e = 0.0
    for _ in range(_MAX_STEPS):
        mid = 0.5 * (a + b)
        tol1 = _SQRT_EPS * abs(x) + xtol / 3.0
        tol2 = 2.0 * tol1
        if abs(x - mid) <= tol2 - 0.5 * (b - a):
            break
        golden = True
        if abs(e) > tol1:  # try the parabola through (v, fv), (w, fw), (x, fx)
            r = (x - w) * (fx - fv)
            q = (x - v) * (fx - fw)
            p = (x - v) * q - (x - w) * r
            q = 2.0 * (q - r)
            p = -p if q > 0 else p
            q = abs(q)
            last, e = e, d
            if abs(p) < abs(0.5 * q * last) and q * (a - x) < p < q * (b - x):
                d = p / q
                if (x + d - a) < tol2 or (b - x - d) < tol2:
                    d = tol1 if x < mid else -tol1
                golden = False
        if golden:
            e = (b - x) if x < mid else (a - x)
            d = _GOLDEN * e
        u = x + (d if abs(d) >= tol1 else math.copysign(tol1, d))
        fu = -f(u)
        if fu <= fx:
            a, b = (a, x) if u < x else (x, b)
            v, fv, w, fw, x, fx = w, fw, x, fx, u, fu
        else:
            a, b = (u, b) if u < x else (a, u)
            if fu <= fw or w == x:
                v, fv, w, fw = w, fw, u, fu
            elif fu <= fv or v in (x, w):
                v, fv = u, fu
    return x


def root_bracketed(f: Callable[[float], float], lo: float, hi: float, xtol: float) -> float:
    """Return a root of ``f`` in ``[lo, hi]``, where ``f(lo)`` and ``f(hi)`` differ in sign.

    Illinois regula falsi: a secant step inside the bracket, halving the weight of an end
    kept twice in a row (superlinear, never leaving the bracket), until the bracket is
    shorter than ``xtol`` (its midpoint is returned) or ``f`` is exactly zero. Raises
    ValueError without a sign change.
    """
    a, b = lo, hi
    fa, fb = f(a), f(b)
    if fa == 0.0:
        return a
    if fb == 0.0:
        return b
    if (fa > 0) == (fb > 0):
        raise ValueError(f"f({lo}) and f({hi}) have the same sign: no bracketed root")
    side = 0
    for _ in range(_MAX_STEPS):
        x = (a * fb - b * fa) / (fb - fa)
        if not a < x < b:  # rounding at a tiny bracket: bisect instead
            x = 0.5 * (a + b)
        fx = f(x)
        if fx == 0.0:
            return x
        if (fx > 0) == (fb > 0):
            b, fb = x, fx
            if side == -1:
                fa *= 0.5
            side = -1
        else:
            a, fa = x, fx
            if side == 1:
                fb *= 0.5
            side = 1
        if b - a <= xtol:
            break
    return 0.5 * (a + b)
