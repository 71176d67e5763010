"""Drift inside the static positions, recognised before any other term is tested.

A bias that wanders (random walk or instability, docs/design.md §5 ``bias_drift``) makes each
position's samples trend. Within position p and axis c the least-squares slope ``s_pc`` has,
for white noise alone, the standard error ``σ_pc = s_e / √Σ(t − t̄)²`` (``s_e`` the
residual scatter), so ``z_pc = s_pc/σ_pc`` is N(0, 1). A temperature that changes during
the positions explains slopes ``c_c·dT/dt`` with one coefficient per axis; that part is
removed first (``temperature_bias`` is tested across positions, not here). What remains,
``Σ z²``, is χ² with ``3·n_positions − (3 if temperature)`` degrees of freedom.

A Wiener bias of intensity q (counts/√s) gives a slope variance ``c_p q²``, ``c_p = 6/(5 T_p)``,
over a window of ``T_p`` seconds (the OLS slope of Brownian motion), from which q is
estimated. Each window's excess ``e_p = s_p² − σ_p²`` has mean ``c_p q²`` and, the slope
being normal, variance ``2 (σ_p² + c_p q²)²``; the weighted least-squares estimate

    q̂² = Σ_p w_p c_p e_p / Σ_p w_p c_p²,    w_p = 1 / (2 (σ_p² + c_p q̂²)²)          (1)

(weights first at q = 0, then at that estimate) is unbiased at any window lengths,
and its σ is ``σ(q̂²) = 1/√(Σ_p w_p c_p²)``; ``σ(q̂) = σ(q̂²)/(2 q̂)`` (the delta method; at
``q̂ = 0``, the one-sided bound ``√σ(q̂²)``). With windows of one length this is the plain
average ``(5T/6)·mean(e_p)``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from canimucal.analysis.data import Samples
from canimucal.model.chi2_tail import chi2_sf
from canimucal.model.noise import DEFAULT_MAX_GAP_SAMPLES, allan_deviation

Array = NDArray[np.float64]


@dataclass(frozen=True)
class DriftTest:
    """Within-position trend test of one sensor (three axes).

    ``z`` ``(n_positions, 3)`` slope z-scores after the temperature part; ``statistic`` their
    χ², ``df`` its degrees of freedom, ``p_value``; ``random_walk`` the q estimate per axis
    (counts/√s, 0 where the slopes show none; module doc eq. 1) and ``random_walk_sigma`` its
    σ; ``seconds`` mean window length.
    """

    z: Array
    statistic: float
    df: int
    p_value: float
    random_walk: Array
    seconds: float
    random_walk_sigma: Array = field(default_factory=lambda: np.full(3, np.nan))


def slope(t: Array, x: Array) -> tuple[Array, Array]:
    """OLS slope of each column of ``x`` against ``t`` and its white-noise standard error.

    From centred sums (no residual array): ``s = Sxy/Sxx``, ``s_e² = (Syy − s·Sxy)/(n − 2)``.
    """
    tc = t - t.mean()
    xc = x - x.mean(axis=0)
    sxx = float(tc @ tc)
    sxy = tc @ xc
    syy = np.einsum("ij,ij->j", xc, xc)
    slope = sxy / sxx
    dof = max(t.size - 2, 1)
    scatter = np.sqrt(np.clip(syy - slope * sxy, 0.0, None) / dof)
    return slope, scatter / np.sqrt(sxx)


def drift_test(
    windows: Sequence[tuple[Array, Samples]], temperature_rates: Array | None = None
) -> DriftTest:
    """Test the samples ``(t_s (n,), x (n, 3))`` of each position for trends.

    ``x`` may be float32 (a session's window); each is converted to float64 before summing.

    ``temperature_rates`` ``(n_positions,)`` °C/s, or None when the temperature is unknown
    or constant.
    """
    slopes, sigmas, lengths = [], [], []
    for t, samples in windows:
        x = np.asarray(samples, dtype=np.float64)  # before any sum (float32 windows)
        keep = np.all(np.isfinite(x), axis=1)
        s, e = slope(t[keep], x[keep])
        slopes.append(s)
        sigmas.append(np.where(e > 0, e, np.inf))
        lengths.append(float(t[keep][-1] - t[keep][0]))
    z = np.array(slopes) / np.array(sigmas)
    removed = 0
    if temperature_rates is not None and np.any(temperature_rates != 0):
        x_rate = np.asarray(temperature_rates, dtype=float)[:, None] / np.array(sigmas)
        coef = np.sum(x_rate * z, axis=0) / np.sum(x_rate**2, axis=0)
        z = z - x_rate * coef
        removed = 3
    df = max(z.size - removed, 1)
    statistic = float(np.sum(z**2))
    seconds = float(np.mean(lengths))
    walk, walk_sigma = walk_estimate(np.array(slopes), np.array(sigmas), np.array(lengths))
    p = chi2_sf(df, statistic)  # numpy only: solve's motion check runs this (issue 23)
    return DriftTest(z, statistic, df, p, walk, seconds, walk_sigma)


def walk_estimate(slopes: Array, sigmas: Array, seconds: Array) -> tuple[Array, Array]:
    """q̂ and σ(q̂) per axis from the slopes ``(P, 3)``, their white σ and the windows' lengths.

    Module doc eq. (1). Slopes with an infinite σ (a constant axis) carry no weight.
    """
    c = (6.0 / (5.0 * np.maximum(seconds, 1e-300)))[:, None] * np.ones_like(slopes)
    white = np.where(np.isfinite(sigmas), sigmas**2, np.inf)
    excess = np.where(np.isfinite(white), slopes**2 - white, 0.0)
    q2 = np.zeros(slopes.shape[1])
    for _ in range(2):  # weights at q = 0 (white slopes alone), then at that estimate
        w = 1.0 / (2.0 * (white + c * np.clip(q2, 0.0, None)[None, :]) ** 2)
        info = np.sum(w * c * c, axis=0)
        q2 = np.sum(w * c * excess, axis=0) / np.where(info > 0, info, np.inf)
    sigma_q2 = 1.0 / np.sqrt(np.where(info > 0, info, np.nan))
    q = np.sqrt(np.clip(q2, 0.0, None))
    sigma_q = np.where(q > 0, sigma_q2 / (2.0 * np.where(q > 0, q, 1.0)), np.sqrt(sigma_q2))
    return q, sigma_q


def random_walk_covariance(mid_times_s: Array, seconds: Array, q: float) -> Array:
    """Covariance of the position means that a Wiener bias of intensity q adds (counts²).

    Means of windows centred at ``mid_times_s``: ``q² min(t_p, t_p')`` between positions,
    plus ``q² T/3`` for the part inside each window of ``T`` seconds (diagonal).
    """
    t = np.asarray(mid_times_s, dtype=float) - float(np.min(mid_times_s))
    cov = q**2 * np.minimum.outer(t, t)
    return cov + np.diag(q**2 * np.asarray(seconds, dtype=float) / 3.0)


WALK_FACTOR = 2.0
"""A slope-based random walk is named only up to this factor over the Allan bound."""


def allan_walk_upper(windows: Sequence[tuple[Array, Samples]]) -> Array:
    """95 % upper bound (per axis, units/√s) of a random walk from the windows' Allan deviation.

    Every term of ``σ²(τ) = N²/τ + B² + q²τ/3`` is non-negative, so ``q² ≤ 3σ²(τ)/τ`` at every
    τ; with the one-sided 95 % bound of the Allan variance, ``σ̂²·edf/χ²_edf(0.05)`` (edf the
    equivalent dof of the point), ``q_up = min_τ √(3 σ²_up(τ)/τ)``. The windows are pooled as
    segments (separated by gaps longer than the interpolated ones). A walk that the slope test
    reports far above this bound is a trend the Allan deviation does not see as a random walk
    (motion, settling of another shape), not a wandering bias.
    """
    parts, dts = [], []
    gap = np.full((DEFAULT_MAX_GAP_SAMPLES + 1, 3), np.nan)
    for t, samples in windows:
        x = np.asarray(samples, dtype=np.float64)  # before any sum (float32 windows)
        keep = np.all(np.isfinite(x), axis=1)
        if keep.sum() < 8:
            continue
        parts += [x[keep] - x[keep].mean(axis=0), gap]
        dts.append(float(np.median(np.diff(t[keep]))))
    if not parts:
        return np.full(3, np.inf)
    res = allan_deviation(np.concatenate(parts[:-1]), 1.0 / float(np.median(dts)))
    edf = res.edf[:, None]
    from scipy import special  # lazy (issue 23)

    upper = res.avar * edf / special.chdtri(edf, 0.95)
    return np.asarray(np.sqrt(np.min(3.0 * upper / res.taus_s[:, None], axis=0)))


def walk_consistent(drift: DriftTest, bound: Array, *, alpha: float = 0.01) -> bool:
    """Whether the axes that carry the trend have a walk within the Allan bound.

    The axes whose own slope χ² (``Σ_p z²`` on P dof) is significant at ``alpha/3`` carry the
    trend (the largest one when none does alone); each must have ``q ≤ WALK_FACTOR · bound``.
    The other axes' q, noise of the slope-variance excess, are not judged.
    """
    per_axis = np.sum(drift.z**2, axis=0)
    from scipy import special  # lazy (issue 23)

    p = special.chdtrc(drift.z.shape[0], per_axis)
    axes = np.flatnonzero(p < alpha / drift.z.shape[1])
    if axes.size == 0:
        axes = np.array([int(np.argmax(per_axis))])
    return bool(np.all(drift.random_walk[axes] <= WALK_FACTOR * np.asarray(bound)[axes]))
