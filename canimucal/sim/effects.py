"""Hidden effects for the discrepancy tests: one effect of the vocabulary, sized in σ.

:func:`hide_effect` returns a truth JSON document carrying one effect (docs/design.md §5
vocabulary) on a random axis or entry, of a size drawn uniformly between ``low`` and
``high`` times the σ of that entry's own estimate (``sigmas``, from
:func:`canimucal.analysis.discrepancy.effect_sigmas` on a clean session of the same plan and
noise). ``bias_drift`` is sized by the within-position slope it causes: a Wiener bias of
intensity q gives slopes of rms ``√(6 q²/(5 T))`` over T seconds, set to ``k`` times the
white-noise standard error of a slope. ``axis_sign`` inverts one accelerometer axis.

Every session also follows a non-linear warm-up (:func:`warm_up_profile`), so that
``temperature_bias`` is testable and clean data see a changing temperature too.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from canimucal.errors import InputError

Array = NDArray[np.float64]

HIDDEN_EFFECTS = (
    "base_tilt",
    "cross_axis",
    "scale_nonlinearity",
    "temperature_bias",
    "bias_drift",
    "gyro_g_sensitivity",
    "axis_sign",
)
"""Effects :func:`hide_effect` can inject (the docs/design.md §5 vocabulary)."""

_KEYS = {
    "base_tilt": "accel.base_tilt",
    "cross_axis": "accel.cross_axis",
    "scale_nonlinearity": "accel.scale_nonlinearity",
    "temperature_bias": "accel.temperature_bias",
    "gyro_g_sensitivity": "gyro.gyro_g_sensitivity",
}
_OFF = ((0, 1), (0, 2), (1, 0), (1, 2), (2, 0), (2, 1))


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
    if effect not in HIDDEN_EFFECTS:
        raise InputError(f"unknown effect {effect!r}; choose from {', '.join(HIDDEN_EFFECTS)}")
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
    sig = np.asarray(sigmas[_KEYS[effect]], dtype=float)
    choices = np.flatnonzero(np.isfinite(sig))
    entry = int(rng.choice(choices))
    size = float(rng.choice([-1.0, 1.0]) * k * sig[entry])
    return d, _apply(d, effect, entry, size, k)


def _apply(d: dict[str, Any], effect: str, entry: int, size: float, k: float) -> HiddenEffect:
    accel = d["accel"]
    if effect == "base_tilt":
        tilt = dict(d.get("base_tilt_deg", {"alpha0": 0.0, "beta0": 0.0}))
        name = ("alpha0", "beta0")[entry]
        tilt[name] = float(tilt.get(name, 0.0)) + float(np.rad2deg(size))
        d["base_tilt_deg"] = tilt
        return HiddenEffect(effect, name, size, k)
    if effect == "cross_axis":
        i, j = _OFF[entry]
        kmat = np.array(accel["K"], dtype=float)
        kmat[i, j] += size
        accel["K"] = kmat.tolist()
        return HiddenEffect(effect, f"K[{i}][{j}]", size, k)
    if effect in ("scale_nonlinearity", "temperature_bias"):
        key = "quadratic" if effect == "scale_nonlinearity" else "temp_coeff"
        values = [0.0, 0.0, 0.0]
        values[entry] = size
        accel[key] = values
        return HiddenEffect(effect, f"{key}[{entry}]", size, k)
    gyro = d.setdefault("gyro", {})
    gmat = np.zeros((3, 3))
    gmat[entry // 3, entry % 3] = size
    gyro["G"] = gmat.tolist()
    return HiddenEffect(effect, f"G[{entry // 3}][{entry % 3}]", size, k)
