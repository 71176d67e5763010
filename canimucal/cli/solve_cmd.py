"""`canimucal solve`: a recording in, the calibration JSON of docs/design.md §5 out."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from canimucal.analysis.calibrate import Solution
from canimucal.analysis.solve import solve_recording
from canimucal.cli.input_options import INPUT_HELP, SECOND_HELP, add_input_options, read_input
from canimucal.cli.output import add_json_option, check_outputs, emit
from canimucal.cli.spec_options import add_model_options, choice_from_args
from canimucal.cli.user_config import user_acceptance
from canimucal.io.calibration import RecordingRef, sha256_of
from canimucal.model.vocabulary.units import QUANTITIES


def add_subparser(subparsers: Any) -> None:
    """Register ``solve``."""
    p = subparsers.add_parser(
        "solve",
        help="solve a recording for the calibration parameters",
        description="Solve a recording: joint least squares when the positions carry "
        "angles, the scalar |f| = g fit otherwise. The model defaults to the one the "
        "session solved (header keys plan, model, tilt, gyro, tolerance_deg). Prints every "
        "parameter with its σ and the acceptance verdict; --json writes the calibration "
        "JSON; exit 3 when acceptance fails (after writing).",
    )
    p.add_argument("recording", help=INPUT_HELP)
    p.add_argument("second", nargs="?", help=SECOND_HELP)
    add_input_options(p)
    add_model_options(p, default_tilt=False)
    p.set_defaults(model=None, tilt=None, tilt_model=None)  # None: from the header
    p.add_argument(
        "--tolerance-deg",
        type=float,
        help="1σ angle-setting error of each position (default: header, else estimated)",
    )
    p.add_argument(
        "--prior-k-sigma",
        type=float,
        metavar="FRACTION",
        help="hold K at the nominal with this relative 1σ (default: the header's plan's)",
    )
    p.add_argument(
        "--prior-k",
        metavar="FILE",
        help="the factory K to hold it at: a calibration JSON or read-params --json output",
    )
    p.add_argument(
        "--no-check",
        action="store_true",
        help="report the acceptance verdict but exit 0 when it fails",
    )
    p.add_argument("--g", type=float, help="local gravity, m/s² (default: header, latitude)")
    add_json_option(p)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    """Solve and report."""
    check_outputs(args)
    rec = read_input(args, args.recording, args.second)
    ref = RecordingRef(file=Path(args.recording).name, sha256=sha256_of(args.recording))
    solved = solve_recording(rec, choice_from_args(args), recording=ref, limits=user_acceptance())
    for note in solved.notes:
        print(f"note: {note}", file=sys.stderr)
    for warning in solved.solution.warnings:
        print(f"warning: {warning}", file=sys.stderr)
    verdict = solved.verdict
    text = solution_report(solved.solution, solved.g_source) + (verdict.text if verdict else "")
    emit(args, solved.record.to_dict(), text)
    if verdict is not None and not verdict.block.passed and not args.no_check:
        print(
            "error: acceptance failed (the JSON is written; --no-check to exit 0)", file=sys.stderr
        )
        return 3
    return 0


def solution_report(solution: Solution, g_source: str) -> str:
    """Every parameter with its σ, what was not determined, and the fit quality."""
    r = solution.record
    lines = [f"plan {r.plan}; g = {r.conditions.g if r.conditions else '?'} m/s² ({g_source})"]
    lines += _vector_lines(_label("accel.bias"), r.accel.bias, r.accel.bias_sigma)
    lines += _matrix_lines(_label("accel.K"), r.accel.K, r.accel.K_sigma)
    if r.base_tilt_deg is not None:
        t, deg = r.base_tilt_deg, QUANTITIES["base_tilt"].shown_unit
        s = t.sigma or (None, None)
        lines.append(
            f"base tilt: alpha0 {_pm(t.alpha0, s[0])} {deg}, beta0 {_pm(t.beta0, s[1])} {deg}"
        )
    if r.gyro is not None:
        lines += _vector_lines(_label("gyro.bias"), r.gyro.bias, r.gyro.bias_sigma)
        lines += _matrix_lines(_label("gyro.S"), r.gyro.S, r.gyro.S_sigma)
        lines += _matrix_lines(_label("gyro.G"), r.gyro.G, r.gyro.G_sigma)
    for name, reason in solution.undetermined.items():
        lines.append(f"not determined: {name}: {reason}")
    if r.fit is not None and r.fit.rms is not None:
        lines.append(f"fit: rms {r.fit.rms:.3g} m/s² after correction, dof {r.fit.dof}")
    if solution.quality is not None:
        scatter = " and the pose scatter" if solution.joint is not None else ""
        if solution.joint is not None and r.fit is not None and r.fit.pose_scatter_deg is not None:
            scatter += f" ({r.fit.pose_scatter_deg:.3g}°, {r.fit.pose_scatter_basis})"
        lines.append(solution.quality.line(f"the within-position noise{scatter}"))
    return "\n".join(lines) + "\n"


def _label(family: str) -> str:
    """``accel K (counts per m/s²)``: a parameter family in words, with its unit."""
    return f"{family.replace('.', ' ')} ({QUANTITIES[family].unit_words})"


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
