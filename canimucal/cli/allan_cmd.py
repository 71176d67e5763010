"""`canimucal allan`: Allan deviation of a recording's longest still stretch.

Also the fitted noise terms and the averaging time they recommend (DESIGN §2 conventions).
"""

from __future__ import annotations

import argparse
from typing import Any

import numpy as np
from numpy.typing import NDArray

from canimucal.cli.output import add_json_option, check_outputs, emit
from canimucal.errors import InputError
from canimucal.io.recording import Recording, read_recording
from canimucal.model.noise import (
    AllanResult,
    NoiseTerms,
    allan_deviation,
    best_averaging_time_s,
    fit_noise,
)
from canimucal.model.sensor import DEFAULT_ACCEL_LSB, DEFAULT_GYRO_LSB
from canimucal.model.static import detect_static_intervals

MIN_STILL_SECONDS = 10.0


def add_subparser(subparsers: Any) -> None:
    """Register ``allan``."""
    p = subparsers.add_parser(
        "allan",
        help="Allan deviation, noise terms and recommended averaging time",
        description="Overlapping Allan deviation of the longest still stretch of a recording "
        "(one labelled position, or the longest static interval found), the fitted white "
        "noise, bias instability and random walk, and the averaging time they recommend.",
    )
    p.add_argument("recording", help="recording CSV (canimucal.recording/1)")
    p.add_argument("--position", type=int, help="analyse this labelled position")
    add_json_option(p)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    """Analyse and report."""
    check_outputs(args)
    rec = read_recording(args.recording)
    start, stop, where = _still_stretch(rec, args.position)
    fs = rec.sample_rate_hz
    lsb = {
        "accel": _lsb(rec, "accel_lsb", DEFAULT_ACCEL_LSB),
        "gyro": _lsb(rec, "gyro_lsb", DEFAULT_GYRO_LSB),
    }
    sensors: dict[str, tuple[AllanResult, NoiseTerms]] = {}
    for name, data in (("accel", rec.accel), ("gyro", rec.gyro)):
        x = data[start:stop]
        if np.sum(np.all(np.isfinite(x), axis=1)) >= 3 * fs:
            _refuse_constant(x, name, where)
            allan = allan_deviation(x, fs)
            sensors[name] = (allan, fit_noise(allan))
    if not sensors:
        raise InputError(f"{args.recording}: no sensor has 3 s of samples in {where}")
    best = max(best_averaging_time_s(terms) for _, terms in sensors.values())
    doc = _document(sensors, lsb, best, where, (stop - start) / fs)
    emit(args, doc, _report(sensors, lsb, best, where, (stop - start) / fs))
    return 0


def _refuse_constant(x: NDArray[np.float64], name: str, where: str) -> None:
    """Refuse an axis that never changes: it has no noise to analyse (a stuck sensor)."""
    spread = np.nanmax(x, axis=0) - np.nanmin(x, axis=0)
    for axis in np.flatnonzero(~(spread > 0)):
        raise InputError(
            f"{name} {'xyz'[axis]} is constant ({x[0, axis]:g}) over {where}: no noise to "
            "analyse (a stuck sensor?)"
        )


def _lsb(rec: Recording, key: str, default: float) -> float:
    value = rec.header.get(key)
    return abs(float(value)) if isinstance(value, float) else abs(default)


def _still_stretch(rec: Recording, position: int | None) -> tuple[int, int, str]:
    """Sample range [start, stop) to analyse, and a phrase saying where it came from."""
    if position is not None:
        idx = np.flatnonzero(rec.position == position)
        if idx.size == 0:
            raise InputError(f"no samples labelled position {position}")
        return int(idx[0]), int(idx[-1]) + 1, f"position {position}"
    labels = rec.position
    if np.any(labels >= 0):
        best = max((np.flatnonzero(labels == p) for p in np.unique(labels[labels >= 0])), key=len)
        return int(best[0]), int(best[-1]) + 1, f"position {int(labels[best[0]])} (longest)"
    finite = np.all(np.isfinite(rec.accel), axis=1)
    filled = np.where(finite[:, None], rec.accel, np.nanmedian(rec.accel, axis=0))
    intervals = detect_static_intervals(filled, rec.sample_rate_hz)
    if not intervals:
        raise InputError("no still stretch found (no labelled position, no static interval)")
    longest = max(intervals, key=lambda i: i.stop - i.start)
    seconds = (longest.stop - longest.start) / rec.sample_rate_hz
    if seconds < MIN_STILL_SECONDS:
        raise InputError(
            f"the longest still stretch lasts {seconds:.1f} s;"
            f" an Allan deviation needs at least {MIN_STILL_SECONDS:g} s"
        )
    return longest.start, longest.stop, f"samples {longest.start}–{longest.stop} (longest static)"


def _si(values: NDArray[np.float64], lsb: float) -> list[float]:
    return [float(v) for v in np.asarray(values) * lsb]


def _document(
    sensors: dict[str, tuple[AllanResult, NoiseTerms]],
    lsb: dict[str, float],
    best: float,
    where: str,
    seconds: float,
) -> dict[str, Any]:
    out: dict[str, Any] = {"stretch": where, "seconds": seconds, "best_averaging_s": best}
    for name, (allan, terms) in sensors.items():
        unit = "m/s²" if name == "accel" else "rad/s"
        out[name] = {
            "units_si": unit,
            "lsb": lsb[name],
            "taus_s": allan.taus_s,
            "adev_counts": allan.adev,
            "adev_sigma_counts": allan.adev_sigma,
            "white_noise_density_counts": terms.white_noise_density,
            "white_noise_density_si": _si(terms.white_noise_density, lsb[name]),
            "bias_instability_counts": terms.bias_instability,
            "random_walk_counts_per_sqrt_s": terms.random_walk,
            "best_averaging_s": best_averaging_time_s(terms),
        }
    return out


def _report(
    sensors: dict[str, tuple[AllanResult, NoiseTerms]],
    lsb: dict[str, float],
    best: float,
    where: str,
    seconds: float,
) -> str:
    lines = [f"Allan deviation of {where}, {seconds:.1f} s"]
    for name, (_allan, terms) in sensors.items():
        unit = "m/s²/√Hz" if name == "accel" else "rad/s/√Hz"
        lines.append(f"{name}:")
        for axis, label in enumerate("xyz"):
            n = terms.white_noise_density[axis]
            lines.append(
                f"  {label}: white {n:.4g} counts/√Hz ({n * lsb[name]:.3g} {unit}), "
                f"bias instability {terms.bias_instability[axis]:.3g} counts, "
                f"random walk {terms.random_walk[axis]:.3g} counts/√s"
            )
    lines.append(f"recommended averaging time: {best:.0f} s (clipped to 15–120 s)")
    return "\n".join(lines) + "\n"
