"""Settling after each move: an exponential transient at the start of every position.

After a hand placement (or any move) a sensor often settles: mechanical ringing dies out, a
mount creeps, a filter or a thermal gradient relaxes. Inside position p, axis c the samples are
modelled as

    x_pc(t) = m_pc + a_pc · exp(−(t − t_p)/τ) + e,    e white, var σ_pc²          (1)

with ``t_p`` the position's first sample, one time constant ``τ`` shared by every position and
axis of the sensor, and a free amplitude ``a_pc``. For a given τ the amplitudes are linear:
with ``u_p = exp(−(t − t_p)/τ)`` centred within the window (``ũ``) and ``x̃`` the centred
samples, the fit lowers χ² by

    Δχ²(τ) = Σ_p Σ_c (ũ_p · x̃_pc)² / (ũ_p · ũ_p · σ_pc²)                          (2)

which for white noise alone is χ² with ``3·P`` degrees of freedom at any fixed τ. ``σ_pc`` is
taken from the first differences (``var(Δx)/2``), which a slow transient hardly touches. τ is
profiled over a log grid from three sample periods to a third of the shortest window (a slower
"transient" is a trend, which the drift test owns); the transient is called significant when
``G · P(χ²_{3P} > max Δχ²) < alpha`` (Bonferroni over the ``G`` grid points), and τ's 95 %
interval is the profile set ``max Δχ² − Δχ²(τ) ≤ χ²₁(0.95) = 3.84`` (−2 log-likelihood = χ²).

A transient is called settling only when τ's interval ends below the grid's top (otherwise
it cannot be told from a trend), and only when it belongs to the *start* of the positions:
the same fit at the same τ on each window's closing stretch, time reversed (its last sample
first), gives ``Δχ²_close``, and ``G · P(F_{3P,3P} > Δχ²/Δχ²_close) < alpha``. A bias random
walk (or any noise whose increments are stationary) looks the same read backwards, so it
lifts both ends alike: without this control a gyro walk of 5σ was taken for settling on 2 of
20 seeds (τ ≈ 5 s), half of every 30 s window trimmed and the walk not named (issue 21
item 4). White noise leaves the two fits independent χ²_{3P}, hence the F.

A found transient is trimmed per position: with ``τ_u`` the interval's upper end and ``z_p``
the largest amplitude of position p in units of its standard error ``σ √(2/(τ_u f_s))``
(``ũ·ũ ≈ τ f_s/2``), window p loses its first
``τ_u · max(MIN_TRIM_TIME_CONSTANTS, ln(z_p / RESIDUAL_Z))`` seconds (at most half the
window), so that what is left of the transient, even at ``τ = τ_u``, carries less than
``RESIDUAL_Z`` standard errors of evidence and moves neither the mean nor the drift test.

The fit reads each position's opening window only: its first ``OPENING_S`` seconds (the whole
window when shorter), so the τ grid's top is a third of the shortest *opening* window and the
cost is bounded per position whatever the recording's length (issue 23). A transient slower
than ``OPENING_S / 3`` is a trend there too, left to the drift test. Sessions of positions up
to ``OPENING_S`` long are fitted exactly as before.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from canimucal.model.search1d import maximise_bounded, root_bracketed

Array = NDArray[np.float64]

SETTLING_ALPHA = 0.01
"""Significance level of the transient (after the Bonferroni correction over the τ grid)."""

MIN_TRIM_TIME_CONSTANTS = 3.0
"""A found transient is trimmed for at least this many times τ's upper 95 % bound."""

RESIDUAL_Z = 0.1
"""The trim leaves at most this many standard errors of each position's amplitude."""

MAX_TRIM_FRACTION = 0.5
"""No window loses more than this fraction of its length to the trim."""

GRID_POINTS = 40

OPENING_S = 120.0
"""Seconds from each position's first sample that the settling fit reads (module doc)."""
_CHI2_95_1 = 3.841458820694124  # χ²₁ 95 % point, scipy.stats.chi2.ppf(0.95, 1)


@dataclass(frozen=True)
class Settling:
    """The settling fit of one sensor over all positions (module doc, eq. 1–2).

    ``tau_s`` the time constant and ``tau_ci95_s`` its interval (NaN when no window is long
    enough to fit one); ``statistic`` the largest Δχ² on ``df`` dof and ``p_value`` its
    grid-corrected p; ``found`` whether the transient is significant; ``trim_s`` ``(P,)`` the
    seconds cut from each window's start (0 when not found); ``amplitude`` ``(P, 3)`` the fitted
    ``a_pc`` at τ̂ (units of the data). Windows with fewer than 10 finite samples are left
    out of the fit (amplitude and trim 0).
    """

    tau_s: float
    tau_ci95_s: tuple[float, float]
    statistic: float
    df: int
    p_value: float
    found: bool
    trim_s: Array
    amplitude: Array


def _noise_sigma(x: Array) -> Array:
    d = np.diff(x, axis=0)
    return np.asarray(np.sqrt(np.mean(d * d, axis=0) / 2.0))


def fit_settling(
    windows: Sequence[tuple[Array, Array]], *, alpha: float = SETTLING_ALPHA
) -> Settling:
    """Fit eq. (1) to the windows ``(t_s (n,), x (n, 3))`` of one sensor (module doc)."""
    from scipy import special  # lazy (issue 23)

    clean, closing, used = [], [], []
    for i, (t_all, x_all) in enumerate(windows):
        finite = np.flatnonzero(np.all(np.isfinite(x_all), axis=1))
        if finite.size < 10:
            continue
        # only the opening and closing OPENING_S are read: cut them from the window (t is
        # sorted) before the finite rows are taken, so a long window is never copied whole
        first, last = float(t_all[finite[0]]), float(t_all[finite[-1]])
        head = int(np.searchsorted(t_all, first + OPENING_S, side="right"))
        t_open, x_open = _finite_part(t_all, x_all, finite[finite < head])
        clean.append((t_open, x_open))
        tail = int(np.searchsorted(t_all, last - OPENING_S, side="left"))
        t_end, x_end = _finite_part(t_all, x_all, finite[finite >= tail])
        closing.append((t_end[-1] - t_end[::-1], x_end[::-1]))  # reversed: last sample first
        used.append(i)
    n = len(windows)
    nan2 = (float("nan"), float("nan"))
    if not clean:
        return Settling(float("nan"), nan2, 0.0, 0, 1.0, False, np.zeros(n), np.zeros((n, 3)))
    dt = min(float(np.median(np.diff(t))) for t, _ in clean)
    shortest = min(float(t[-1] - t[0]) for t, _ in clean)
    low, high = 3.0 * dt, shortest / 3.0
    df = 3 * len(clean)
    if not high > low:
        return Settling(float("nan"), nan2, 0.0, df, 1.0, False, np.zeros(n), np.zeros((n, 3)))
    grid = np.geomspace(low, high, GRID_POINTS)
    prepared = [_prepare(t, x) for t, x in clean]
    gains = np.array([_gain(prepared, tau)[0] for tau in grid])
    k = int(np.argmax(gains))
    tau, best = _refine(prepared, grid, k, float(gains[k]))
    ci = _interval(prepared, grid, gains, tau, best)
    p = float(min(1.0, GRID_POINTS * special.chdtrc(df, best)))
    closing_gain = _gain([_prepare(t, x) for t, x in closing], tau)[0]
    p_open = float(min(1.0, GRID_POINTS * special.fdtrc(df, df, best / max(closing_gain, 1e-300))))
    found = p < alpha and ci[1] < grid[-1] and p_open < alpha
    amplitude = np.zeros((n, 3))
    amplitude[used] = _gain(prepared, tau)[1]
    trims = np.zeros(n)
    if found:
        for i, (_t, _x, sigma) in zip(used, prepared, strict=True):
            se = sigma * np.sqrt(2.0 / (ci[1] / dt))
            z = float(np.max(np.abs(amplitude[i]) / se))
            trims[i] = ci[1] * max(MIN_TRIM_TIME_CONSTANTS, np.log(max(z, 1.0) / RESIDUAL_Z))
    return Settling(tau, ci, best, df, p, found, trims, amplitude)


def _finite_part(t: Array, x: Array, rows: NDArray[np.intp]) -> tuple[Array, Array]:
    """Return ``t`` and ``x`` at ``rows`` as float64."""
    return np.asarray(t[rows], dtype=float), np.asarray(x[rows], dtype=float)


def _prepare(t: Array, x: Array) -> tuple[Array, Array, Array]:
    """Return times from the window's first sample, the centred samples, each axis's σ."""
    sigma = _noise_sigma(x)
    return t - t[0], x - x.mean(axis=0), np.where(sigma > 0, sigma, np.inf)


def _refine(
    prepared: Sequence[tuple[Array, Array, Array]], grid: Array, k: int, best: float
) -> tuple[float, float]:
    """Maximise Δχ²(τ) between the grid neighbours of its best grid point."""
    lo, hi = float(grid[max(k - 1, 0)]), float(grid[min(k + 1, grid.size - 1)])
    tau = maximise_bounded(lambda t: _gain(prepared, t)[0], lo, hi, xtol=1e-4 * hi)
    gain = _gain(prepared, tau)[0]
    if gain > best:
        return tau, gain
    return float(grid[k]), best


def _interval(
    prepared: Sequence[tuple[Array, Array, Array]],
    grid: Array,
    gains: Array,
    tau: float,
    best: float,
) -> tuple[float, float]:
    """Profile 95 % interval of τ: where Δχ² stays within 3.84 of its maximum (grid-bounded)."""

    def f(t: float) -> float:
        return _gain(prepared, t)[0] - (best - _CHI2_95_1)

    below = grid[grid < tau]
    above = grid[grid > tau]
    low = float(grid[0])
    outside_low = below[gains[: below.size] < best - _CHI2_95_1]
    if outside_low.size:
        low = root_bracketed(f, float(outside_low[-1]), tau, 1e-6 * tau)
    high = float(grid[-1])
    outside_high = above[gains[grid.size - above.size :] < best - _CHI2_95_1]
    if outside_high.size:
        high = root_bracketed(f, tau, float(outside_high[0]), 1e-6 * tau)
    return low, high


def _gain(prepared: Sequence[tuple[Array, Array, Array]], tau: float) -> tuple[float, Array]:
    """Δχ² of eq. (2) at ``tau`` and the fitted amplitudes ``(P, 3)``."""
    total = 0.0
    amps = []
    for t, xc, sigma in prepared:
        # exp(−t/τ) is below 1e-304 past 700 τ: only the rows before count (t is sorted),
        # and with x̃ centred, ũ·x̃ = u·x̃ and ũ·ũ = u·u − (Σu)²/n exactly
        k = int(np.searchsorted(t, 700.0 * tau))
        u = np.exp(-t[:k] / tau)
        total_u = float(u.sum())
        uu = float(u @ u) - total_u * total_u / t.size
        proj = u @ xc[:k]
        total += float(np.sum(proj**2 / (uu * sigma**2)))
        amps.append(proj / uu)
    return total, np.array(amps)


def trim_mask(t: Array, trim_s: float) -> NDArray[np.bool_]:
    """Rows of a window kept after trimming ``trim_s`` (at most half the window) from its start."""
    if trim_s <= 0 or t.size == 0:
        return np.ones(t.size, dtype=bool)
    cut = min(trim_s, MAX_TRIM_FRACTION * float(t[-1] - t[0]))
    return np.asarray(t - t[0] >= cut)
