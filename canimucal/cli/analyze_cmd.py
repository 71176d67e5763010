"""`canimucal analyze`: model discrepancy on measured data (docs/design.md §5, §6)."""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from canimucal.analysis.base_fit import EARTH_RATE_NAMES, EARTH_RATE_VERTICAL
from canimucal.analysis.conditions import recording_conditions
from canimucal.analysis.gyro_only import analyse_gyro_only, gyro_document, gyro_report, has_accel
from canimucal.analysis.reference import Reference, reference_for
from canimucal.analysis.repeats import unique_samples
from canimucal.analysis.replay import ReplayRow, replay, replay_ratios
from canimucal.analysis.report import (
    ANALYSIS_SCHEMA,
    Analysis,
    analyse_recording,
    analysis_document,
    base_fit_summary,
    extended_truth,
    observed_poses,
)
from canimucal.analysis.session_model import ModelChoice
from canimucal.analysis.solve import site_of
from canimucal.analysis.static_noise import (
    analyse_static,
    recording_lsb,
    static_document,
    static_findings,
    static_report,
    static_rows,
)
from canimucal.cli.analyze_plots import check_plot_targets, write_plots
from canimucal.cli.input_options import INPUT_HELP, SECOND_HELP, add_input_options, read_input
from canimucal.cli.output import add_json_option, check_outputs, emit
from canimucal.errors import InputError
from canimucal.io.atomic import refuse_existing
from canimucal.io.plans import plan_from_document, plan_to_dict, write_plan
from canimucal.io.recording import Recording
from canimucal.io.truth import write_truth
from canimucal.model.positions import Plan
from canimucal.model.vocabulary.effects import EFFECTS
from canimucal.model.vocabulary.units import (
    QUANTITIES,
    SCALE_FAMILIES,
    Scales,
    family_of,
    operator_value,
    with_unit,
)


def add_subparser(subparsers: Any) -> None:
    """Register ``analyze``."""
    p = subparsers.add_parser(
        "analyze",
        help="show what the base model gets wrong on measured data, name the cause",
        description="Fit the base model (bias + diagonal scale + white noise) to measured "
        "data, show where it fails, test each candidate effect (nested-model tests, Holm "
        "at 1 %, leave-one-position-out cross-validation), extend the model and report "
        "the gain. Candidate effects: "
        + "; ".join(f"{e.name}, {e.wording}" for e in EFFECTS.values())
        + ".",
    )
    p.add_argument("input", help=INPUT_HELP)
    p.add_argument("second", nargs="?", help=SECOND_HELP)
    add_input_options(p)
    p.add_argument("--g", type=float, help="local gravity, m/s² (default: header, latitude)")
    p.add_argument("--latitude-deg", type=float, help="latitude (Earth rate in the gyro model)")
    p.add_argument(
        "--tolerance-deg",
        type=float,
        default=None,
        help="angle-setting 1σ of each position (default: the recording's tolerance_deg "
        "header, else estimated from the data)",
    )
    p.add_argument("--truth-out", metavar="F", help="write the extended model as truth JSON")
    p.add_argument("--poses-out", metavar="F", help="write the observed poses (pose schedule)")
    p.add_argument("--plots", metavar="DIR", help="write PNG plots (needs matplotlib)")
    add_json_option(p)
    p.set_defaults(run=run)


def _check_files(args: argparse.Namespace) -> None:
    check_outputs(args)
    for target in (args.truth_out, args.poses_out):
        if target:
            refuse_existing(Path(target), overwrite=bool(args.overwrite))
    if args.plots:
        check_plot_targets(Path(args.plots), overwrite=bool(args.overwrite))
    if args.g is not None and not (np.isfinite(args.g) and args.g > 0):
        raise InputError(f"--g must be a positive number, got {args.g}")
    if args.latitude_deg is not None and not abs(args.latitude_deg) <= 90.0:
        raise InputError(f"--latitude-deg must be within [-90, 90], got {args.latitude_deg}")


def _checked_poses(analysis: Analysis, target: str | None) -> Plan | None:
    """Check the pose schedule to write before any output is written (None: not asked)."""
    if not target:
        return None
    plan = observed_poses(analysis)
    if plan is None:
        raise InputError("--poses-out needs positions with angles; this input has none")
    try:
        plan_from_document(plan_to_dict(plan), target)
    except InputError as exc:
        raise InputError(
            f"--poses-out: the observed poses do not fit the pose-schedule format ({exc})"
        ) from None
    return plan


def run(args: argparse.Namespace) -> int:
    """Analyse and report."""
    _check_files(args)
    rec, held = unique_samples(read_input(args, args.input, args.second))
    notes = () if held is None else (held.line(),)
    rows = static_rows(rec)
    if rows is not None:
        return _run_static(args, rec, rows, notes)
    if not has_accel(rec):
        return _run_gyro_only(args, rec, notes)
    reference = reference_for(args.input)
    g_flag = args.g if args.g is not None else (reference.g if reference else None)
    cond = recording_conditions(rec, g_flag)
    g_source = "data README" if args.g is None and reference else cond.g_source
    latitude = cond.latitude_rad
    if args.latitude_deg is not None:
        latitude = float(np.deg2rad(args.latitude_deg))
    analysis = analyse_recording(
        rec,
        g=cond.g,
        g_source=g_source,
        latitude=latitude,
        heading=cond.heading_rad,
        tolerance_deg=args.tolerance_deg,
        notes=notes,
    )
    plan = _checked_poses(analysis, args.poses_out)
    replayed = replay(analysis)
    document = analysis_document(analysis)
    ratios = replay_ratios(replayed)
    if ratios is not None:
        document["noise"]["replay"] = ratios
    emit(args, document, report_text(analysis, reference, replayed))
    if args.truth_out:
        write_truth(args.truth_out, extended_truth(analysis), overwrite=args.overwrite)
    if args.poses_out and plan is not None:
        write_plan(args.poses_out, plan, overwrite=args.overwrite)
    if args.plots:
        write_plots(analysis, Path(args.plots), overwrite=bool(args.overwrite))
    return 0


def _run_static(
    args: argparse.Namespace, rec: Recording, rows: NDArray[np.intp], notes: tuple[str, ...]
) -> int:
    """One static pose: noise terms, drift and averaging times, no calibration terms."""
    for flag, value in (("--truth-out", args.truth_out), ("--poses-out", args.poses_out),
                        ("--plots", args.plots)):  # fmt: skip
        if value:
            raise InputError(
                f"{flag}: {args.input} is one static record (one pose): no model to write"
            )
    sa = analyse_static(rec, rows, recording_lsb(rec))
    sa = replace(sa, warnings=(*notes, *sa.warnings))
    noise = static_document(sa)
    document = {
        "schema": ANALYSIS_SCHEMA,
        "sensors": {},
        "findings": static_findings(sa),
        "untestable": [
            {"effect": e.name, "reason": STATIC_REASON} for e in EFFECTS.values() if not e.one_pose
        ],
        "ambiguous": [],
        "noise": noise,
    }
    text = static_report(sa) + f"Calibration terms: untestable ({STATIC_REASON}).\n"
    emit(args, document, text)
    return 0


STATIC_REASON = "one static pose: calibration terms need several positions"


def _run_gyro_only(args: argparse.Namespace, rec: Recording, notes: tuple[str, ...]) -> int:
    """No accelerometer data: what the gyro alone shows (:mod:`canimucal.analysis.gyro_only`)."""
    for flag, value in (("--truth-out", args.truth_out), ("--poses-out", args.poses_out),
                        ("--plots", args.plots)):  # fmt: skip
        if value:
            raise InputError(
                f"{flag}: {args.input} has no accelerometer data: the extended model, the "
                "observed poses and the plots need it"
            )
    site, _source = site_of(rec, ModelChoice(g=args.g, latitude_deg=args.latitude_deg))
    analysis = analyse_gyro_only(rec, site)
    emit(args, gyro_document(analysis, notes), gyro_report(analysis, notes))
    return 0


def report_text(a: Analysis, reference: Reference | None, replayed: list[ReplayRow] | None) -> str:
    """Build the readable report: estimates, what the base model gets wrong, findings, gain."""
    r = a.result
    n = len(a.session.averages)
    kind = "known angles: joint model" if a.session.known_positions else "no angles: |f| = g fit"
    if r.trials:
        kind += f", {r.trials} trials: one bias each, K shared"
    lines = [
        f"{n} static positions ({kind}); g = {a.session.g:.5f} m/s² ({a.g_source})",
        *(f"note: {note}" for note in a.notes),
        "",
        *_estimates(a, reference),
        "",
        "What the base model (bias + diagonal scale + white noise) gets wrong (residual of "
        "each position's mean, in mg and °/s at the recording's LSB):",
        *_residual_table(a),
        _lack_of_fit(a),
        *_allan_lines(a),
        "",
        "Findings (Holm-adjusted p, family-wise 1 %):",
    ]
    lines += [f"  {f.effect} ({f.sensor}): {f.evidence}; p = {f.p_value:.2g}" for f in r.findings]
    summary = base_fit_summary(r)["summary"]
    if summary is not None:
        lines.append(f"  {summary}")
    for x in r.ambiguous:
        lines.append(
            f"  ambiguous ({x.sensor}): {x.candidates[0]} or {x.candidates[1]} (estimates "
            f"correlated {x.correlation:.3f} in the model holding both; neither is named)"
        )
        sep = x.separating
        if sep is not None:
            lines.append(
                f"    to separate them add one position: alpha {sep.alpha_deg:g}°, beta "
                f"{sep.beta_deg:g}°, psi {sep.psi_deg:g}° (tilts within ±{sep.tilt_limit_deg:g}°; "
                f"correlation {x.correlation:.3f} → {sep.correlation_after:.3f}, head-to-head "
                f"non-centrality {sep.before:.1f} → {sep.noncentrality:.1f})"
            )
    lines += [f"  untestable {k}: {v}" for k, v in r.untestable.items()]
    lines += [
        "",
        "Gain (rms of the per-position means, before → after; cv = refit with each position "
        "left out, term selection included):",
    ]
    for sensor, sc in r.scores.items():
        unit = "m/s²" if sensor == "accel" else _gyro_unit(a)
        low, high = sc.cv_rms_ratio_ci95
        verdict = "gain claimed" if sc.claimed else "no gain claimed"
        lines.append(
            f"  {sensor}: rms {sc.base_rms:.4g} → {sc.extended_rms:.4g} {unit} "
            f"(×{sc.rms_ratio:.2f}); cv_rms {sc.base_cv_rms:.4g} → {sc.extended_cv_rms:.4g} "
            f"(×{sc.cv_rms_ratio:.2f}, 95 % {low:.2f}–{high:.2f}; {verdict}); "
            f"terms {', '.join(sc.extended_terms)}"
        )
    lines += [f"warning: {w}" for w in r.warnings]
    lines += _replay_lines(replayed)
    return "\n".join(lines) + "\n"


def _gyro_unit(a: Analysis) -> str:
    return "rad/s" if "gyro_lsb" in a.recording.header else "counts"


def _estimates(a: Analysis, ref: Reference | None) -> list[str]:
    vals, sigs = a.result.base_values, a.result.base_sigmas
    head = "Base-model estimates" + (f" beside {ref.name}:" if ref else ":")
    out = [head]
    rows: list[tuple[str, str, float | None]] = []
    units = {family: QUANTITIES[family].unit for family in ("accel.bias", "accel.K", "gyro.bias")}
    for i in range(3):
        rows.append(
            (f"accel.bias[{i}]", units["accel.bias"], ref.accel_offsets[i] if ref else None)
        )
    for i in range(3):
        rows.append((f"accel.K[{i}][{i}]", units["accel.K"], ref.accel_scales[i] if ref else None))
    for i in range(3):
        rows.append((f"gyro.bias[{i}]", units["gyro.bias"], ref.gyro_offsets[i] if ref else None))
    # the Earth rate fitted as a nuisance (no latitude or orientation), at the nominal scale
    earth = "rad/s" if a.session.gyro_lsb_known else "counts"
    rows += [(name, earth, None) for name in (*EARTH_RATE_NAMES, EARTH_RATE_VERTICAL)]
    scales = _scales(a)
    for name, unit, factory in rows:
        if name not in vals:
            continue
        v, s = vals[name], sigs[name]
        text = f"  {name:<16} {v:12.3f} ± {s:.3g} {unit}"
        if name.startswith("gyro.earth_rate"):
            text = f"  {name:<24} {v:12.3g} ± {s:.3g} {unit}"
        text += _operator_text(name, unit, v, s, scales, a.session.gyro_lsb_known)
        if factory is not None:
            text += f"   factory {factory:9.1f}   difference {(v - factory) / s:+.1f}σ"
        out.append(text)
    if ref:
        out.append(
            "  gyro scale factory diag("
            + ", ".join(f"{x:.0f}" for x in ref.gyro_scales)
            + f") {QUANTITIES['gyro.S'].unit}: not estimable from static data"
        )
    return out


def _scales(a: Analysis) -> Scales:
    """Return the nominal LSBs and g the analysis ran at (the operator's units' scales)."""
    return Scales(a.session.accel_lsb, a.session.gyro_lsb, a.session.g)


def _operator_text(
    name: str, unit: str, value: float, sigma: float, scales: Scales, gyro_known: bool
) -> str:
    """``  (−6.25 ± 0.43 mg)``: an estimate in the operator's unit ("" when there is none)."""
    if name.startswith("gyro.earth_rate"):
        if unit != "rad/s":
            return ""
        deg = float(np.rad2deg(1.0))
        return f"  ({with_unit(value * deg, sigma * deg, '°/s', digits=4)})"
    family = family_of(name)
    if family.startswith("gyro") and not gyro_known:
        return ""  # counts of an unknown LSB: no °/s to give
    diagonal = family in SCALE_FAMILIES
    shown = operator_value(family, value, scales, diagonal=diagonal)
    spread = abs(operator_value(family, sigma, scales))
    return f"  ({with_unit(shown, spread, QUANTITIES[family].operator_unit, digits=4)})"


def residual_units(label: str, scales: Scales, gyro_known: bool) -> tuple[str, float, str]:
    """Return a residual column's head, the factor to the operator's unit and that unit.

    Accelerometer residuals in counts (the joint fit) or m/s² (the |f| = g fit) become mg;
    gyro residuals in counts become °/s, or stay counts when the file gives no gyro LSB.
    """
    if label.startswith("|f|"):
        return "|f| − g", 1000.0 / scales.g, "mg"
    sensor = label.split(".", 1)[0]
    if sensor == "gyro" and not gyro_known:
        return label, 1.0, "counts"
    quantity = QUANTITIES[f"{sensor}.bias"]
    return label, quantity.to_operator(scales), quantity.operator_unit


def _residual_table(a: Analysis) -> list[str]:
    """Tabulate the base fit's residual of each position and channel, each with its unit.

    With trials (docs/design.md §6 *Trials*) a first column names each position's trial:
    a label recurs in every trial, and its positions are the trials' own.
    """
    r = a.result
    columns = [
        residual_units(lbl, _scales(a), a.session.gyro_lsb_known) for lbl in r.residual_labels
    ]
    trials = [x.trial for x in a.session.averages] if r.trials else None
    head = (
        ("  trial" if trials else "")
        + "  pos  "
        + "  ".join(f"{name:>16}" for name, _, _ in columns)
    )
    out = [head]
    for k, row in enumerate(r.residuals):
        cells = [
            f"{v * factor:+.4g} {unit}" for v, (_, factor, unit) in zip(row, columns, strict=True)
        ]
        lead = f"  {_trial_cell(trials[k]):>5}" if trials else ""
        out.append(f"{lead}  {k:3d}  " + "  ".join(f"{cell:>16}" for cell in cells))
    return out


def _trial_cell(trial: int | None) -> str:
    """Show a trial as the residual table does (``-`` for rows of no trial)."""
    return "-" if trial is None or trial < 0 else str(trial)


def _lack_of_fit(a: Analysis) -> str:
    chi2, dof, p = a.result.lack_of_fit
    noise = a.result.noise
    against = "the noise predicted from the scatter inside each position"
    if noise is not None and noise.pose_scatter.source != "none":
        est = noise.pose_scatter
        low, high = est.ci95_deg
        how = {
            "estimated": f"estimated from the data (REML, 95 % {low:.3g}–{high:.3g}°)",
            "header": "from the recording's tolerance_deg header",
            "flag": "from --tolerance-deg",
            "plan": "from the plan",
        }.get(est.source, est.source)
        against += f" and a pose-setting scatter of {est.value_deg:.3g}° {how}"
    text = (
        f"  lack of fit: χ² = {chi2:.1f} on {dof} dof (χ²/dof = {chi2 / max(dof, 1):.2f}, "
        f"p = {p:.2g}) against {against}"
    )
    if noise is not None:
        text += (
            f"\n  extended model under the same noise model: χ²/dof = "
            f"{noise.chi2 / max(noise.dof, 1):.2f} on {noise.dof} dof"
        )
    return text


def _allan_lines(a: Analysis) -> list[str]:
    out = []
    for sensor, c in a.allan.items():
        out.append(
            f"  Allan deviation ({sensor}, longest position, τ up to {c.taus_s[-1]:.3g} s): "
            f"measured / white-noise prediction at long τ = "
            + ", ".join(f"{x:.2f}" for x in c.ratio_long)
            + " (x, y, z); white density "
            + ", ".join(f"{x:.3g}" for x in c.density)
            + " counts·√s"
        )
    return out


def _replay_lines(rows: list[ReplayRow] | None) -> list[str]:
    if rows is None:
        return ["", "Replay: orientations unknown, the session cannot be replayed as poses."]
    out = ["", "Replay through the simulator (base fit on each; mean of 3 seeds):"]
    out += [
        f"  {r.label:<24} accel rms {r.accel_rms:.4g} m/s², χ²/dof {r.chi2_per_dof:.2f}"
        for r in rows
    ]
    ratios = replay_ratios(rows)
    if ratios is not None:
        low, high = ratios["rms_ratio_ci95"]
        verdict = "within" if low <= 1.0 <= high else "OUTSIDE"
        out.append(
            f"  extended replay / measured: rms ×{ratios['rms_ratio']:.2f} (one replay's 95 % "
            f"{low:.2f}–{high:.2f}: measurement {verdict} it), χ²/dof ×{ratios['chi2_ratio']:.2f}"
        )
    return out
