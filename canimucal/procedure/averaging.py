"""How long each position is averaged: the plan's seconds, the first position's noise.

The plan registry gives each position its seconds (:class:`~canimucal.model.positions.Plan`);
:meth:`AveragingPolicy.seconds_for` turns them into the time a session averages, and
:func:`plan_schedule` into what is known of it before the first position (the plan screen,
``canimucal plan``, the field guide and the certificate all read that one schedule):

- ``fixed_s`` (the demo's and the TUI's ``--seconds``): every position, the first one included.
- ``user_s``: the first position ``max(first_min_s, user_s)``, then ``user_s``.
- Otherwise (the default) the first position records ``max(first_min_s, its seconds)``
  (120 s: long enough for an Allan deviation out to 30 s), and a noise model fitted to its
  Allan deviation (:func:`canimucal.model.noise.fit_noise`) sets the time of the others,
  each at most its own seconds in the plan: the plan's time is the operator's budget, the
  noise may only shorten it (clipped to ``min_s``–budget). White noise has no Allan minimum,
  so its choice is the budget itself: the plan's seconds. Until a choice is made (a resumed
  session without its first position's samples) the others get the plan's seconds.

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
gyro (optimum 20–40 s) pulls a white accelerometer's budget down the same way. The ratio is
free of units, so it compares an accelerometer axis with a gyro axis without a conversion
(the acceptance limits, which might rank the sensors, bound the accelerometer alone).

The optima come from 120 s, where a white axis's fitted walk scatters: on pure white noise
(40 seeds, 100 Hz, a 120 s budget) the time had median 113 s over the three accelerometer
axes and 85 s over all six (5th percentile 60 s in both; ``benchmarks/averaging.py``).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from canimucal.model.noise import (
    AveragingChoice,
    NoiseTerms,
    allan_deviation,
    choose_averaging,
    fit_noise,
)
from canimucal.model.positions import DEFAULT_SECONDS, Plan
from canimucal.procedure.events import AveragingTimeChosen

Array = NDArray[np.float64]

MIN_SAMPLES_FOR_NOISE = 200
DEFAULT_BUDGET_S = 120.0
"""The noise rule's upper clip when no plan gives one (``plan --noise`` without positions)."""


@dataclass(frozen=True)
class AveragingPolicy:
    """Averaging-time rules; see the module doc."""

    fixed_s: float | None = None
    user_s: float | None = None
    first_min_s: float = 120.0
    min_s: float = 15.0
    """Shortest time the noise may choose (a budget below it is kept as it is)."""

    def first_seconds(self, planned_s: float = DEFAULT_SECONDS) -> float:
        """Averaging time of the first position, whose plan gives it ``planned_s``."""
        if self.fixed_s is not None:
            return self.fixed_s
        return max(self.first_min_s, self.user_s or planned_s)

    def later_seconds(self, planned_s: float, chosen_s: float | None) -> tuple[float, str]:
        """Time of a later position (its plan gives ``planned_s``) and its source.

        ``fixed``, ``user``, ``noise`` (the first position's choice, at most ``planned_s``)
        or ``plan`` (no choice yet).
        """
        if self.fixed_s is not None:
            return self.fixed_s, "fixed"
        if self.user_s is not None:
            return self.user_s, "user"
        if chosen_s is not None:
            return min(chosen_s, planned_s), "noise"
        return planned_s, "plan"

    def seconds_for(self, index: int, planned_s: float, chosen_s: float | None = None) -> float:
        """Averaging time of position ``index`` (0: the first), planned ``planned_s``."""
        if index == 0:
            return self.first_seconds(planned_s)
        return self.later_seconds(planned_s, chosen_s)[0]

    def clip(self, budget_s: float) -> tuple[float, float]:
        """Range the noise may choose from under a budget of ``budget_s`` (module doc)."""
        return min(self.min_s, budget_s), budget_s

    @property
    def needs_noise(self) -> bool:
        """Whether the noise of the first position decides the later times."""
        return self.fixed_s is None and self.user_s is None


@dataclass(frozen=True)
class PlanSchedule:
    """What is known before the first position of a plan's times (module doc).

    ``seconds``: each position's averaging time as :meth:`AveragingPolicy.seconds_for` gives
    it before the data (under the noise rule: the budget, which white noise takes);
    ``setup_seconds`` the operator's time to set up one position (the plan's).
    """

    seconds: tuple[float, ...]
    setup_seconds: float
    rule: str
    """``fixed``, ``user`` or ``noise`` (module doc)."""

    @property
    def total_seconds(self) -> float:
        """Averaging time of the whole plan, seconds."""
        return float(sum(self.seconds))

    @property
    def operator_minutes(self) -> float:
        """Minutes of the operator's time: setting up each position plus its averaging."""
        return (self.total_seconds + self.setup_seconds * len(self.seconds)) / 60.0

    def words(self) -> str:
        """One line: each position's time, the total and the operator's minutes."""
        return f"{self.times_words()}: {self.totals_words()}"

    def totals_words(self) -> str:
        """``540 s of averaging, about 33 operator minutes``."""
        return (
            f"{self.total_seconds:g} s of averaging, about {self.operator_minutes:.0f} "
            "operator minutes"
        )

    def times_words(self) -> str:
        """Each position's averaging time in words (runs of equal times told once)."""
        first, later = self.seconds[0], self.seconds[1:]
        if self.rule == "fixed" or not later and self.rule != "noise":
            return _runs(self.seconds, "")
        head = f"position 1 {first:g} s"
        if self.rule == "noise":
            head += " (it measures the noise)"
        if not later:
            return head
        at_most = "at most " if self.rule == "noise" else ""
        return f"{head}, {_runs(later, 'then ' + at_most, start=2)}"


def _runs(seconds: Sequence[float], prefix: str, start: int = 1) -> str:
    """``60 s each`` when all are equal, else ``positions 2–3 30 s, position 4 60 s``."""
    if len(set(seconds)) == 1:
        each = " each" if len(seconds) > 1 else ""
        return f"{prefix}{seconds[0]:g} s{each}"
    parts, i = [], 0
    while i < len(seconds):
        j = i
        while j + 1 < len(seconds) and seconds[j + 1] == seconds[i]:
            j += 1
        where = f"position {start + i}" if i == j else f"positions {start + i}–{start + j}"
        parts.append(f"{where} {seconds[i]:g} s")
        i = j + 1
    return prefix + ", ".join(parts)


def plan_schedule(plan: Plan, policy: AveragingPolicy | None = None) -> PlanSchedule:
    """Return the times ``policy`` (default: the procedure's rule) gives ``plan``'s positions."""
    policy = policy or AveragingPolicy()
    seconds = tuple(policy.seconds_for(i, p.seconds, None) for i, p in enumerate(plan.positions))
    rule = "fixed" if policy.fixed_s is not None else "user" if policy.user_s else "noise"
    return PlanSchedule(seconds, plan.setup_seconds, rule)


def scheduled_plan(plan: Plan, schedule: PlanSchedule) -> Plan:
    """``plan`` with each position's seconds those of ``schedule`` (for its bounds)."""
    positions = tuple(
        replace(p, seconds=s) for p, s in zip(plan.positions, schedule.seconds, strict=True)
    )
    return replace(plan, positions=positions)


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
    return (
        f"first position at least {policy.first_min_s:g} s; later ones the plan's seconds "
        f"or less: the time that keeps every {' and '.join(sensors)} axis nearest its Allan "
        f"minimum on the first (the worst one limits; at least {policy.min_s:g} s)"
    )


def choose_time(
    policy: AveragingPolicy,
    samples: Mapping[str, Sequence[Array]],
    sample_rate_hz: float,
    sensors: Sequence[str],
    budget_s: float = DEFAULT_BUDGET_S,
) -> AveragingTimeChosen:
    """Decide the later positions' time after the first one (module doc).

    ``samples``: per sensor, the first position's ``(n, 3)`` rows (in pieces); only the
    ``sensors`` the plan fits (:func:`averaged_sensors`) are used, and a sensor without
    :data:`MIN_SAMPLES_FOR_NOISE` finite rows (a unit without gyro) drops out. ``budget_s``:
    the longest time the plan gives a later position (the upper clip).
    """
    if not policy.needs_noise:
        seconds, source = policy.later_seconds(budget_s, None)
        return AveragingTimeChosen(seconds, source)
    rows = {
        name: np.concatenate(samples[name])
        for name in sensors
        if name in samples and len(samples[name])
    }
    choice = noise_choice(rows, sample_rate_hz, policy.clip(budget_s))
    if choice is None:
        return AveragingTimeChosen(budget_s, "plan")
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


def later_budget_s(plan: Plan) -> float:
    """Return the longest time ``plan`` gives a position after the first (the noise's clip)."""
    later = [p.seconds for p in plan.positions[1:]]
    return max(later) if later else DEFAULT_BUDGET_S
