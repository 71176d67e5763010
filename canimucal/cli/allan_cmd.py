"""`canimucal allan`: Allan deviation of one static file or a recording's longest still stretch.

Also the fitted noise terms with intervals, a drift test, each axis's best averaging time and
one for all axes (:mod:`canimucal.analysis.static_noise`; docs/design.md §2 conventions).
Every number carries its unit: the terms in counts (the device's) with their intervals, and
beside them in the operator's unit of the sensor's bias (mg, °/s: the units registry,
:data:`~canimucal.model.vocabulary.units.QUANTITIES`, at the recording's LSBs and g).
"""

from __future__ import annotations

import argparse
from dataclasses import replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from canimucal.analysis.repeats import unique_samples
from canimucal.analysis.static_noise import (
    DRIFT_SEGMENTS,
    StaticAnalysis,
    analyse_static,
    best_averaging_text,
    recording_lsb,
    static_document,
    static_rows,
)
from canimucal.cli.input_options import INPUT_HELP, SECOND_HELP, add_input_options, read_input
from canimucal.cli.output import add_json_option, check_outputs, emit
from canimucal.errors import InputError
from canimucal.io.grouping import label_runs
from canimucal.io.recording import Recording
from canimucal.model.sensor import STANDARD_GRAVITY
from canimucal.model.static import detect_static_intervals
from canimucal.model.vocabulary.units import QUANTITIES, Scales

ALLAN_SCHEMA = "canimucal.allan/1"
"""``allan --json`` (docs/design.md §5)."""
MIN_STILL_SECONDS = 10.0
MIN_SENSOR_SECONDS = 3.0
"""A sensor needs this many seconds of samples in the stretch to be analysed."""


def add_subparser(subparsers: Any) -> None:
    """Register ``allan``."""
    p = subparsers.add_parser(
        "allan",
        help="Allan deviation, noise terms and recommended averaging time",
        description="Overlapping Allan deviation of one long static file, or of the longest "
        "still stretch of a recording (one labelled position, or the longest static interval "
        "found): the fitted white noise, bias instability and random walk with 95 % "
        "intervals, a drift test, each axis's best averaging time and one for all axes with "
        "the limiting axis named.",
    )
    p.add_argument("recording", help=INPUT_HELP)
    p.add_argument("second", nargs="?", help=SECOND_HELP)
    add_input_options(p, plan=False)
    p.add_argument("--position", type=int, help="analyse this labelled position")
    add_json_option(p)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    """Analyse and report."""
    check_outputs(args)
    rec, held = unique_samples(read_input(args, args.recording, args.second))
    start, stop, where = _still_stretch(rec, args.position)
    fs = rec.sample_rate_hz
    for name, data in (("accel", rec.accel), ("gyro", rec.gyro)):
        x = data[start:stop]
        if np.sum(np.all(np.isfinite(x), axis=1)) >= MIN_SENSOR_SECONDS * fs:
            _refuse_constant(x, name, where)
    rows = np.arange(start, stop)
    sa = analyse_static(rec, rows, recording_lsb(rec), where=where, min_seconds=MIN_SENSOR_SECONDS)
    if held is not None:
        sa = replace(sa, warnings=(held.line(), *sa.warnings))
    g = _site_g(rec)
    emit(args, _document(sa, g), _report(sa, g))
    return 0


def _refuse_constant(x: NDArray[np.float64], name: str, where: str) -> None:
    """Refuse an axis that never changes: it has no noise to analyse (a stuck sensor)."""
    spread = np.nanmax(x, axis=0) - np.nanmin(x, axis=0)
    for axis in np.flatnonzero(~(spread > 0)):
        raise InputError(
            f"{name} {'xyz'[axis]} is constant ({x[0, axis]:g}) over {where}: no noise to "
            "analyse (a stuck sensor?)"
        )


def _still_stretch(rec: Recording, position: int | None) -> tuple[int, int, str]:
    """Sample range [start, stop) to analyse, and a phrase saying where it came from."""
    if position is not None:
        idx = np.flatnonzero(rec.position == position)
        if idx.size == 0:
            raise InputError(f"no samples labelled position {position}")
        return int(idx[0]), int(idx[-1]) + 1, f"position {position}"
    labels = rec.position
    whole = static_rows(rec) if not np.any(labels >= 0) else None
    if whole is not None and whole.size >= MIN_STILL_SECONDS * rec.sample_rate_hz:
        return int(whole[0]), int(whole[-1]) + 1, "the whole record (one static pose)"
    runs = label_runs(labels)  # ascending labels: the first of equal lengths wins, as before
    if runs:
        label, spans = max(runs.items(), key=lambda item: sum(b - a for a, b in item[1]))
        return spans[0][0], spans[-1][1], f"position {label} (longest)"
    accel = np.asarray(rec.accel, dtype=np.float64)
    finite = np.all(np.isfinite(accel), axis=1)
    filled = np.where(finite[:, None], accel, np.nanmedian(accel, axis=0))
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


def operator_units(sa: StaticAnalysis, g: float) -> dict[str, tuple[float, str]]:
    """Per sensor, the operator's unit of one count and its name (mg, °/s: the registry's)."""
    scales = Scales(sa.lsb["accel"], sa.lsb["gyro"], g)
    out = {}
    for name in sa.sensors:
        quantity = QUANTITIES[f"{name}.bias"]
        out[name] = (quantity.to_operator(scales), quantity.operator_unit)
    return out


def _site_g(rec: Recording) -> float:
    """Return the recording's g (m/s²), else standard gravity (1 mg = g/1000)."""
    g = rec.header.get("g")
    ok = isinstance(g, int | float) and not isinstance(g, bool) and np.isfinite(g) and g > 0
    return float(g) if ok else STANDARD_GRAVITY  # type: ignore[arg-type]


def _document(sa: StaticAnalysis, g: float = STANDARD_GRAVITY) -> dict[str, Any]:
    """Build the JSON: per sensor the ADEV, the terms with intervals, drift, best times.

    ``operator`` holds the terms in the operator's unit of the sensor (mg or °/s per count).
    """
    out: dict[str, Any] = {
        "schema": ALLAN_SCHEMA,
        "stretch": sa.where,
        "seconds": sa.seconds,
        **{k: v for k, v in static_document(sa).items() if k not in ("stretch", "seconds")},
    }
    for name, s in sa.sensors.items():
        terms, lsb = s.terms, sa.lsb[name]
        out[name] = {
            "units_si": "m/s²" if name == "accel" else "rad/s",
            "lsb": lsb,
            "taus_s": s.allan.taus_s,
            "adev_counts": s.allan.adev,
            "adev_sigma_counts": s.allan.adev_sigma,
            "white_noise_density_counts": terms.white_noise_density,
            "white_noise_density_si": _si(terms.white_noise_density, lsb),
            "bias_instability_counts": terms.bias_instability,
            "random_walk_counts_per_sqrt_s": terms.random_walk,
            "best_averaging_s": sa.choice.seconds,
            "best_averaging_s_per_axis": [float(v) for v in sa.choice.optima_s[name]],
            "operator": _operator_terms(sa, name, g),
        }
    return out


def _operator_terms(sa: StaticAnalysis, name: str, g: float) -> dict[str, Any]:
    """Return one sensor's noise terms in the operator's unit (``allan --json``)."""
    factor, unit = operator_units(sa, g)[name]
    terms = sa.sensors[name].terms
    return {
        "units": {
            "white_noise_density": f"{unit}/√Hz",
            "bias_instability": unit,
            "random_walk": f"{unit}/√s",
        },
        "white_noise_density": [float(v) * factor for v in terms.white_noise_density],
        "bias_instability": [float(v) * factor for v in terms.bias_instability],
        "random_walk": [float(v) * factor for v in terms.random_walk],
    }


def _report(sa: StaticAnalysis, g: float = STANDARD_GRAVITY) -> str:
    lines = [f"Allan deviation of {sa.where}, {sa.seconds:.1f} s"]
    units = operator_units(sa, g)
    for name, s in sa.sensors.items():
        terms, ci = s.terms, s.intervals
        factor, unit = units[name]
        lines.append(f"{name} (95 % intervals in brackets; in {unit} at the recording's LSB):")
        for axis, label in enumerate("xyz"):
            parts = (
                ("white", terms.white_noise_density, ci.white_noise_density, "/√Hz", ".4g"),
                ("bias instability", terms.bias_instability, ci.bias_instability, "", ".3g"),
                ("random walk", terms.random_walk, ci.random_walk, "/√s", ".3g"),
            )
            cells = [
                f"{what} {value[axis]:{fmt}} counts{per} [{_band(band[axis])} counts{per}] "
                f"({value[axis] * factor:.3g} {unit}{per})"
                for what, value, band, per, fmt in parts
            ]
            lines.append(
                f"  {label}: {', '.join(cells)}, best averaging "
                f"{best_averaging_text(sa, name, axis)}"
            )
        verdict = "bias_drift" if s.drift_named else "no bias_drift"
        if s.drift.p_value < 0.01 and not s.drift_named:
            verdict += " (trends beyond the Allan random-walk bound: not a wandering bias)"
        lines.append(
            f"  drift: slopes of {DRIFT_SEGMENTS} segments χ² = {s.drift.statistic:.1f} on "
            f"{s.drift.df} dof, p = {s.drift.p_value:.2g}: {verdict}"
        )
    c = sa.choice
    worst = max(float(np.max(v)) for v in c.loss.values())
    lines.append(
        f"recommended averaging time: {c.seconds:.0f} s for every axis (each within ×{worst:.2f} "
        f"of its own best ADEV; clipped to 15–120 s); limiting axis {c.limiting_axis}"
    )
    lines += [f"warning: {w}" for w in sa.warnings]
    return "\n".join(lines) + "\n"


def _band(pair: NDArray[np.float64]) -> str:
    return f"{pair[0]:.3g}–{pair[1]:.3g}"
