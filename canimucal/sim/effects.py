"""Hidden effects for the discrepancy tests: one effect of the vocabulary, sized in σ.

:func:`hide_effect` returns a truth JSON document carrying one effect of the effect registry
(docs/design.md §6), at the truth path the registry names, on a random axis or entry, of a
size drawn uniformly between ``low`` and ``high`` times the σ of that entry's own estimate
(``sigmas``, from :func:`canimucal.analysis.discrepancy.effect_sigmas` on a clean session
of the same plan and noise). ``bias_drift`` is sized by the within-position slope it
causes: a Wiener bias of intensity q gives slopes of rms ``√(6 q²/(5 T))`` over T seconds,
set to ``k`` times the white-noise standard error of a slope. ``axis_sign`` inverts one
accelerometer axis.

Every session also follows a non-linear warm-up (:func:`warm_up_profile`), so that
``temperature_bias`` is testable and clean data see a changing temperature too.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from canimucal.errors import InputError
from canimucal.model.vocabulary.effects import EFFECTS

Array = NDArray[np.float64]


@dataclass(frozen=True)
class HiddenEffect:
    """What was hidden: the effect, the entry, its size (its units) and in σ."""

    effect: str
    entry: str
    size: float
    sigmas: float


def warm_up_profile(
    start_c: float = 25.0,
    rise_c: float = 15.0,
    time_constant_s: float = 120.0,
    after_s: float = 0.0,
) -> list[list[float]]:
    """Tabulate a warm-up ``T = start + rise (1 − e^(−t/τ))`` as (s, °C) pairs to 1 h.

    ``after_s``: the same warm-up seen from ``t = after_s`` on (time 0 of the table), as by a
    session that waited that long before its first position.
    """
    times = np.concatenate([np.arange(0.0, 600.0, 5.0), np.arange(600.0, 3601.0, 60.0)])
    temps = start_c + rise_c * (1.0 - np.exp(-(times + after_s) / time_constant_s))
    return [[float(t), float(c)] for t, c in zip(times, temps, strict=True)]


def slope_random_walk(k_sigma: float, sample_sigma: float, fs_hz: float, seconds: float) -> float:
    """Random walk q (counts/√s) whose slopes over ``seconds`` are ``k_sigma`` white σ."""
    n = fs_hz * seconds
    slope_sigma = sample_sigma * np.sqrt(12.0 / (n * seconds**2))  # σ of an OLS slope
    return float(k_sigma * slope_sigma * np.sqrt(5.0 * seconds / 6.0))


def hide_effect(
    base: Mapping[str, Any],
    effect: str,
    rng: np.random.Generator,
    sigmas: Mapping[str, Array],
    *,
    low: float = 5.0,
    high: float = 10.0,
    drift_reference: tuple[float, float, float] = (4.4, 200.0, 30.0),
) -> tuple[dict[str, Any], HiddenEffect]:
    """Copy the truth document ``base`` with ``effect`` added (module doc).

    ``drift_reference`` = (white σ per sample in counts, sample rate Hz, seconds per
    position) sizes ``bias_drift``.
    """
    entry = EFFECTS.lookup(effect)
    d: dict[str, Any] = {k: (dict(v) if isinstance(v, dict) else v) for k, v in base.items()}
    accel = d.setdefault("accel", {})
    k = float(rng.uniform(low, high))
    if effect == "axis_sign":
        axis = int(rng.integers(3))
        kmat = np.array(accel["K"], dtype=float)
        kmat[axis] *= -1.0
        accel["K"] = kmat.tolist()
        return d, HiddenEffect(effect, f"K[{axis}][{axis}]", float(kmat[axis, axis]), np.inf)
    if effect == "bias_drift":
        axis = int(rng.integers(3))
        q = slope_random_walk(k, *drift_reference)
        walk = [0.0, 0.0, 0.0]
        walk[axis] = q
        accel["random_walk"] = walk
        return d, HiddenEffect(effect, f"random_walk[{axis}]", q, k)
    sensor = entry.sensors[0]
    sig = np.asarray(sigmas[f"{sensor}.{effect}"], dtype=float)
    choices = np.flatnonzero(np.isfinite(sig))
    k_entry = int(rng.choice(choices))
    size = float(rng.choice([-1.0, 1.0]) * k * sig[k_entry])
    path = entry.truth_path(sensor, k_entry)
    add_to_truth(d, path, size * entry.truth_per_unit, len(entry.labels))
    return d, HiddenEffect(effect, entry.labels[k_entry], size, k)


_PATH_STEP = re.compile(r"([A-Za-z_][A-Za-z0-9_]*)((?:\[\d+\])*)")


def add_to_truth(doc: dict[str, Any], path: str, value: float, length: int = 3) -> None:
    """Add ``value`` at ``path`` of the truth document ``doc`` (``accel.K[0][1]``, ...).

    Objects on the way are copied before they change (``doc`` shares them with its base);
    a missing number starts at 0, a missing list at ``length`` zeros.
    """
    *parents, leaf = path.split(".")
    node = doc
    for key in parents:
        node[key] = dict(node.get(key, {}))
        node = node[key]
    match = _PATH_STEP.fullmatch(leaf)
    if match is None:
        raise InputError(f"bad truth path {path!r}")
    key, indices = match.group(1), [int(i) for i in re.findall(r"\d+", match.group(2))]
    if not indices:
        node[key] = float(node.get(key, 0.0)) + value
        return
    array = np.array(node.get(key, np.zeros(length)), dtype=float)
    array[tuple(indices)] += value
    node[key] = array.tolist()
