"""How long each position is averaged (the first level position, then the measured noise).

- ``fixed_s`` (the demo's ``--seconds``): every position, the first one included.
- Otherwise the first position records ``max(first_min_s, user_s or default_s)`` (120 s by
  default: long enough for an Allan deviation out to 30 s), and a noise model fitted to its
  Allan deviation (:func:`canimucal.model.noise.fit_noise`) sets the time of the others, the
  largest of the axes' ADEV minima clipped to 15–120 s
  (:func:`~canimucal.model.noise.best_averaging_time_s`). ``user_s`` overrides that choice.
  Until a choice is made the others get ``default_s`` (30 s).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from canimucal.model.noise import NoiseTerms, allan_deviation, best_averaging_time_s, fit_noise
from canimucal.procedure.events import AveragingTimeChosen

Array = NDArray[np.float64]

MIN_SAMPLES_FOR_NOISE = 200


@dataclass(frozen=True)
class AveragingPolicy:
    """Averaging-time rules; see the module doc."""

    fixed_s: float | None = None
    user_s: float | None = None
    default_s: float = 30.0
    first_min_s: float = 120.0
    clip_s: tuple[float, float] = (15.0, 120.0)

    def first_seconds(self) -> float:
        """Averaging time of the first position."""
        if self.fixed_s is not None:
            return self.fixed_s
        return max(self.first_min_s, self.user_s or self.default_s)

    def later_seconds(self, chosen_s: float | None) -> tuple[float, str]:
        """Averaging time of later positions and its source (``fixed``/``user``/``noise``)."""
        if self.fixed_s is not None:
            return self.fixed_s, "fixed"
        if self.user_s is not None:
            return self.user_s, "user"
        if chosen_s is not None:
            return chosen_s, "noise"
        return self.default_s, "default"

    @property
    def needs_noise(self) -> bool:
        """Whether the noise of the first position decides the later times."""
        return self.fixed_s is None and self.user_s is None


def noise_choice(
    samples: list[Array], sample_rate_hz: float, clip_s: tuple[float, float]
) -> tuple[float, list[NoiseTerms]] | None:
    """Fit the noise of each sensor's ``(n, 3)`` samples; the largest best time, clipped."""
    terms = []
    for rows in samples:
        if np.sum(np.all(np.isfinite(rows), axis=1)) < MIN_SAMPLES_FOR_NOISE:
            continue
        terms.append(fit_noise(allan_deviation(rows, sample_rate_hz)))
    if not terms:
        return None
    return max(best_averaging_time_s(t, clip=clip_s) for t in terms), terms


def choose_time(
    policy: AveragingPolicy, accel_rows: list[Array], sample_rate_hz: float
) -> AveragingTimeChosen:
    """Decide the later positions' time after the first one (accelerometer noise only).

    Only the accelerometer's Allan deviation is used: the accelerometer calibration is what
    the positions are for, and a white-noise gyro (no ADEV minimum) would always ask for the
    upper clip.
    """
    if not policy.needs_noise:
        seconds, source = policy.later_seconds(None)
        return AveragingTimeChosen(seconds, source)
    rows = [np.concatenate(accel_rows)] if accel_rows else []
    choice = noise_choice(rows, sample_rate_hz, policy.clip_s)
    if choice is None:
        return AveragingTimeChosen(policy.default_s, "default")
    seconds, terms = choice
    return AveragingTimeChosen(
        seconds,
        "noise",
        tuple(float(x) for t in terms for x in t.white_noise_density),
        tuple(float(x) for t in terms for x in t.random_walk),
    )
