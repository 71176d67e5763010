"""`canimucal solve`: a recording in, the calibration JSON of DESIGN §5 out."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

import numpy as np

from canimucal.analysis.calibrate import SiteConditions, Solution, solve_positions, solve_scalar
from canimucal.analysis.pose_scatter import fit_scatter, header_tolerance_deg
from canimucal.cli.conditions import recording_conditions
from canimucal.cli.output import add_json_option, check_outputs, emit
from canimucal.cli.spec_options import add_model_options, spec_from_args
from canimucal.errors import InputError, ModelError
from canimucal.io.calibration import Device, RecordingRef, calibration_to_dict, sha256_of
from canimucal.io.grouping import has_angles, position_averages
from canimucal.io.recording import Recording, read_recording
from canimucal.model.layout import JointSpec
from canimucal.model.positions import Pose, PositionAverage, average_position
from canimucal.model.static import detect_static_intervals


def add_subparser(subparsers: Any) -> None:
    """Register ``solve``."""
    p = subparsers.add_parser(
        "solve",
        help="solve a recording for the calibration parameters",
        description="Solve a recording: joint least squares when the positions carry "
        "angles, the scalar |f| = g fit otherwise. Prints every parameter with its σ; "
        "--json writes the calibration JSON.",
    )
    p.add_argument("recording", help="recording CSV (canimucal.recording/1)")
    add_model_options(p, default_tilt=False)
    p.add_argument("--g", type=float, help="local gravity, m/s² (default: header, latitude)")
    add_json_option(p)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    """Solve and report."""
    check_outputs(args)
    rec = read_recording(args.recording)
    cond = recording_conditions(rec, args.g)
    latitude = cond.latitude_rad
    if args.latitude_deg is not None:
        latitude = float(np.deg2rad(args.latitude_deg))
    site = SiteConditions(
        g=cond.g,
        latitude=latitude,
        heading=cond.heading_rad,
        height_m=cond.height_m,
        accel_lsb=cond.accel_lsb,
        gyro_lsb=cond.gyro_lsb,
        temp_c=_mean_temp(rec),
    )
    device = Device(serial=_serial(rec), node_id=_node_id(rec))
    ref = RecordingRef(file=Path(args.recording).name, sha256=sha256_of(args.recording))
    if has_angles(rec):
        averages = position_averages(rec, tolerance_deg=header_tolerance_deg(rec) or 0.0)
        has_gyro = all(a.mean_gyro is not None for a in averages)
        spec = spec_from_args(args, has_gyro=has_gyro)
        averages, note = _with_pose_scatter(rec, averages, spec, site)
        solution = solve_positions(averages, spec, site, device, recording=ref)
        if note:
            print(f"note: {note}", file=sys.stderr)
        if solution.joint is not None and solution.joint.dof < MIN_DOF:
            print(
                f"warning: only {solution.joint.dof} residual degrees of freedom: the σ "
                "and the fit's χ² rest on very few residuals (add positions)",
                file=sys.stderr,
            )
    else:
        averages = _unlabelled_averages(rec)
        solution = solve_scalar(averages, site, device, full=args.model == "full", recording=ref)
    for warning in solution.warnings:
        print(f"warning: {warning}", file=sys.stderr)
    emit(args, calibration_to_dict(solution.record), solution_report(solution, cond.g_source))
    return 0


MIN_DOF = 10
"""Below this many residual degrees of freedom `solve` warns (DESIGN §9)."""


def _with_pose_scatter(
    rec: Recording, averages: list[PositionAverage], spec: JointSpec, site: SiteConditions
) -> tuple[list[PositionAverage], str | None]:
    """Give the poses the header's scatter when it has one, else the one the data show."""
    if header_tolerance_deg(rec) is not None:
        return averages, None
    try:
        out, est = fit_scatter(
            averages, spec, g=site.g, latitude=site.latitude, heading=site.heading,
            accel_lsb=site.accel_lsb, gyro_lsb=site.gyro_lsb,
        )  # fmt: skip
    except ModelError:
        return averages, None  # the solve itself says what is wrong with these positions
    low, high = est.ci95_deg
    if est.source == "assumed":
        how = "assumed: too few residuals to estimate it"
    else:
        how = f"estimated from the data (REML, 95 % {low:.3g}–{high:.3g}°)"
    return out, f"pose-setting scatter {est.value_deg:.3g}° {how}; no tolerance_deg header"


def _serial(rec: Recording) -> int:
    value = rec.header.get("device_serial")
    return int(value) if isinstance(value, int | float) and not isinstance(value, bool) else 0


def _node_id(rec: Recording) -> int | None:
    value = rec.header.get("node_id")
    return int(value) if isinstance(value, int | float) and not isinstance(value, bool) else None


def _mean_temp(rec: Recording) -> float | None:
    t = rec.temp_c[np.isfinite(rec.temp_c)]
    return float(t.mean()) if t.size else None


def _unlabelled_averages(rec: Recording) -> list[PositionAverage]:
    """Average the still stretches for the scalar fit: labels, else detected intervals."""
    if np.any(rec.position >= 0):
        return position_averages(rec, require_angles=False)
    finite = np.all(np.isfinite(rec.accel), axis=1)
    if finite.sum() < 3:
        raise InputError("the recording has no accelerometer samples")
    filled = np.where(finite[:, None], rec.accel, np.nanmedian(rec.accel, axis=0))
    intervals = detect_static_intervals(filled, rec.sample_rate_hz)
    unknown = Pose(np.nan, np.nan, np.nan)
    return [
        average_position(
            unknown, rec.accel[i.start : i.stop], rec.gyro[i.start : i.stop], rec.sample_rate_hz
        )
        for i in intervals
    ]


def solution_report(solution: Solution, g_source: str) -> str:
    """Every parameter with its σ, what was not determined, and the fit quality."""
    r = solution.record
    lines = [f"plan {r.plan}; g = {r.conditions.g if r.conditions else '?'} m/s² ({g_source})"]
    lines += _vector_lines("accel bias (counts)", r.accel.bias, r.accel.bias_sigma)
    lines += _matrix_lines("accel K (counts per m/s²)", r.accel.K, r.accel.K_sigma)
    if r.base_tilt_deg is not None:
        t = r.base_tilt_deg
        s = t.sigma or (None, None)
        lines.append(f"base tilt: alpha0 {_pm(t.alpha0, s[0])} deg, beta0 {_pm(t.beta0, s[1])} deg")
    if r.gyro is not None:
        lines += _vector_lines("gyro bias (counts)", r.gyro.bias, r.gyro.bias_sigma)
        lines += _matrix_lines("gyro S (counts per rad/s)", r.gyro.S, r.gyro.S_sigma)
        lines += _matrix_lines("gyro G (counts per m/s²)", r.gyro.G, r.gyro.G_sigma)
    for name, reason in solution.undetermined.items():
        lines.append(f"not determined: {name}: {reason}")
    if r.fit is not None and r.fit.rms is not None:
        lines.append(f"fit: rms {r.fit.rms:.3g} m/s² after correction, dof {r.fit.dof}")
    return "\n".join(lines) + "\n"


def _pm(value: float | None, sigma: float | None) -> str:
    if value is None:
        return "null (held at nominal)"
    return f"{value:.6g} ± {sigma:.2g}" if sigma is not None else f"{value:.6g} (held)"


def _vector_lines(title: str, values: Any, sigmas: Any) -> list[str]:
    if values is None:
        return [f"{title}: null (held at nominal)"]
    sig = sigmas or (None,) * 3
    return [f"{title}: " + ", ".join(_pm(v, s) for v, s in zip(values, sig, strict=True))]


def _matrix_lines(title: str, values: Any, sigmas: Any) -> list[str]:
    if values is None or all(v is None for row in values for v in row):
        return [f"{title}: null (held at nominal)"]
    sig = sigmas or ((None,) * 3,) * 3
    rows = [
        "  [" + ", ".join(_pm(v, s) for v, s in zip(row, srow or (None,) * 3, strict=True)) + "]"
        for row, srow in zip(values, sig, strict=True)
    ]
    return [f"{title}:", *rows]
