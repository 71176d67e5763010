"""Warm-up: wait until the temperature slope is below a threshold.

The slope is the least-squares line through the (sample time, temperature) points of the
last ``window_s``; the unit is warm when the window is full and |slope| is at most
``threshold_c_per_min``. Temperature arrives with TPDO3 (0.01 °C steps, every 100 ms): over
a 60 s window the slope's resolution is far below the default 0.1 °C/min. A node that sends
no temperature within ``window_s`` is taken as warm (nothing to wait for), and says so.
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np

from canimucal.procedure.events import WarmupProgressed

DEFAULT_WINDOW_S = 60.0
DEFAULT_THRESHOLD_C_PER_MIN = 0.1


class WarmupTracker:
    """Temperature slope over a sliding window of sample time."""

    def __init__(
        self,
        *,
        window_s: float = DEFAULT_WINDOW_S,
        threshold_c_per_min: float = DEFAULT_THRESHOLD_C_PER_MIN,
    ) -> None:
        self.window_s = float(window_s)
        self.threshold_c_per_min = float(threshold_c_per_min)
        self._points: deque[tuple[float, float]] = deque()
        self.first_time_s: float | None = None
        self.latest_time_s = 0.0
        self.temp_c = float("nan")

    def add(self, time_s: float, temp_c: float) -> None:
        """Record the temperature at sample time ``time_s`` (NaN: no reading yet)."""
        if self.first_time_s is None:
            self.first_time_s = time_s
        self.latest_time_s = time_s
        if not math.isfinite(temp_c):
            return
        self.temp_c = float(temp_c)
        self._points.append((time_s, float(temp_c)))
        while self._points and self._points[0][0] < time_s - self.window_s:
            self._points.popleft()

    @property
    def elapsed_s(self) -> float:
        """Sample time since the first block."""
        return 0.0 if self.first_time_s is None else self.latest_time_s - self.first_time_s

    @property
    def slope_c_per_min(self) -> float | None:
        """Least-squares temperature slope over the window (°C/min), None with < 2 points."""
        if len(self._points) < 2:
            return None
        t, temp = np.array(self._points).T
        if np.ptp(t) <= 0.0:
            return None
        return float(np.polyfit(t - t[0], temp, 1)[0] * 60.0)

    @property
    def warm(self) -> bool:
        """Window full and slope at most the threshold (or no temperature for a window)."""
        if self.elapsed_s < self.window_s:
            return False
        slope = self.slope_c_per_min
        if slope is None:
            return not self._points
        return abs(slope) <= self.threshold_c_per_min


def progress_event(tracker: WarmupTracker, *, skipped: bool) -> WarmupProgressed:
    """Describe the warm-up as it stands (``skipped``: the operator stopped waiting)."""
    return WarmupProgressed(
        tracker.temp_c,
        tracker.slope_c_per_min,
        tracker.threshold_c_per_min,
        tracker.elapsed_s,
        tracker.window_s,
        tracker.warm or skipped,
        skipped,
    )
