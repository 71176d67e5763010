"""How long each position is averaged (the first level position, then the measured noise).

- ``fixed_s`` (the demo's ``--seconds``): every position, the first one included.
- Otherwise the first position records ``max(first_min_s, user_s or default_s)`` (120 s by
  default: long enough for an Allan deviation out to 30 s), and a noise model fitted to its
  Allan deviation (:func:`canimucal.model.noise.fit_noise`) sets the time of the others from
  each axis's own ADEV minimum, clipped to 15–120 s. ``user_s`` overrides that choice. Until
  a choice is made the others get ``default_s`` (30 s).

Which axes decide (:func:`averaged_sensors`): every axis whose position averages the plan
turns into parameters. The accelerometer's always (K, bias, base tilt); the gyro's too when
the model has a gyro (``mems``: its bias is the mean of the positions' rates; ``nav``: S from
the Earth rate in the positions' averages; G from the rate's change with the specific force
between positions). A position mean over T seconds scatters by the axis's Allan deviation
σ_a(T), and every parameter fitted from that axis's averages inherits it, so the axis loses
``L_a(T) = σ_a(T)/σ_a(τ*_a)`` against its own best time τ*_a. The time is the minimax
``argmin_T max_a L_a(T)`` over the relevant axes of both sensors
(:func:`~canimucal.model.noise.choose_averaging`): the parameter served worst is as close to
its own best as one shared time allows. The binding axis, named ``sensor.axis``, is the axis
that limits the plan; of two that bind together, the drifting one (optimum below T). The upper
clip is the operator's time budget, so a white axis's best is the clip: a white gyro and a
drifting accelerometer axis meet at the time where both lose the same factor, and a drifting
gyro (optimum 20–40 s) pulls a white accelerometer's 120 s down the same way. The ratio is
free of units, so it compares an accelerometer axis with a gyro axis without a conversion
(the acceptance limits, which might rank the sensors, bound the accelerometer alone).

The optima come from 120 s, where a white axis's fitted walk scatters: on pure white noise
(40 seeds, 100 Hz) the time had median 113 s over the three accelerometer axes and 85 s over
all six (5th percentile 60 s in both; ``benchmarks/averaging.py``).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
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


def averaged_sensors(gyro: str) -> tuple[str, ...]:
    """Sensors whose position averages a plan fits, for the gyro model ``gyro`` (module doc).

    ``none``: the accelerometer alone; ``mems``, ``moves``, ``nav``: accelerometer and gyro.
    """
    return ("accel",) if gyro == "none" else ("accel", "gyro")


def noise_choice(
    samples: Mapping[str, Array], sample_rate_hz: float, clip_s: tuple[float, float]
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


def describe_rule(policy: AveragingPolicy, sensors: Sequence[str] = ("accel", "gyro")) -> str:
    """One line saying how the procedure times its positions under ``policy``.

    ``sensors`` those whose axes decide (:func:`averaged_sensors`).
    """
    if policy.fixed_s is not None:
        return f"every position {policy.fixed_s:g} s (fixed)"
    if policy.user_s is not None:
        return f"first position {policy.first_seconds():g} s, then {policy.user_s:g} s (user)"
    lo, hi = policy.clip_s
    return (
        f"first position {policy.first_seconds():g} s; then the time that keeps every "
        f"{' and '.join(sensors)} axis nearest its own Allan minimum (the worst one "
        f"limits), measured on the first position ({lo:g}–{hi:g} s; {policy.default_s:g} s "
        "until known)"
    )


def choose_time(
    policy: AveragingPolicy,
    samples: Mapping[str, Sequence[Array]],
    sample_rate_hz: float,
    sensors: Sequence[str],
) -> AveragingTimeChosen:
    """Decide the later positions' time after the first one (module doc).

    ``samples``: per sensor, the first position's ``(n, 3)`` rows (in pieces); only the
    ``sensors`` the plan fits (:func:`averaged_sensors`) are used, and a sensor without
    :data:`MIN_SAMPLES_FOR_NOISE` finite rows (a unit without gyro) drops out.
    """
    if not policy.needs_noise:
        seconds, source = policy.later_seconds(None)
        return AveragingTimeChosen(seconds, source)
    rows = {
        name: np.concatenate(samples[name])
        for name in sensors
        if name in samples and len(samples[name])
    }
    choice = noise_choice(rows, sample_rate_hz, policy.clip_s)
    if choice is None:
        return AveragingTimeChosen(policy.default_s, "default")
    picked, terms = choice
    limiting = picked.limiting_axis.split(".")[0]
    t = terms[limiting]
    return AveragingTimeChosen(
        picked.seconds,
        "noise",
        tuple(float(x) for x in t.white_noise_density),
        tuple(float(x) for x in t.random_walk),
        tuple(float(x) for x in picked.optima_s[limiting]),
        picked.limiting_axis,
        tuple((name, tuple(float(x) for x in v)) for name, v in picked.optima_s.items()),
        tuple((name, tuple(float(x) for x in v)) for name, v in picked.loss.items()),
    )
