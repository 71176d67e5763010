"""How long each position is averaged (the first level position, then the measured noise).

- ``fixed_s`` (the demo's ``--seconds``): every position, the first one included.
- Otherwise the first position records ``max(first_min_s, user_s or default_s)`` (120 s by
  default: long enough for an Allan deviation out to 30 s), and a noise model fitted to its
  Allan deviation (:func:`canimucal.model.noise.fit_noise`) sets the time of the others from
  each axis's own ADEV minimum, clipped to 15–120 s: the time that keeps every axis of the
  sensor that limits the plan closest to its own best (minimax,
  :func:`~canimucal.model.noise.choose_averaging`), with the limiting axis named. The sensor
  is the accelerometer: it is what the positions calibrate. ``user_s`` overrides that choice.
  Until a choice is made the others get ``default_s`` (30 s).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from canimucal.model.noise import (
    AveragingChoice,
    NoiseTerms,
    allan_deviation,
    choose_averaging,
    fit_noise,
)
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


LIMITING_SENSOR = "accel"
"""The sensor whose per-axis optima set the averaging time (module doc)."""


def noise_choice(
    samples: dict[str, Array], sample_rate_hz: float, clip_s: tuple[float, float]
) -> tuple[AveragingChoice, dict[str, NoiseTerms]] | None:
    """Apply the averaging rule: fit each sensor's ``(n, 3)`` samples, choose over their axes.

    Sensors with fewer than :data:`MIN_SAMPLES_FOR_NOISE` finite rows are left out; None
    when none is left. The choice is :func:`~canimucal.model.noise.choose_averaging`.
    """
    terms = {}
    for name, rows in samples.items():
        if np.sum(np.all(np.isfinite(rows), axis=1)) >= MIN_SAMPLES_FOR_NOISE:
            terms[name] = fit_noise(allan_deviation(rows, sample_rate_hz))
    if not terms:
        return None
    return choose_averaging(terms, clip=clip_s), terms


def describe_rule(policy: AveragingPolicy) -> str:
    """One line saying how the procedure times its positions under ``policy``."""
    if policy.fixed_s is not None:
        return f"every position {policy.fixed_s:g} s (fixed)"
    if policy.user_s is not None:
        return f"first position {policy.first_seconds():g} s, then {policy.user_s:g} s (user)"
    lo, hi = policy.clip_s
    return (
        f"first position {policy.first_seconds():g} s; then the time that keeps every "
        f"{LIMITING_SENSOR} axis nearest its own Allan minimum, measured on the first "
        f"position ({lo:g}–{hi:g} s; {policy.default_s:g} s until known)"
    )


def choose_time(
    policy: AveragingPolicy, accel_rows: list[Array], sample_rate_hz: float
) -> AveragingTimeChosen:
    """Decide the later positions' time after the first one (module doc).

    Only the accelerometer's Allan deviation is used (:data:`LIMITING_SENSOR`): the
    accelerometer calibration is what the positions are for, and a white-noise gyro (no ADEV
    minimum) would always ask for the upper clip.
    """
    if not policy.needs_noise:
        seconds, source = policy.later_seconds(None)
        return AveragingTimeChosen(seconds, source)
    rows = {LIMITING_SENSOR: np.concatenate(accel_rows)} if accel_rows else {}
    choice = noise_choice(rows, sample_rate_hz, policy.clip_s)
    if choice is None:
        return AveragingTimeChosen(policy.default_s, "default")
    picked, terms = choice
    t = terms[LIMITING_SENSOR]
    return AveragingTimeChosen(
        picked.seconds,
        "noise",
        tuple(float(x) for x in t.white_noise_density),
        tuple(float(x) for x in t.random_walk),
        tuple(float(x) for x in picked.optima_s[LIMITING_SENSOR]),
        picked.limiting_axis,
    )
