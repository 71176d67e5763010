"""`canimucal analyze`: what the base model gets wrong on measured data, and the gain.

load (``io.importers``) → group into positions (``analysis_session``) → base fit, candidate
tests, extension (``model.discrepancy``) → noise against the simulator's white noise (Allan
deviation) → the analysis JSON (docs/design.md §5), a truth JSON of the extended model and the
observed poses as a pose schedule, and a replay of the session through the simulator
(:mod:`canimucal.analysis.replay`).
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from canimucal.analysis.conditions import recording_conditions
from canimucal.analysis.data import (
    FAMILY_ALPHA,
    Ambiguity,
    DiscrepancyResult,
    ExtendedParams,
    Samples,
    SessionData,
)
from canimucal.analysis.discrepancy import analyse_discrepancy
from canimucal.analysis.repeats import unique_samples
from canimucal.analysis.session import session_from_recording
from canimucal.analysis.static_noise import static_rows
from canimucal.errors import InputError
from canimucal.io.grouping import detect_trials
from canimucal.io.recording import Recording
from canimucal.model.noise import (
    NoiseTerms,
    allan_deviation,
    best_averaging_time_s,
    choose_averaging,
    fit_noise,
)
from canimucal.model.positions import Plan, PlannedPosition
from canimucal.model.vocabulary.constants import OUTPUT_DATA_RATES_HZ
from canimucal.model.vocabulary.plans import CUSTOM
from canimucal.sim.truth import effects_document

log = logging.getLogger(__name__)

Array = NDArray[np.float64]

ANALYSIS_SCHEMA = "canimucal.analysis/1"
INT16_HEADROOM = 30000.0
"""Largest count a rescaled truth lets the data's largest value reach (INT16: 32767)."""


@dataclass(frozen=True)
class AllanCheck:
    """Allan deviation of the longest static window against the white noise it implies.

    ``adev`` and ``white`` are ``(len(taus_s), 3)`` counts; ``density`` the white-noise
    density (counts·√s) read at short τ; ``ratio_long`` measured over white at the longest
    τ (> 1: something beyond white noise, e.g. bias drift); ``best_averaging_s`` the fit's
    best averaging time; ``terms`` the fitted noise terms (:func:`.fit_noise`).
    """

    taus_s: Array
    adev: Array
    white: Array
    density: Array
    ratio_long: Array
    best_averaging_s: float
    terms: NoiseTerms | None = None


@dataclass(frozen=True)
class Analysis:
    """Everything `analyze` found on one recording."""

    recording: Recording
    session: SessionData
    result: DiscrepancyResult
    allan: Mapping[str, AllanCheck]
    g_source: str
    notes: tuple[str, ...] = ()
    """Data-quality lines about the input (held repeats: :mod:`.repeats`)."""


def analyze(
    recording: Recording,
    *,
    g: float | None = None,
    latitude_deg: float | None = None,
    tolerance_deg: float | None = None,
) -> Analysis:
    """Run the discrepancy loop as ``canimucal analyze`` does (g: flag, header, latitude).

    One long static recording has no calibration terms to test: :class:`InputError`
    pointing to ``canimucal.analyze_static`` (its noise terms and averaging times).
    """
    recording, held = unique_samples(recording)
    if not np.isfinite(recording.accel).any():
        raise InputError(
            f"{recording.source or 'recording'}: no accelerometer data: the discrepancy loop "
            "needs it; `canimucal analyze` reports what the gyro alone shows"
        )
    if static_rows(recording) is not None:
        raise InputError(
            f"{recording.source or 'recording'}: one static record (one pose): no calibration "
            "terms to test; use canimucal.analyze_static for its noise and averaging times"
        )
    cond = recording_conditions(recording, g)
    latitude = cond.latitude_rad
    if latitude_deg is not None:
        latitude = float(np.deg2rad(latitude_deg))
    return analyse_recording(
        recording,
        g=cond.g,
        g_source=cond.g_source,
        latitude=latitude,
        heading=cond.heading_rad,
        tolerance_deg=tolerance_deg,
        notes=() if held is None else (held.line(),),
    )


def analyse_recording(
    rec: Recording,
    *,
    g: float,
    g_source: str = "given",
    latitude: float | None = None,
    heading: float = 0.0,
    tolerance_deg: float | None = None,
    notes: tuple[str, ...] = (),
) -> Analysis:
    """Run the discrepancy loop on ``rec`` (``latitude``/``heading`` radians).

    ``tolerance_deg`` fixes the pose-setting scatter; None takes the recording's
    ``tolerance_deg`` header, else estimates it from the data. ``rec`` is taken as it is:
    held repeats are removed before (:func:`.repeats.unique_samples`, whose line goes in
    ``notes``). Several trials (the ``trial`` column, else found as ``solve`` finds them:
    :func:`~canimucal.io.grouping.detect_trials`, its line in the notes) give each trial its
    own biases in the base model and every candidate's (:mod:`.base_fit`), with known angles
    or without (the |f| = g fit: docs/design.md §6 *Trials*).
    """
    if bool((rec.position >= 0).any()):  # several trials in one file, no trial column
        rec, found = detect_trials(rec)
        notes += () if found is None else (found,)
    session = session_from_recording(
        rec, g=g, latitude=latitude, heading=heading, tolerance_deg=tolerance_deg
    )
    log.info(
        "%d positions (%s)", len(session.averages), "known" if session.known_positions else "scalar"
    )
    result = analyse_discrepancy(session)
    longest = max(session.windows, key=lambda w: w.t_s.size)
    allan = {"accel": _allan(rec, longest.accel)}
    if session.has_gyro and longest.gyro is not None:
        allan["gyro"] = _allan(rec, longest.gyro)
    return Analysis(rec, session, result, allan, g_source, notes)


def _allan(rec: Recording, x: Samples) -> AllanCheck:
    """Allan deviation of the samples of the longest position (settling trimmed).

    ``allan_deviation`` converts a float32 window to float64 before its sums.
    """
    fs = rec.sample_rate_hz
    res = allan_deviation(x, fs)
    terms = fit_noise(res)
    density = np.sqrt(res.adev[0] ** 2 * res.taus_s[0])  # white: σ(τ) = N/√τ
    white = density[None, :] / np.sqrt(res.taus_s)[:, None]
    good = np.flatnonzero(res.edf >= 10.0)
    last = good[-1] if good.size else res.taus_s.size - 1
    return AllanCheck(
        res.taus_s, res.adev, white, density, res.adev[last] / white[last],
        best_averaging_time_s(terms, clip=(0.1, 1e4)), terms,
    )  # fmt: skip


def _sensor_block(a: Analysis, sensor: str) -> dict[str, Any]:
    score = a.result.scores.get(sensor)
    if score is None:
        return {}
    return {
        "base_model": {
            "terms": list(score.base_terms),
            "rms": score.base_rms,
            "cv_rms": score.base_cv_rms,
        },
        "extended_model": {
            "terms": list(score.extended_terms),
            "rms": score.extended_rms,
            "cv_rms": score.extended_cv_rms,
        },
        "gain": {
            "rms_ratio": score.rms_ratio,
            "cv_rms_ratio": score.cv_rms_ratio,
            "cv_rms_ratio_ci95": list(score.cv_rms_ratio_ci95),
            "claimed": score.claimed,
        },
    }


def input_referred_white(a: Analysis, sensor: str) -> list[float]:
    """White-noise density per axis in SI/√Hz (counts·√s divided by the scale)."""
    check = a.allan.get(sensor)
    if check is None:
        return []
    p = a.result.params
    if sensor == "accel":
        scale = np.abs(np.diag(p.K))
    else:
        scale = np.full(3, 1.0 / abs(a.session.gyro_lsb))
    return [float(v) for v in check.density / scale]


def analysis_document(a: Analysis) -> dict[str, Any]:
    """Build the analysis JSON of docs/design.md §5."""
    findings = [
        {
            "effect": f.effect,
            "sensor": f.sensor,
            "size": f.size,
            **({} if f.sigma is None else {"sigma": f.sigma}),
            "units": f.units,
            "p_value": f.p_value,
            "evidence": f.evidence,
        }
        for f in a.result.findings
    ]
    untestable = [{"effect": k, "reason": v} for k, v in a.result.untestable.items()]
    best = max((c.best_averaging_s for c in a.allan.values()), default=float("nan"))
    noise: dict[str, Any] = {
        "accel_white": input_referred_white(a, "accel"),
        "gyro_white": input_referred_white(a, "gyro"),
        "best_averaging_s": best,
    }
    noise["warnings"] = [*a.notes, *a.result.warnings]
    terms = {k: c.terms for k, c in a.allan.items() if c.terms is not None}
    if terms:
        choice = choose_averaging(terms)
        noise["best_averaging_s_per_axis"] = {k: v.tolist() for k, v in choice.optima_s.items()}
        # docs/design.md §5: the largest of the axes' optima, on the same clipped scale as the
        # per-axis values (a white axis has no minimum inside the data: the clip's top)
        noise["best_averaging_s"] = max(float(np.max(v)) for v in choice.optima_s.values())
        noise["limiting_axis"] = choice.limiting_axis
        noise["averaging_s"] = choice.seconds
    noise["settling"] = {
        k: {"found": f.found, "tau_s": _finite(f.tau_s), "ci95": [_finite(x) for x in f.tau_ci95_s],
            "trimmed_s": [float(x) for x in f.trim_s], "p_value": f.p_value}
        for k, f in a.session.settling.items()
    }  # fmt: skip
    summary = a.result.noise
    if summary is not None:
        est = summary.pose_scatter
        noise["pose_scatter_deg"] = {
            "value": est.value_deg,
            "ci95": list(est.ci95_deg),
            "source": est.source,
        }
    earth = a.result.earth_rate_horizontal
    if earth is not None:
        noise["earth_rate_horizontal_counts"] = {"value": earth.value, "ci95": list(earth.ci95)}
    return {
        "schema": ANALYSIS_SCHEMA,
        "sensors": {s: _sensor_block(a, s) for s in ("accel", "gyro") if s in a.result.scores},
        "findings": findings,
        "untestable": untestable,
        "ambiguous": [_ambiguity(x) for x in a.result.ambiguous],
        "base_fit": base_fit_summary(a.result),
        "noise": noise,
    }


def base_fit_summary(result: DiscrepancyResult) -> dict[str, Any]:
    """Return the base model's lack of fit and, when nothing is named, the line saying so.

    ``summary`` is None when a cause is named; else "no cause named; the base model fits"
    or "… is rejected, χ²/dof N: the misfit is not one of the candidates" (p below the
    family-wise level), the text's line and the JSON's ``base_fit.summary`` alike.
    """
    chi2, dof, p = result.lack_of_fit
    ratio = chi2 / max(dof, 1)
    rejected = bool(np.isfinite(p) and p < FAMILY_ALPHA)
    summary = None
    if not result.findings:
        if not rejected:
            summary = f"no cause named; the base model fits (χ²/dof {ratio:.2f}, p = {p:.2g})"
        elif result.ambiguous:
            summary = (
                f"no cause named; the base model is rejected, χ²/dof {ratio:.4g}: the "
                "candidates that could explain it cannot be told apart (ambiguous below)"
            )
        else:
            summary = (
                f"no cause named; the base model is rejected, χ²/dof {ratio:.4g}: the misfit "
                "is not one of the candidates"
            )
    out: dict[str, Any] = {
        "chi2": chi2,
        "dof": dof,
        "p_value": _finite(p),
        "rejected": rejected,
        "summary": summary,
    }
    if result.trials:
        out["trials"] = result.trials
    return out


def _finite(x: float) -> float | None:
    return float(x) if np.isfinite(x) else None


def _ambiguity(x: Ambiguity) -> dict[str, Any]:
    """Write one ``ambiguous`` entry of the analysis JSON (docs/design.md §5)."""
    out: dict[str, Any] = {
        "sensor": x.sensor,
        "candidates": list(x.candidates),
        "correlation": x.correlation,
    }
    sep = x.separating
    if sep is not None:
        out["separating_position"] = {
            "alpha_deg": sep.alpha_deg,
            "beta_deg": sep.beta_deg,
            "psi_deg": sep.psi_deg,
            "correlation_after": sep.correlation_after,
            "noncentrality_after": sep.noncentrality,
            "noncentrality_before": sep.before,
            "tilt_limit_deg": sep.tilt_limit_deg,
        }
    return out


def extended_truth(a: Analysis) -> dict[str, Any]:
    """Build a truth JSON document of the extended model (docs/design.md §5), for `sim --truth`."""
    p, s, rec = a.result.params, a.session, a.recording
    temps, t0 = _temperature_profile(a)
    temp0 = temps[0][1] if temps else 25.0
    mean_t = float(np.mean([t for _, t in temps])) if temps else temp0
    accel_bias = p.accel_bias + p.accel_temp_coeff * (temp0 - mean_t)
    rate = min(OUTPUT_DATA_RATES_HZ, key=lambda r: abs(r - rec.sample_rate_hz))
    ka, kg = _count_scale(rec.accel), _count_scale(rec.gyro)
    doc: dict[str, Any] = {
        "schema": "canimucal.truth/1",
        "sample_rate_hz": rate,
        "g": s.g,
        "heading_deg": float(np.rad2deg(s.heading)),
        "base_tilt_deg": {
            "alpha0": float(np.rad2deg(p.alpha0)),
            "beta0": float(np.rad2deg(p.beta0)),
        },
        "accel": {
            "nominal_lsb": s.accel_lsb / ka,
            "quantization": _step(rec.accel, ka),
            "bias": (ka * accel_bias).tolist(),
            "K": (ka * p.K).tolist(),
            "quadratic": (ka * p.quadratic).tolist(),
            "temp_coeff": (ka * p.accel_temp_coeff).tolist(),
            "random_walk": (ka * p.accel_random_walk).tolist(),
            "noise_density": input_referred_white(a, "accel"),
        },
    }
    if s.latitude is not None:
        doc["latitude_deg"] = float(np.rad2deg(s.latitude))
    if p.gyro_bias is not None:
        gyro_bias = p.gyro_bias + p.gyro_temp_coeff * (temp0 - mean_t)
        doc["gyro"] = {
            "nominal_lsb": s.gyro_lsb / kg,
            "quantization": _step(rec.gyro, kg),
            "bias": (kg * gyro_bias).tolist(),
            "G": (kg * p.G).tolist(),
            "temp_coeff": (kg * p.gyro_temp_coeff).tolist(),
            "random_walk": (kg * p.gyro_random_walk).tolist(),
            "noise_density": input_referred_white(a, "gyro"),
        }
    if temps:
        doc["temperature"] = {"profile": [[t - t0, c] for t, c in temps]}
    if p.effects:  # the simulator applies these through their columns (counts of its unit)
        scale = {"accel": ka, "gyro": kg}
        doc["effects"] = effects_document(
            {key: scale[key.split(".", 1)[0]] * np.asarray(v) for key, v in p.effects.items()}
        )
    if p.trial_accel_bias is not None:  # docs/design.md §6 Trials: what the model fitted
        doc["trials"] = _trials_document(p, (ka, kg), temp0 - mean_t)
    return doc


def _trials_document(
    p: ExtendedParams, scales: tuple[float, float], dtemp: float
) -> list[dict[str, Any]]:
    """Each trial's biases as the truth JSON's ``trials`` (counts of the simulated unit).

    At the first position's temperature, as ``accel.bias``/``gyro.bias`` are (their mean).
    """
    assert p.trial_accel_bias is not None
    ka, kg = scales
    out = []
    for k, trial in enumerate(p.trials):
        entry: dict[str, Any] = {
            "trial": int(trial),
            "accel_bias": (ka * (p.trial_accel_bias[k] + p.accel_temp_coeff * dtemp)).tolist(),
        }
        if p.trial_gyro_bias is not None:
            entry["gyro_bias"] = (kg * (p.trial_gyro_bias[k] + p.gyro_temp_coeff * dtemp)).tolist()
        out.append(entry)
    return out


FACT_CHUNK_ROWS = 1 << 20
"""Rows a whole-column check reads at once (no temporaries the size of the recording)."""


@dataclass(frozen=True)
class _CountFacts:
    """Of a column's finite samples: any at all, all whole counts, the largest |x|."""

    any_finite: bool
    whole: bool
    largest: float


def _count_facts(samples: Samples) -> _CountFacts:
    """Read ``samples`` in chunks of :data:`FACT_CHUNK_ROWS` rows (the same answer as at once)."""
    any_finite, whole, largest = False, True, 0.0
    for start in range(0, samples.shape[0], FACT_CHUNK_ROWS):
        chunk = samples[start : start + FACT_CHUNK_ROWS]
        finite = chunk[np.isfinite(chunk)]
        if finite.size:
            any_finite = True
            whole = whole and bool(np.all(finite == np.round(finite)))
            largest = max(largest, float(np.abs(finite).max()))
    return _CountFacts(any_finite, any_finite and whole, largest)


def _whole_counts(samples: Samples) -> bool:
    return _count_facts(samples).whole


def _step(samples: Samples, scale: float = 1.0) -> float:
    """1 (INT16 rounding) when the data are whole counts or rescaled to counts, else 0."""
    return 1.0 if scale != 1.0 or _whole_counts(samples) else 0.0


def _count_scale(samples: Samples) -> float:
    """Return counts of the simulated unit per unit of the data (1 for whole counts).

    Data in physical units (an importer's ``accel_lsb: 1``, floats) cannot travel as INT16
    counts of that size: a 1 m/s² count would round the signal away. The truth then takes
    the finest power-of-two count whose INT16 range still holds the data's largest value
    (:data:`INT16_HEADROOM`); the input-referred noise densities are unchanged.
    """
    facts = _count_facts(samples)
    if facts.whole or not facts.any_finite or facts.largest == 0.0:
        return 1.0
    return float(2.0 ** np.floor(np.log2(INT16_HEADROOM / facts.largest)))


def _temperature_profile(a: Analysis) -> tuple[list[tuple[float, float]], float]:
    """(time, °C) of each position's middle, and the recording's start time."""
    t0 = float(a.recording.t[0])
    out = []
    for w in a.session.windows:
        if w.temp_c is None or not np.any(np.isfinite(w.temp_c)):
            return [], t0
        temp = np.asarray(w.temp_c, dtype=np.float64)  # before summing (float32 windows)
        out.append((float(np.mean(w.t_s)), float(np.nanmean(temp))))
    return out, t0


def observed_poses(a: Analysis) -> Plan | None:
    """Return the observed poses and durations as a pose schedule (None: orientations unknown).

    Each pose's tolerance is the pose-setting scatter the analysis used.
    """
    if not a.session.known_positions:
        return None
    positions = []
    noise = a.result.noise
    for avg, w in zip(a.session.averages, a.session.windows, strict=True):
        p = avg.pose
        seconds = max(float(w.t_s[-1] - w.t_s[0]), 1.0)
        alpha, beta, psi = (_wrap(x) for x in (p.alpha, p.beta, p.psi))
        tol = p.tolerance if noise is None else noise.pose_scatter.value
        positions.append(PlannedPosition(alpha, beta, psi, tol, seconds))
    return Plan(CUSTOM, tuple(positions))


def _wrap(angle: float) -> float:
    """Wrap an angle into (−π, π] (the pose schedule's range, ±180°)."""
    return float(-((np.pi - angle) % (2.0 * np.pi)) + np.pi)
