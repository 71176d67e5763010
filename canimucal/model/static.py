"""Static intervals in a recording, and motion tests for blocks of samples.

The interval detector follows the idea of Tedaldi et al. (2014, the imu_tk static detector):
a moving variance of the accelerometer, compared with a threshold tied to the sensor noise.
Written here from scratch, vectorised with cumulative sums.

**Statistic.** For each window of ``w = round(window_s · f_s)`` consecutive samples, the total
moving standard deviation ``s = √(var_x + var_y + var_z)`` (counts, sample variances with
``w − 1`` dof). Lost samples (NaN rows) are left out of their windows; a window with fewer
than half its samples is never quiet.

**Default threshold.** ``threshold = 3 × (10th percentile of s over the record)``: the 10th
percentile is a static window whenever at least 10 % of the record is static, and a static
window's ``s`` scatters by only ≈ 1/√(2(w − 1)) (7 % at w = 100) around the noise level, so
three times it is never reached by chance at rest, while a turn by hand exceeds it many times
over (on the Xsens recording: static windows ≈ 5.5 counts, motion 80–1200).

**Intervals.** A sample is static when the window centred on it is quiet; runs of static
samples are returned as half-open ``[start, stop)``, and runs shorter than ``min_duration_s``
are dropped, so a pose is found when it lasts ``min_duration_s + window_s``. (Taking every
sample of every quiet window instead would reach half a window further into the slow start
and end of each motion: on synthetic data that biased a pose's mean by 1.5 counts, ten times
the noise of the mean.)
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from canimucal.errors import ModelError

logger = logging.getLogger(__name__)

DEFAULT_THRESHOLD_FACTOR = 3.0
"""The default threshold is this factor times the reference (static) moving std."""

REFERENCE_PERCENTILE = 10.0
"""Percentile of the moving std taken as the static noise level."""

Array = NDArray[np.float64]


@dataclass(frozen=True)
class StaticInterval:
    """A static run of samples, ``[start, stop)`` sample indices."""

    start: int
    stop: int

    @property
    def n(self) -> int:
        """Number of samples in the interval."""
        return self.stop - self.start

    def seconds(self, sample_rate_hz: float) -> float:
        """Duration of the interval at ``sample_rate_hz``."""
        return self.n / float(sample_rate_hz)


def moving_std(x: ArrayLike, window: int) -> Array:
    """Total moving std ``√(Σ_axes var)`` of each window of ``window`` samples.

    ``x`` is ``(n,)`` or ``(n, axes)``; returns ``n − window + 1`` values, entry ``j`` covering
    samples ``[j, j + window)``. Rows with a NaN (lost samples) are left out of their windows;
    a window with fewer than half its samples finite gets ``inf`` (never quiet).
    """
    data = np.asarray(x, dtype=float)
    rows = data.reshape(data.shape[0], -1)
    if window < 2 or window > rows.shape[0]:
        raise ModelError(f"window must be 2..{rows.shape[0]} samples, got {window}")
    finite = np.all(np.isfinite(rows), axis=1)
    if not np.any(finite):
        raise ModelError("every sample is lost (NaN): cannot estimate the noise level")
    centred = np.where(finite[:, None], rows - rows[finite].mean(axis=0), 0.0)
    s0 = _window_sums(finite.astype(float)[:, None], window)[:, 0]
    s1 = _window_sums(centred, window)
    s2 = _window_sums(centred**2, window)
    enough = s0 >= max(2.0, window / 2.0)
    count = np.where(enough, s0, 2.0)[:, None]
    var = np.maximum((s2 - s1**2 / count) / (count - 1.0), 0.0)
    return np.where(enough, np.sqrt(var.sum(axis=1)), np.inf)


def _window_sums(x: Array, window: int) -> Array:
    """Sum ``x`` over each window of ``window`` rows, from one cumulative sum."""
    c = np.concatenate((np.zeros((1, x.shape[1])), np.cumsum(x, axis=0)))
    return c[window:] - c[:-window]


def default_threshold(stds: Array, factor: float = DEFAULT_THRESHOLD_FACTOR) -> float:
    """``factor`` × the 10th percentile of the finite moving stds (module doc)."""
    finite = stds[np.isfinite(stds)]
    if finite.size == 0:
        raise ModelError("no window without lost samples: cannot estimate the noise level")
    return float(factor * np.percentile(finite, REFERENCE_PERCENTILE))


def detect_static_intervals(
    accel: ArrayLike,
    sample_rate_hz: float,
    *,
    window_s: float = 1.0,
    threshold: float | None = None,
    min_duration_s: float = 2.0,
    gyro: ArrayLike | None = None,
    gyro_threshold: float | None = None,
) -> list[StaticInterval]:
    """Find the static intervals of a recording by the accelerometer moving std (module doc).

    ``accel`` (and ``gyro``) are ``(n, 3)`` counts. ``threshold`` (counts, on the total moving
    std) defaults to 3 × its 10th percentile; with ``gyro`` a window must be quiet on both
    sensors (``gyro_threshold`` chosen the same way). Returns the intervals in time order;
    an interval may hold a few lost (NaN) rows, which averaging drops.
    """
    fs = float(sample_rate_hz)
    if not np.isfinite(fs) or fs <= 0.0:
        raise ModelError(f"sample_rate_hz must be positive, got {sample_rate_hz!r}")
    a = np.asarray(accel, dtype=float)
    window = int(round(window_s * fs))
    quiet = _quiet_windows(a, window, threshold)
    if gyro is not None:
        gy = np.asarray(gyro, dtype=float)
        if gy.shape[0] != a.shape[0]:
            raise ModelError(f"gyro has {gy.shape[0]} samples, accel {a.shape[0]}")
        quiet &= _quiet_windows(gy, window, gyro_threshold)
    min_samples = int(np.ceil(min_duration_s * fs))
    intervals = [
        StaticInterval(int(start), int(stop))
        for start, stop in _centred_runs(quiet, window)
        if stop - start >= min_samples
    ]
    logger.debug("found %d static intervals (window %d samples)", len(intervals), window)
    return intervals


def _quiet_windows(x: Array, window: int, threshold: float | None) -> NDArray[np.bool_]:
    stds = moving_std(x, window)
    level = default_threshold(stds) if threshold is None else float(threshold)
    return stds <= level


def _centred_runs(quiet: NDArray[np.bool_], window: int) -> list[tuple[int, int]]:
    """Return the centre samples of quiet runs: windows ``[ja, jb)`` give ``[ja+h, jb+h)``.

    ``h = window // 2``: window ``j`` covers ``[j, j + window)`` and is centred on ``j + h``.
    A run that reaches the first (last) window extends to the record's first (last) sample.
    """
    edges = np.diff(np.concatenate(([0], quiet.astype(np.int8), [0])))
    starts = np.flatnonzero(edges == 1) + window // 2
    stops = np.flatnonzero(edges == -1) + window // 2
    if starts.size:
        starts[starts == window // 2] = 0
        stops[stops == quiet.size + window // 2] = quiet.size + window - 1
    return [(int(a), int(b)) for a, b in zip(starts, stops, strict=True)]


@dataclass(frozen=True)
class DisturbanceScores:
    """Per-axis z-scores of one block against the expected static noise (see below)."""

    variance_z: Array
    mean_z: Array | None

    @property
    def max_z(self) -> float:
        """The largest score of the block."""
        worst = float(np.max(self.variance_z))
        if self.mean_z is not None:
            worst = max(worst, float(np.max(self.mean_z)))
        return worst


def disturbance_scores(
    block: ArrayLike,
    reference_std: ArrayLike,
    *,
    reference_mean: ArrayLike | None = None,
    reference_n: int | None = None,
) -> DisturbanceScores:
    """Score a block of ``n`` samples (``(n, axes)``) against the expected static noise.

    - excess variance: ``z = (s²/σ² − 1)·√((n − 1)/2)``, the normal approximation of
      ``(n − 1) s²/σ² ~ χ²(n − 1)``, with σ the reference per-sample std;
    - mean shift (when ``reference_mean`` is given, e.g. the running mean of the position):
      ``z = |x̄ − μ| / (σ·√(1/n + 1/n_ref))`` (``n_ref`` None: the reference mean is exact).

    NaN rows are dropped first; fewer than 2 finite rows score 0.
    """
    rows = np.asarray(block, dtype=float)
    rows = rows.reshape(rows.shape[0], -1)
    rows = rows[np.all(np.isfinite(rows), axis=1)]
    sigma = np.broadcast_to(np.asarray(reference_std, dtype=float), (rows.shape[1],))
    if np.any(~(sigma > 0.0)):
        raise ModelError(f"reference_std must be positive, got {sigma}")
    n = rows.shape[0]
    if n < 2:
        return DisturbanceScores(np.zeros(rows.shape[1]), None)
    var = rows.var(axis=0, ddof=1)
    variance_z = (var / sigma**2 - 1.0) * np.sqrt((n - 1) / 2.0)
    mean_z = None
    if reference_mean is not None:
        inv_n_ref = 0.0 if reference_n is None else 1.0 / float(reference_n)
        se = sigma * np.sqrt(1.0 / n + inv_n_ref)
        mean_z = np.abs(rows.mean(axis=0) - np.asarray(reference_mean, dtype=float)) / se
    return DisturbanceScores(variance_z, mean_z)


def detect_disturbance(
    block_accel: ArrayLike,
    block_gyro: ArrayLike | None,
    reference_std_accel: ArrayLike,
    reference_std_gyro: ArrayLike | None = None,
    *,
    reference_mean_accel: ArrayLike | None = None,
    reference_mean_gyro: ArrayLike | None = None,
    reference_n: int | None = None,
    k: float = 5.0,
) -> bool:
    """Tell whether a block shows motion: any score of :func:`disturbance_scores` above ``k``.

    Stateless, for the procedure to call on each block while averaging a position. At k = 5
    the false-alarm probability of a still block with white noise is 5.7e-7 per score for the
    mean test, and for the variance test (χ² tail) 1.4e-4 at n = 20, 3.6e-5 at n = 50,
    1.4e-5 at n = 100. The gyro is scored only when its block and reference std are given.
    """
    worst = disturbance_scores(
        block_accel,
        reference_std_accel,
        reference_mean=reference_mean_accel,
        reference_n=reference_n,
    ).max_z
    if block_gyro is not None and reference_std_gyro is not None:
        gyro = disturbance_scores(
            block_gyro,
            reference_std_gyro,
            reference_mean=reference_mean_gyro,
            reference_n=reference_n,
        )
        worst = max(worst, gyro.max_z)
    return worst > k
