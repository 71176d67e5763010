"""One long static recording: noise terms with intervals, drift, and the averaging time per axis.

The standard way to characterise an IMU's noise is one long recording in one pose. Such a
file has no positions to calibrate from; what it gives, per sensor and axis, is the Allan
deviation (:func:`~canimucal.model.noise.allan_deviation`) and from it the white noise density,
the bias instability and the random walk with their 95 % intervals
(:func:`~canimucal.model.noise.noise_intervals`), the averaging time that minimises each
axis's ADEV, and one time for all axes with the limiting axis named
(:func:`~canimucal.model.noise.choose_averaging`).

``bias_drift`` is tested as in a session (:mod:`.drift`): the record is cut into
:data:`DRIFT_SEGMENTS` equal segments whose slopes give the χ² test and the random walk q; a
significant result is named ``bias_drift`` only when q stays within
:data:`~.drift.WALK_FACTOR` of the Allan deviation's 95 % random-walk bound.

A recording is treated as static (:func:`static_rows`) when it has one labelled position, or no
labels and every still interval found has the same orientation (within
:data:`SAME_POSE_DEG`): cutting such a file into "positions" would make fake ones.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from canimucal.analysis.drift import (
    DriftTest,
    allan_walk_upper,
    drift_test,
    walk_consistent,
)
from canimucal.analysis.repeats import unique_samples
from canimucal.errors import InputError
from canimucal.io.grouping import position_rows
from canimucal.io.recording import Recording
from canimucal.model.noise import (
    AllanResult,
    AveragingChoice,
    NoiseIntervals,
    NoiseTerms,
    allan_deviation,
    axis_optima_s,
    choose_averaging,
    fit_noise,
    noise_intervals,
)
from canimucal.model.sensor import DEFAULT_ACCEL_LSB, DEFAULT_GYRO_LSB
from canimucal.model.vocabulary.effects import EFFECTS

Array = NDArray[np.float64]

DRIFT_SEGMENTS = 8
"""Segments a static record is cut into for the within-segment slope (drift) test."""

DRIFT_ALPHA = 0.01
"""Level of the drift test (one test per sensor)."""

SAME_POSE_DEG = 2.0
"""Still intervals whose mean specific forces differ by less than this are one pose."""

MIN_STATIC_SECONDS = 30.0
"""Shortest static record analysed (an Allan deviation out to 7.5 s)."""

MISFIT_CHI2 = 3.0
"""An axis whose Allan fit has a larger χ²/dof is reported as not described by the fit."""

DEFAULT_CLIP_S = (15.0, 120.0)
"""Range of the averaging time chosen for a calibration position."""


@dataclass(frozen=True)
class SensorStatic:
    """One sensor of a static record (units of the data, counts for raw outputs).

    ``optima_s`` the per-axis ADEV minima (unclipped; inf for a white axis); ``drift`` the
    segment slope test, ``drift_named`` whether it is named ``bias_drift``; ``walk_upper``
    the Allan deviation's 95 % random-walk bound used for that.
    """

    allan: AllanResult
    terms: NoiseTerms
    intervals: NoiseIntervals
    optima_s: Array
    drift: DriftTest
    drift_named: bool
    walk_upper: Array


@dataclass(frozen=True)
class StaticAnalysis:
    """Everything found on one static record; ``choice`` the averaging time over all axes."""

    where: str
    seconds: float
    sample_rate_hz: float
    sensors: dict[str, SensorStatic]
    lsb: dict[str, float]
    choice: AveragingChoice
    warnings: tuple[str, ...] = ()


def recording_lsb(rec: Recording) -> dict[str, float]:
    """SI per count of each sensor: the header's ``accel_lsb``/``gyro_lsb``, else nominal."""
    out = {}
    for key, default in (("accel", DEFAULT_ACCEL_LSB), ("gyro", DEFAULT_GYRO_LSB)):
        value = rec.header.get(f"{key}_lsb")
        ok = isinstance(value, int | float) and not isinstance(value, bool) and value != 0
        out[key] = abs(float(value)) if ok else abs(default)  # type: ignore[arg-type]
    return out


def static_rows(rec: Recording) -> NDArray[np.intp] | None:
    """Rows of ``rec`` forming one static record, or None when it holds several poses."""
    groups, labelled = position_rows(rec)
    if labelled:
        return groups[0] if len(groups) == 1 else None
    if not groups:
        return None
    means = np.array(
        [np.nanmean(np.asarray(rec.accel[g], dtype=np.float64), axis=0) for g in groups]
    )
    norm = np.linalg.norm(means, axis=1, keepdims=True)
    if not np.all(np.isfinite(norm) & (norm > 0)):
        return None
    unit = means / norm
    cos = np.clip(unit @ unit[0], -1.0, 1.0)
    if np.max(np.rad2deg(np.arccos(cos))) >= SAME_POSE_DEG:
        return None
    return np.arange(int(groups[0][0]), int(groups[-1][-1]) + 1)


def analyze_static(recording: Recording) -> StaticAnalysis:
    """Analyse one long static recording as ``canimucal analyze``/``allan`` do (public API).

    A recording holding several poses is an :class:`InputError` that points to
    ``canimucal.analyze``.
    """
    recording, held = unique_samples(recording)
    rows = static_rows(recording)
    if rows is None:
        raise InputError(
            f"{recording.source or 'recording'}: holds several poses, not one static record: "
            "use canimucal.analyze"
        )
    sa = analyse_static(recording, rows, recording_lsb(recording))
    return sa if held is None else replace(sa, warnings=(held.line(), *sa.warnings))


def analyse_static(
    rec: Recording,
    rows: NDArray[np.intp],
    lsb: dict[str, float],
    *,
    where: str = "the whole record",
    clip: tuple[float, float] = DEFAULT_CLIP_S,
    min_seconds: float = MIN_STATIC_SECONDS,
) -> StaticAnalysis:
    """Analyse ``rows`` of ``rec`` as one static record (module doc).

    A sensor needs ``min_seconds`` of finite samples; with none, :class:`InputError`.
    """
    fs = rec.sample_rate_hz
    seconds = rows.size / fs
    sensors = {}
    for name, data in (("accel", rec.accel), ("gyro", rec.gyro)):
        x = np.asarray(data[rows], dtype=np.float64)
        keep = np.all(np.isfinite(x), axis=1)
        if np.sum(keep) >= min_seconds * fs:
            sensors[name] = _sensor(rec.t[rows], x, fs)
    if not sensors:
        raise InputError(
            f"{rec.source or 'recording'}: no sensor has {min_seconds:g} s of samples in "
            f"{where} ({seconds:.1f} s)"
        )
    choice = choose_averaging({k: v.terms for k, v in sensors.items()}, clip=clip)
    return StaticAnalysis(where, seconds, fs, sensors, lsb, choice, _misfits(sensors))


def _misfits(sensors: dict[str, SensorStatic]) -> tuple[str, ...]:
    """Name the axes the three-term Allan model does not describe.

    A large χ²/dof, or a fitted curve outside the ADEV points' band (the intervals were then
    widened to hold it: :func:`~canimucal.model.noise.noise_intervals`).
    """
    out = []
    for name, s in sensors.items():
        widening = s.intervals.widening
        for axis in np.flatnonzero((s.terms.reduced_chi2 > MISFIT_CHI2) | (widening > 1.0)):
            how = (
                f"its intervals widened ×{widening[axis]:.2g} to hold the fitted curve"
                if widening[axis] > 1.0
                else "the intervals are what the ADEV points allow"
            )
            out.append(
                f"{name} {'xyz'[axis]}: the three-term Allan model misfits (χ²/dof = "
                f"{s.terms.reduced_chi2[axis]:.1f}: coloured or filtered noise); {how}"
            )
    return tuple(out)


def _sensor(t: Array, x: Array, fs: float) -> SensorStatic:
    allan = allan_deviation(x, fs)
    terms = fit_noise(allan)
    cuts = np.array_split(np.arange(t.size), DRIFT_SEGMENTS)
    drift = drift_test([(t[c], x[c]) for c in cuts if np.all(np.isfinite(x[c]), axis=1).sum() > 2])
    upper = allan_walk_upper([(t, x)])
    named = drift.p_value < DRIFT_ALPHA and walk_consistent(drift, upper)
    return SensorStatic(
        allan, terms, noise_intervals(allan, terms), axis_optima_s(terms), drift, named, upper
    )


def _pairs(values: Array, ci: Array, scale: float) -> list[dict[str, object]]:
    return [
        {"value": float(v * scale), "ci95": [float(lo * scale), float(hi * scale)]}
        for v, (lo, hi) in zip(values, ci, strict=True)
    ]


def static_document(sa: StaticAnalysis) -> dict[str, object]:
    """Build the noise block of a static record (counts; ``*_si`` scaled by the LSB)."""
    sensors: dict[str, object] = {}
    for name, s in sa.sensors.items():
        lsb = sa.lsb.get(name, 1.0)
        sensors[name] = {
            "lsb": lsb,
            "taus_s": s.allan.taus_s.tolist(),
            "adev_counts": s.allan.adev.tolist(),
            "adev_sigma_counts": s.allan.adev_sigma.tolist(),
            "white_noise_density_counts": _pairs(
                s.terms.white_noise_density, s.intervals.white_noise_density, 1.0
            ),
            "white_noise_density_si": _pairs(
                s.terms.white_noise_density, s.intervals.white_noise_density, lsb
            ),
            "bias_instability_counts": _pairs(
                s.terms.bias_instability, s.intervals.bias_instability, 1.0
            ),
            "random_walk_counts_per_sqrt_s": _pairs(
                s.terms.random_walk, s.intervals.random_walk, 1.0
            ),
            "best_averaging_s": [float(v) for v in sa.choice.optima_s[name]],
            "drift": {
                "statistic": s.drift.statistic,
                "df": s.drift.df,
                "p_value": s.drift.p_value,
                "random_walk_counts_per_sqrt_s": s.drift.random_walk.tolist(),
                "named": s.drift_named,
            },
        }
    return {
        "stretch": sa.where,
        "seconds": sa.seconds,
        "sensors": sensors,
        "best_averaging_s": sa.choice.seconds,
        "best_averaging_s_per_axis": {k: v.tolist() for k, v in sa.choice.optima_s.items()},
        "limiting_axis": sa.choice.limiting_axis,
        "warnings": list(sa.warnings),
    }


def static_findings(sa: StaticAnalysis) -> list[dict[str, object]]:
    """``bias_drift`` findings of a static record (analysis JSON ``findings``)."""
    out: list[dict[str, object]] = []
    for name, s in sa.sensors.items():
        if s.drift_named:
            q = s.drift.random_walk
            out.append(
                {
                    "effect": "bias_drift",
                    "sensor": name,
                    "size": float(np.max(q)),
                    "units": EFFECTS["bias_drift"].unit,
                    "p_value": s.drift.p_value,
                    "evidence": f"slopes of {DRIFT_SEGMENTS} segments χ² = "
                    f"{s.drift.statistic:.1f} on {s.drift.df} dof; random walk q = "
                    f"{np.array2string(q, precision=3)} counts/√s",
                }
            )
    return out


def static_report(sa: StaticAnalysis) -> str:
    """Build the readable report of a static record."""
    lines = [f"Static record: {sa.where}, {sa.seconds:.1f} s at {sa.sample_rate_hz:g} Hz"]
    for name, s in sa.sensors.items():
        lsb = sa.lsb.get(name, 1.0)
        si = "m/s²/√Hz" if name == "accel" else "rad/s/√Hz"
        lines.append(f"{name} (95 % intervals):")
        ci = s.intervals
        for axis, label in enumerate("xyz"):
            n = s.terms.white_noise_density[axis]
            nl, nh = ci.white_noise_density[axis]
            bl, bh = ci.bias_instability[axis]
            ql, qh = ci.random_walk[axis]
            lines.append(
                f"  {label}: white {n:.4g} counts/√Hz ({nl:.4g}–{nh:.4g}; {n * lsb:.3g} {si}), "
                f"bias instability {s.terms.bias_instability[axis]:.3g} counts "
                f"({bl:.3g}–{bh:.3g}), random walk {s.terms.random_walk[axis]:.3g} counts/√s "
                f"({ql:.3g}–{qh:.3g}), best averaging {best_averaging_text(sa, name, axis)}"
            )
        verdict = "named bias_drift" if s.drift_named else "no bias_drift named"
        if s.drift.p_value < DRIFT_ALPHA and not s.drift_named:
            verdict += " (trends beyond the Allan random-walk bound: not a wandering bias)"
        lines.append(
            f"  drift: slopes of {DRIFT_SEGMENTS} segments χ² = {s.drift.statistic:.1f} on "
            f"{s.drift.df} dof, p = {s.drift.p_value:.2g}: {verdict}"
        )
    c = sa.choice
    lines.append(
        f"averaging time for all axes: {c.seconds:.0f} s (each axis within "
        f"×{max(float(np.max(v)) for v in c.loss.values()):.2f} of its own best ADEV); "
        f"limiting axis {c.limiting_axis}"
    )
    lines += [f"warning: {w}" for w in sa.warnings]
    return "\n".join(lines) + "\n"


def best_averaging_text(sa: StaticAnalysis, sensor: str, axis: int) -> str:
    """One axis's best averaging time as the JSON gives it (``choice.optima_s``, clipped).

    A white axis (no minimum inside the data) gives the range's top, and says so.
    """
    value = float(sa.choice.optima_s[sensor][axis])
    white = not np.isfinite(sa.sensors[sensor].optima_s[axis])
    return f"{value:.3g} s" + (" (white: the range's top)" if white else "")
