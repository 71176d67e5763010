"""`canimucal solve`: a recording in, the calibration JSON of docs/design.md §5 out."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from canimucal.analysis.calibrate import Solution, trials_line
from canimucal.analysis.solve import solve_recording
from canimucal.analysis.static_noise import recording_lsb
from canimucal.cli.input_options import INPUT_HELP, SECOND_HELP, add_input_options, read_input
from canimucal.cli.output import add_json_option, check_outputs, emit
from canimucal.cli.spec_options import add_model_options, choice_from_args
from canimucal.cli.user_config import user_acceptance
from canimucal.io.calibration import (
    Calibration,
    RecordingRef,
    sha256_of,
    slope_trim_correlation,
)
from canimucal.io.recording import Recording
from canimucal.model.sensor import STANDARD_GRAVITY
from canimucal.model.vocabulary.units import Scales
from canimucal.runtime.certificate import NOT_ESTIMATED, value_rows


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
    conditions = solved.record.conditions
    scales = recording_scales(rec, conditions.g if conditions is not None else None)
    report = solution_report(solved.solution, solved.g_source, scales)
    text = report + (verdict.text if verdict else "")
    emit(args, solved.record.to_dict(), text)
    if verdict is not None and not verdict.block.passed and not args.no_check:
        print(
            "error: acceptance failed (the JSON is written; --no-check to exit 0)", file=sys.stderr
        )
        return 3
    return 0


def solution_report(solution: Solution, g_source: str, scales: Scales | None = None) -> str:
    """Every parameter with its σ and unit, what was not determined, and the fit quality.

    Each value in the file's unit (counts, counts/(m/s²), deg) and, given ``scales`` (the
    nominal LSBs and g), beside it in the operator's (mg, ppm from nominal, °, °/s): the
    certificate's rows (:func:`~canimucal.runtime.certificate.value_rows`).
    """
    r = solution.record
    g = r.conditions.g if r.conditions is not None else None
    g_text = "not given" if g is None else f"{g:g} m/s²"
    lines = [f"plan {r.plan}; g = {g_text} ({g_source})"]
    rows = _folded(value_rows(r.to_dict(), scales))
    width = max((len(name) for name, _, _ in rows), default=0)
    wide = max((len(device) for _, device, _ in rows), default=0)
    lines.append(f"{'parameter':<{width}}  {'value ± σ (device)':<{wide}}  operator's units")
    lines += [f"{name:<{width}}  {device:<{wide}}  {shown}" for name, device, shown in rows]
    if r.mounting_trim_deg is not None:
        lines.append(trim_line(r))
    if r.trials:
        lines.append(trials_line(r) or "")
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


def _folded(rows: list[tuple[str, str, str]]) -> list[tuple[str, str, str]]:
    """One row for a family held at nominal throughout (``gyro.G  nominal (not estimated)``)."""
    families: dict[str, list[tuple[str, str, str]]] = {}
    for row in rows:
        families.setdefault(row[0].split("[", 1)[0], []).append(row)
    out = []
    for family, members in families.items():
        if len(members) > 1 and all(device == NOT_ESTIMATED for _, device, _ in members):
            out.append((family, NOT_ESTIMATED, "—"))
        else:
            out += members
    return out


def trim_line(record: Calibration) -> str:
    """Say how far the mounting trim is told apart from the floor slope (its rows are above)."""
    correlation = slope_trim_correlation(record)
    if correlation is None:
        return "mounting trim: fitted beside the floor slope"
    return (
        "mounting trim: fitted beside the floor slope, largest correlation with it "
        f"{correlation:+.2f}"
    )


def recording_scales(rec: Recording, g: float | None) -> Scales:
    """Return a recording's nominal LSBs (its header's, else nominal) and the g it used."""
    lsb = recording_lsb(rec)
    return Scales(lsb["accel"], lsb["gyro"], g or STANDARD_GRAVITY)
