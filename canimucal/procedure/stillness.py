"""Stillness of one node: the moving standard deviation of its accelerometer.

A window of ``window_s`` of the latest samples is *still* when every axis's standard
deviation is at most the threshold. Before the sensor's own noise is known the threshold is
``max(floor, QUIET_FACTOR × the quietest window seen so far)`` per axis: the unit rests
before the operator first moves it, so the quietest window is the noise level (a still
window's std scatters by ≈ 1/√(2(w − 1)), 7 % at w = 100), and a hand turning it moves |f|
by m/s² over a second. The floor (``floor_ms2``, 0.02 m/s² ≈ 2 mg, in counts with the
nominal LSB) keeps a quantized, very quiet axis from calling every bump motion. Once a
position has been averaged, :meth:`StillnessDetector.learn_noise` ties the threshold to its
measured per-sample std. Time is sample time: the detector counts samples (lost ones
included), never reads a clock.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from canimucal.errors import ModelError

Array = NDArray[np.float64]

DEFAULT_WINDOW_S = 0.5
DEFAULT_FLOOR_MS2 = 0.02
QUIET_FACTOR = 3.0
NOISE_FACTOR = 4.0
"""A still window's std scatters by ≈ 1/√(2(w − 1)) (5 % at w = 100): 4× is never reached."""
MIN_THRESHOLD_COUNTS = 1.0
"""Never below one count, so quantization alone cannot look like motion."""


class StillnessDetector:
    """Moving std of the accelerometer over the latest ``window_s`` of samples (counts)."""

    def __init__(
        self,
        sample_rate_hz: float,
        accel_lsb: float,
        *,
        window_s: float = DEFAULT_WINDOW_S,
        floor_ms2: float = DEFAULT_FLOOR_MS2,
    ) -> None:
        if not sample_rate_hz > 0:
            raise ModelError(f"sample rate must be positive, got {sample_rate_hz}")
        self.sample_rate_hz = float(sample_rate_hz)
        self.window_n = max(4, round(window_s * sample_rate_hz))
        self.floor_counts = max(floor_ms2 / abs(accel_lsb), MIN_THRESHOLD_COUNTS)
        self.threshold_counts = np.full(3, self.floor_counts)
        self._quietest = np.full(3, np.inf)
        self._learned = False
        self._buffer = np.empty((0, 3))
        self._still_samples = 0
        self.moving_std_counts = float("nan")

    def learn_noise(self, std_counts: Array) -> None:
        """Tie the threshold to the measured per-sample std of a still position."""
        std = np.asarray(std_counts, dtype=float)
        if std.shape == (3,) and np.all(np.isfinite(std)):
            self.threshold_counts = np.maximum(NOISE_FACTOR * std, MIN_THRESHOLD_COUNTS)
            self._learned = True

    def reset(self) -> None:
        """Forget the window (after a commanded move)."""
        self._buffer = np.empty((0, 3))
        self._still_samples = 0
        self.moving_std_counts = float("nan")

    def update(self, accel_counts: Array, advanced_samples: int) -> bool:
        """Add a block; return whether the latest full window is still.

        ``advanced_samples`` is how far the block moved the sample clock (rows plus samples
        lost in counter gaps); it extends the still time when the window stays still.
        """
        rows = np.asarray(accel_counts, dtype=float).reshape(-1, 3)
        rows = rows[np.all(np.isfinite(rows), axis=1)]
        self._buffer = np.concatenate((self._buffer, rows))[-self.window_n :]
        if self._buffer.shape[0] < self.window_n:
            self._still_samples = 0
            return False
        std = self._buffer.std(axis=0, ddof=1)
        if not self._learned:
            self._quietest = np.minimum(self._quietest, std)
            self.threshold_counts = np.maximum(self.floor_counts, QUIET_FACTOR * self._quietest)
        self.moving_std_counts = float(np.max(std))
        if np.all(std <= self.threshold_counts):
            self._still_samples += advanced_samples
            return True
        self._still_samples = 0
        return False

    @property
    def still_for_s(self) -> float:
        """Sample time the window has stayed still (0 while moving)."""
        return self._still_samples / self.sample_rate_hz
