"""Allan deviation, noise terms and the best averaging time (docs/design.md §2 noise conventions).

Everything here works **in the units of the data** ``x`` (counts for raw outputs, or m/s²,
rad/s after scaling): with ``u`` those units,

- white noise density ``N`` (u·√s = u/√Hz): per-sample σ = N·√f_s, ADEV = N/√τ;
- bias instability ``B`` (u): a flicker floor, ADEV = 0.664·B (0.664 = √(2 ln 2/π)), read off
  conventionally as the minimum of the measured ADEV divided by 0.664;
- random walk ``q`` (u/√s): the bias is a Wiener process, ADEV = q·√(τ/3).

A first-order Gauss–Markov bias of stationary σ_b and correlation time T (the simulator's
``bias_instability`` / ``correlation_time_s``) has the ADEV of :func:`gauss_markov_adev`: a
hump of height ≈ 0.618·σ_b near τ ≈ 1.89·T (0.437·q_c·√T in terms of its driving noise
density q_c = σ_b·√(2/T)). The three-term fit does not describe such a hump: its
``reduced_chi2`` then lies far above 1, which is the signal of a bias drift to look at.

Lost samples (NaN rows) are handled in two steps: gaps of at most ``max_gap_samples`` are
filled by linear interpolation (this slightly lowers the white-noise ADEV at short τ, by at
most the lost fraction: 0.6 % at 1 % single losses), and longer gaps split the record into
segments whose squared second differences are pooled.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from canimucal.errors import ModelError
from canimucal.model.small_linalg import nnls_small

logger = logging.getLogger(__name__)

FLICKER_FACTOR = float(np.sqrt(2.0 * np.log(2.0) / np.pi))
"""ADEV floor of flicker noise per unit of bias instability: 0.6643."""

DEFAULT_MAX_GAP_SAMPLES = 10
"""Longest run of lost samples filled by linear interpolation."""

STRIDE_DIVISOR = 16
"""For cluster size m, cluster starts are taken every max(1, m // 16) samples (see below)."""

MIN_EDF_FOR_FLOOR = 10.0
"""Points with fewer equivalent dof (σ above 22 %) are not used to read off the floor."""

Array = NDArray[np.float64]


@dataclass(frozen=True)
class AllanResult:
    """Overlapping Allan deviation of one record, per axis.

    ``adev`` and ``adev_sigma`` are ``(len(taus_s), n_axes)`` (a 1-D input has one axis).
    ``clusters`` is the number of independent (non-overlapping) clusters of each τ, summed over
    the record's segments; ``edf`` the equivalent degrees of freedom of each point for white
    noise, from which ``adev_sigma = adev / √(2·edf)`` (the ±1σ of the estimate).
    """

    taus_s: Array
    adev: Array
    adev_sigma: Array
    clusters: NDArray[np.int64]
    edf: Array
    sample_rate_hz: float
    n_samples: int
    n_lost: int

    @property
    def avar(self) -> Array:
        """The Allan variance ``adev²``."""
        return self.adev**2


@dataclass(frozen=True)
class NoiseTerms:
    """Fitted noise terms per axis, in the units of the analysed data (see module doc).

    ``white_noise_density`` N (u·√s) and ``random_walk`` q (u/√s) come from the fit, as does
    ``floor_adev`` (u), the ADEV of its constant (flicker) term. ``bias_instability`` B (u)
    is the conventional read-off ``min(measured ADEV) / 0.664`` (over the points with at least
    10 equivalent dof, so one noisy long-τ point does not set it), an upper bound of the
    flicker floor. ``reduced_chi2`` is the fit's χ²/dof against the ADEV confidence (≫ 1: the
    three-term model does not describe the curve, e.g. a Gauss–Markov hump, a filtered sensor).
    """

    white_noise_density: Array
    floor_adev: Array
    random_walk: Array
    bias_instability: Array
    reduced_chi2: Array

    def adev(self, taus_s: ArrayLike) -> Array:
        """Fitted ADEV at ``taus_s``: ``(len(taus_s), n_axes)``.

        ``σ²(τ) = N²/τ + floor² + q² τ/3``.
        """
        tau = np.atleast_1d(np.asarray(taus_s, dtype=float))[:, None]
        avar = (
            self.white_noise_density**2 / tau + self.floor_adev**2 + self.random_walk**2 * tau / 3.0
        )
        return np.sqrt(avar)


def allan_deviation(
    x: ArrayLike,
    sample_rate_hz: float,
    taus_s: ArrayLike | None = None,
    *,
    max_tau_fraction: float = 0.25,
    max_gap_samples: int = DEFAULT_MAX_GAP_SAMPLES,
    per_decade: int = 10,
    full_overlap: bool = False,
) -> AllanResult:
    """Overlapping Allan deviation of rate samples ``x`` (``(n,)`` or ``(n, n_axes)``).

    Default taus: log-spaced, ``per_decade`` per decade, from ``1/f_s`` to
    ``max_tau_fraction · n / f_s`` (rounded to whole samples, duplicates dropped). Rows with a
    NaN are lost samples (module doc). Computed from cumulative sums: for cluster size m,
    ``σ² = Σ (θ[k+2m] − 2θ[k+m] + θ[k])² / (2 m² K)`` with θ the running sum of ``x``. Unless
    ``full_overlap``, for m ≥ 32 the starts k are taken every ``m // 16`` samples: the
    correlation of the squared second differences spans 2m samples and is sampled at 32+
    points, so the estimate keeps the fully overlapping estimator's confidence (checked in
    the tests) while costing O(16·n/m) instead of O(n) per τ.
    """
    fs = _positive(sample_rate_hz, "sample_rate_hz")
    data = np.asarray(x, dtype=float)
    if data.ndim not in (1, 2) or data.shape[0] < 3:
        raise ModelError(f"x must be (n,) or (n, axes) with n >= 3, got shape {data.shape}")
    rows = data.reshape(data.shape[0], -1)
    segments, n_lost = _finite_segments(rows, max_gap_samples)
    longest = max((s.shape[0] for s in segments), default=0)
    if longest < 3:
        raise ModelError("x has no run of 3 finite samples")
    m = _cluster_sizes(taus_s, fs, longest, max_tau_fraction, per_decade)
    sums = np.zeros((m.size, rows.shape[1]))
    counts = np.zeros(m.size)
    clusters = np.zeros(m.size, dtype=np.int64)
    if n_lost:
        logger.debug("allan: %d lost samples, %d segments", n_lost, len(segments))
    divisor = 0 if full_overlap else STRIDE_DIVISOR
    for seg in segments:
        _accumulate(seg, m, sums, counts, clusters, divisor)
    avar = sums / (2.0 * (m[:, None].astype(float) ** 2) * counts[:, None])
    adev = np.sqrt(avar)
    edf = _white_edf(m, segments)
    return AllanResult(
        taus_s=m / fs,
        adev=adev,
        adev_sigma=adev / np.sqrt(2.0 * edf)[:, None],
        clusters=clusters,
        edf=edf,
        sample_rate_hz=fs,
        n_samples=int(rows.shape[0]),
        n_lost=n_lost,
    )


def _positive(value: float, name: str) -> float:
    v = float(value)
    if not np.isfinite(v) or v <= 0.0:
        raise ModelError(f"{name} must be positive and finite, got {value!r}")
    return v


def _finite_segments(rows: Array, max_gap: int) -> tuple[list[Array], int]:
    """Fill short NaN gaps by linear interpolation; split at longer ones."""
    bad = ~np.all(np.isfinite(rows), axis=1)
    n_lost = int(bad.sum())
    if n_lost == 0:
        return [rows - rows.mean(axis=0)], 0
    starts, stops = _runs(bad)
    fill = np.zeros_like(bad)
    good_idx = np.flatnonzero(~bad)
    if good_idx.size == 0:
        return [], n_lost
    for a, b in zip(starts, stops, strict=True):
        if b - a <= max_gap and a > 0 and b < bad.size:
            fill[a:b] = True
    filled = rows.copy()
    idx = np.flatnonzero(fill)
    for axis in range(rows.shape[1]):
        filled[idx, axis] = np.interp(idx, good_idx, rows[good_idx, axis])
    still_bad = bad & ~fill
    seg_starts, seg_stops = _runs(~still_bad)
    mean = filled[~still_bad].mean(axis=0)
    segs = [filled[a:b] - mean for a, b in zip(seg_starts, seg_stops, strict=True)]
    return segs, n_lost


def _runs(mask: NDArray[np.bool_]) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """Half-open [start, stop) of the runs of True in ``mask``."""
    edges = np.diff(np.concatenate(([0], mask.astype(np.int8), [0])))
    return np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)


def _cluster_sizes(
    taus_s: ArrayLike | None, fs: float, longest: int, fraction: float, per_decade: int
) -> NDArray[np.int64]:
    if taus_s is None:
        top = max(1.0, fraction * longest)
        grid = np.logspace(0.0, np.log10(top), int(np.ceil(per_decade * np.log10(top))) + 1)
        return np.unique(np.round(grid).astype(np.int64))
    taus = np.atleast_1d(np.asarray(taus_s, dtype=float))
    m = np.unique(np.round(taus * fs).astype(np.int64))
    if m.size == 0 or m[0] < 1 or 2 * m[-1] >= longest:
        raise ModelError(
            f"taus_s must lie in [{1.0 / fs:g}, {(longest - 1) / (2.0 * fs):g}] s "
            f"for this record, got {taus.min():g}..{taus.max():g}"
        )
    return m


def _accumulate(
    seg: Array,
    m: NDArray[np.int64],
    sums: Array,
    counts: Array,
    clusters: NDArray[np.int64],
    divisor: int,
) -> None:
    """Add one segment's squared second differences of the running sum, per τ."""
    length = seg.shape[0]
    for axis in range(seg.shape[1]):
        theta = np.empty(length + 1)
        theta[0] = 0.0
        np.cumsum(seg[:, axis], out=theta[1:])
        sums[:, axis] += _second_difference_sums(theta, m, divisor)
    for i, mi in enumerate(m):
        if 2 * mi <= length:
            stride = max(1, int(mi) // divisor) if divisor else 1
            counts[i] += (length - 2 * mi) // stride + 1
            clusters[i] += length // mi


def _second_difference_sums(theta: Array, m: NDArray[np.int64], divisor: int) -> Array:
    """``Σ_k (θ[k+2m] − 2θ[k+m] + θ[k])²`` over the (strided) starts k, for each m."""
    length = theta.size - 1
    out = np.zeros(m.size)
    buffer = np.empty(length)  # reused: no 8·n-byte allocation per τ
    for i, mi in enumerate(m):
        if 2 * mi > length:
            continue
        stride = max(1, int(mi) // divisor) if divisor else 1
        n_terms = (length - 2 * mi) // stride + 1
        stop = (n_terms - 1) * stride + 1
        d = buffer[:n_terms]
        middle = theta[mi : mi + stop : stride]
        np.subtract(theta[2 * mi : 2 * mi + stop : stride], middle, out=d)
        d -= middle
        d += theta[0:stop:stride]
        out[i] = float(d @ d)
    return out


def _white_edf(m: NDArray[np.int64], segments: list[Array]) -> Array:
    """Equivalent dof of the overlapping ADEV for white noise, pooled over segments.

    Howe, Allan & Barnes (1981), white FM: ``edf = (3(N−1)/(2m) − 2(N−2)/N) · 4m²/(4m²+5)``
    with N the number of phase points of a segment (its samples + 1). Floor of 1.
    """
    edf = np.zeros(m.size)
    mf = m.astype(float)
    for seg in segments:
        n_phase = seg.shape[0] + 1.0
        ok = 2 * m < n_phase
        term = (3.0 * (n_phase - 1.0) / (2.0 * mf) - 2.0 * (n_phase - 2.0) / n_phase) * (
            4.0 * mf**2 / (4.0 * mf**2 + 5.0)
        )
        edf += np.where(ok, np.maximum(term, 1.0), 0.0)
    return np.maximum(edf, 1.0)


def fit_noise(allan: AllanResult, *, iterations: int = 3) -> NoiseTerms:
    """Fit ``σ²(τ) = N²/τ + floor² + q² τ/3`` to the Allan variance, per axis.

    Non-negative weighted least squares (``small_linalg.nnls_small``) of the AVAR on the basis
    ``{1/τ, 1, τ/3}``, each point weighted by its σ(AVAR) = 2·AVAR/√(2·edf). The weights are
    recomputed from the fitted curve (``iterations`` times) so that points that happen to fall
    low do not pull the fit down.
    """
    tau = allan.taus_s
    basis = np.column_stack((1.0 / tau, np.ones_like(tau), tau / 3.0))
    scale = np.sqrt(2.0 / allan.edf)
    n_axes = allan.adev.shape[1]
    coef = np.zeros((3, n_axes))
    chi2 = np.zeros(n_axes)
    dof = max(tau.size - 3, 1)
    for axis in range(n_axes):
        avar = allan.adev[:, axis] ** 2
        ref = avar.copy()
        for _ in range(max(1, iterations)):
            sigma = np.maximum(ref * scale, np.finfo(float).tiny)
            c, _res = nnls_small(basis / sigma[:, None], avar / sigma)
            ref = basis @ c
        coef[:, axis] = c
        chi2[axis] = float(np.sum(((avar - ref) / (ref * scale)) ** 2)) / dof
    return NoiseTerms(
        white_noise_density=np.sqrt(coef[0]),
        floor_adev=np.sqrt(coef[1]),
        random_walk=np.sqrt(coef[2]),
        bias_instability=_floor_read_off(allan) / FLICKER_FACTOR,
        reduced_chi2=chi2,
    )


def _floor_read_off(allan: AllanResult) -> Array:
    """Minimum ADEV per axis over the points with ≥ 10 equivalent dof (±22 %), else all."""
    steady = allan.edf >= MIN_EDF_FOR_FLOOR
    adev = allan.adev[steady] if np.any(steady) else allan.adev
    return np.asarray(np.min(adev, axis=0))


def best_averaging_time_s(terms: NoiseTerms, *, clip: tuple[float, float] = (15.0, 120.0)) -> float:
    """Averaging time that minimises the fitted ADEV, the largest over axes, clipped.

    Per axis the minimum of ``N²/τ + c + q²τ/3`` is at ``τ* = √3·N/q`` (the flicker floor
    does not move it); an axis with q = 0 (white noise everywhere) has no minimum and gives
    the upper clip. The result is ``clip(max over axes of τ*)`` (docs/design.md §5: "the largest of
    the axes' Allan minima").
    """
    lo, hi = float(clip[0]), float(clip[1])
    if not 0.0 < lo <= hi:
        raise ModelError(f"clip must satisfy 0 < low <= high, got {clip!r}")
    n = terms.white_noise_density
    q = terms.random_walk
    with np.errstate(divide="ignore"):
        tau_star = np.where(q > 0.0, np.sqrt(3.0) * n / np.where(q > 0.0, q, 1.0), np.inf)
    return float(np.clip(np.max(tau_star), lo, hi))


def white_noise_density(x: ArrayLike, sample_rate_hz: float, *, max_m: int = 10) -> Array:
    """Quick white-noise density per axis (units of x · √s) from the ADEV at short τ.

    The median of ``adev(τ)·√τ`` over cluster sizes 1..``max_m`` samples: exact for white
    noise, little affected by drift at these τ.
    """
    fs = _positive(sample_rate_hz, "sample_rate_hz")
    data = np.asarray(x, dtype=float)
    longest = data.shape[0] if data.ndim in (1, 2) else 0
    top = max(1, min(max_m, (longest - 1) // 2 - 1))
    taus = np.arange(1, top + 1) / fs
    res = allan_deviation(data, fs, taus)
    return np.asarray(np.median(res.adev * np.sqrt(res.taus_s)[:, None], axis=0))


def gauss_markov_adev(taus_s: ArrayLike, sigma: float, correlation_time_s: float) -> Array:
    """Analytic ADEV of a first-order Gauss–Markov process of stationary σ and time T.

    ``σ²(τ) = (σ² T/τ) · [2 − (T/τ)(3 − 4 e^(−τ/T) + e^(−2τ/T))]``: ≈ 2σ²τ/(3T) (a random
    walk) for τ ≪ T, ≈ 2σ²T/τ (white) for τ ≫ T, a maximum ≈ 0.618·σ near τ ≈ 1.89·T.
    """
    tau = np.asarray(taus_s, dtype=float)
    t = float(correlation_time_s)
    r = t / tau
    bracket = 2.0 - r * (3.0 - 4.0 * np.exp(-1.0 / r) + np.exp(-2.0 / r))
    return np.sqrt(np.maximum(sigma**2 * r * bracket, 0.0))


def axis_optima_s(terms: NoiseTerms) -> Array:
    """Averaging time minimising each axis's fitted ADEV, ``τ* = √3·N/q`` (inf when q = 0)."""
    n, q = terms.white_noise_density, terms.random_walk
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.asarray(np.where(q > 0.0, np.sqrt(3.0) * n / np.where(q > 0, q, 1.0), np.inf))


@dataclass(frozen=True)
class AveragingChoice:
    """One averaging time for several axes, from each axis's own optimum (:func:`choose_averaging`).

    ``seconds`` the chosen time; ``optima_s`` each sensor's per-axis optimum clipped to the
    allowed range; ``loss`` each sensor's per-axis ADEV at ``seconds`` over its ADEV at its own
    clipped optimum (≥ 1); ``limiting_axis`` the axis that sets the time (``"gyro.z"``).
    """

    seconds: float
    optima_s: dict[str, Array]
    loss: dict[str, Array]
    limiting_axis: str


_CHOICE_GRID = 400

TIE_FACTOR = 1.02
"""Axes whose loss is within 2 % of the worst at the chosen time bind together."""


def choose_averaging(
    terms: dict[str, NoiseTerms], *, clip: tuple[float, float] = (15.0, 120.0)
) -> AveragingChoice:
    """Choose one averaging time for every axis of ``terms`` (sensor name → fitted terms).

    Each axis a has its optimum ``τ*_a`` (:func:`axis_optima_s`, clipped to ``clip``) and, at
    a common time T, the loss ``L_a(T) = σ_a(T)/σ_a(τ*_a)`` (fitted ADEV, ≥ 1). The time is
    the minimax ``T = argmin_T max_a L_a(T)`` over ``clip`` (a log grid of 400 points): no axis
    ends up further from its own best than that. The limiting axis is the one whose loss binds
    at T; of those that bind together (within :data:`TIE_FACTOR`: one asking for less time,
    one for more), the one whose optimum lies below T, i.e. the axis whose drift stops a
    longer average. With every axis white
    (no optimum) the time is the upper clip.
    """
    lo, hi = float(clip[0]), float(clip[1])
    if not 0.0 < lo <= hi:
        raise ModelError(f"clip must satisfy 0 < low <= high, got {clip!r}")
    if not terms:
        raise ModelError("no sensor to choose an averaging time for")
    grid = np.geomspace(lo, hi, _CHOICE_GRID) if hi > lo else np.array([lo])
    optima = {s: np.clip(axis_optima_s(t), lo, hi) for s, t in terms.items()}
    names, curves = [], []
    for sensor, t in terms.items():
        best = np.diag(t.adev(optima[sensor]))
        best = np.where(best > 0, best, np.inf)
        curves.append(t.adev(grid) / best)
        names += [f"{sensor}.{'xyz'[a]}" for a in range(best.size)]
    loss = np.hstack(curves)
    loss = np.where(np.isfinite(loss), loss, 1.0)
    worst = np.max(loss, axis=1)
    k = int(np.argmin(worst))
    seconds = float(grid[k])
    tied = np.flatnonzero(loss[k] >= worst[k] / TIE_FACTOR)
    flat_optima = np.concatenate([optima[s] for s in terms])
    drift_limited = [i for i in tied if flat_optima[i] <= seconds]
    pick = drift_limited[0] if drift_limited else int(tied[0])
    if worst[k] <= 1.0 + 1e-9 and not drift_limited:
        pick = int(np.argmin(flat_optima))
    at = {s: np.diag(t.adev(np.full(3, seconds))) for s, t in terms.items()}
    out_loss = {}
    for s, t in terms.items():
        best = np.diag(t.adev(optima[s]))
        out_loss[s] = np.where(best > 0, at[s] / np.where(best > 0, best, 1.0), 1.0)
    return AveragingChoice(seconds, optima, out_loss, names[pick])


@dataclass(frozen=True)
class NoiseIntervals:
    """95 % intervals ``(n_axes, 2)`` of the fitted terms (units of :class:`NoiseTerms`).

    ``widening`` per axis: the factor by which the ADEV points' confidence band was widened
    so that the fitted curve lies within it (1: the three-term curve fits the band).
    """

    white_noise_density: Array
    bias_instability: Array
    random_walk: Array
    widening: Array = field(default_factory=lambda: np.ones(0))


def _rw_edf(m: NDArray[np.int64], n_phase: float) -> Array:
    """Equivalent dof of the overlapping ADEV for random-walk FM (Howe, Allan & Barnes 1981).

    ``edf = ((N−2)/m) · ((N−1)² − 3m(N−1) + 4m²) / (N−3)²``, N phase points.
    """
    mf = m.astype(float)
    n = float(n_phase)
    top = (n - 2.0) / mf * ((n - 1.0) ** 2 - 3.0 * mf * (n - 1.0) + 4.0 * mf**2)
    return np.asarray(top / (n - 3.0) ** 2)


def noise_intervals(allan: AllanResult, terms: NoiseTerms) -> NoiseIntervals:
    """95 % intervals of the white density N, the random walk q and the bias instability B.

    Each of the K Allan variance points has the χ² interval ``σ̂²·edf/χ²_edf(1 − 0.025/K) …
    σ̂²·edf/χ²_edf(0.025/K)`` (Bonferroni over the points: a simultaneous band), with edf the
    smaller of the white-noise and the random-walk value (Howe, Allan & Barnes 1981), so a
    point where the walk dominates is not trusted beyond what a walk allows. The interval of
    N² (of q²) is the smallest and largest coefficient of any curve ``N²/τ + B_f² + q²τ/3``
    with non-negative terms that stays inside the band at every point (two small linear
    programs). When the fitted curve leaves the band (coloured or filtered noise; the fit's
    ``reduced_chi2`` says so), the band is first widened about each point by the smallest
    factor that takes the fitted curve in (:attr:`NoiseIntervals.widening`), so every
    interval holds its estimate and has its lower end below its upper. B, read off as the
    smallest ADEV over 0.664, takes the interval of that point.
    """
    tau = allan.taus_s
    m = np.round(tau * allan.sample_rate_hz).astype(np.int64)
    n_phase = allan.n_samples + 1.0
    edf = np.maximum(np.minimum(allan.edf, _rw_edf(m, n_phase)), 1.0)[:, None]
    avar = allan.avar
    tail = 0.025 / tau.size  # Bonferroni: the bounds hold at every τ point at once
    from scipy.special import chdtri  # lazy (issue 23); chdtri(v, p): x with P(χ²_v > x) = p

    high = avar * edf / chdtri(edf, 1.0 - tail)
    low = avar * edf / chdtri(edf, tail)
    basis = np.column_stack((1.0 / tau, np.ones_like(tau), tau / 3.0))
    coef = np.vstack([terms.white_noise_density**2, terms.floor_adev**2, terms.random_walk**2])
    n_axes = avar.shape[1]
    bands = np.zeros((2, n_axes, 2))
    widening = np.ones(n_axes)
    for axis in range(n_axes):
        fitted = basis @ coef[:, axis]
        widening[axis] = _widening(fitted, low[:, axis], high[:, axis])
        lo, hi = low[:, axis] / widening[axis], high[:, axis] * widening[axis]
        for i, k in enumerate((0, 2)):
            down, up = _coefficient_range(basis, lo, hi, k)
            value = coef[k, axis]
            bands[i, axis] = np.sqrt([min(down, value), max(up, value)])
    steady = allan.edf >= MIN_EDF_FOR_FLOOR
    idx = np.flatnonzero(steady) if np.any(steady) else np.arange(tau.size)
    j = idx[np.argmin(allan.adev[idx], axis=0)]
    axes = np.arange(n_axes)
    b = np.column_stack((np.sqrt(low[j, axes]), np.sqrt(high[j, axes]))) / FLICKER_FACTOR
    return NoiseIntervals(bands[0], b, bands[1], widening)


def _widening(fitted: Array, low: Array, high: Array) -> float:
    """Smallest factor ``w ≥ 1`` with ``low/w ≤ fitted ≤ high·w`` at every point."""
    with np.errstate(divide="ignore", invalid="ignore"):
        ratios = np.concatenate([fitted / high, low / fitted])
    ratios = ratios[np.isfinite(ratios)]
    worst = float(np.max(ratios)) if ratios.size else 0.0
    return 1.0 if worst <= 1.0 else worst * (1.0 + 1e-9)  # a hair more: the LP stays feasible


def _coefficient_range(basis: Array, low: Array, high: Array, k: int) -> tuple[float, float]:
    """Least and largest coefficient ``k`` of ``c ≥ 0`` with ``low ≤ basis·c ≤ high``.

    Rows are scaled by ``high`` and each coefficient by its largest possible value
    (``min high/basis``), so the linear programs are well conditioned. An infeasible or
    failed program gives ``(inf, -inf)``: the caller's estimate is then the interval.
    """
    caps = np.min(high[:, None] / basis, axis=0)
    caps = np.where(np.isfinite(caps) & (caps > 0), caps, 1.0)
    a = basis * caps / high[:, None]
    a_ub = np.vstack([a, -a])
    b_ub = np.concatenate([np.ones_like(high), -low / high])
    from scipy.optimize import linprog  # lazy (issue 23)

    out = []
    for sign in (1.0, -1.0):
        cost = np.zeros(basis.shape[1])
        cost[k] = sign
        res = linprog(cost, A_ub=a_ub, b_ub=b_ub, bounds=(0.0, None), method="highs")
        out.append(float(res.x[k] * caps[k]) if res.status == 0 else sign * np.inf)
    return out[0], out[1]
