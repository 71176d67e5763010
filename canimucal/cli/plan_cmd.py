"""`canimucal plan`: Cramér–Rao bounds of a plan and what it cannot determine (DESIGN §3)."""

from __future__ import annotations

import argparse
from typing import Any

import numpy as np

from canimucal.analysis.gyro_bounds import GyroMoveBounds, gyro_move_bounds
from canimucal.cli.output import add_json_option, check_outputs, emit
from canimucal.cli.spec_options import add_model_options, spec_from_args
from canimucal.io.plans import resolve_plan
from canimucal.model.plan import BoundTable, builtin_plan, cramer_rao
from canimucal.model.sensor import DEFAULT_ACCEL_LSB, STANDARD_GRAVITY


def add_subparser(subparsers: Any) -> None:
    """Register ``plan``."""
    p = subparsers.add_parser(
        "plan",
        help="Cramér–Rao bound of every parameter for a plan",
        description="Print the Cramér–Rao bound of every parameter of a plan (white noise "
        "1 count/√Hz, K = I/LSB, zero tilt) and the combinations it cannot determine or "
        "only poorly separates.",
    )
    p.add_argument(
        "--plan", default="recommended", help="two, five, recommended or a plan file (JSON/TOML)"
    )
    add_model_options(p, default_tilt=True)
    p.add_argument(
        "--total-seconds",
        type=float,
        help="spread this total averaging time equally over the positions",
    )
    p.add_argument(
        "--with-tolerance",
        action="store_true",
        help="include each position's angle-setting tolerance in the bound",
    )
    add_json_option(p)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    """Compute and print the bound table."""
    check_outputs(args)
    plan = resolve_plan(args.plan, builtin_plan)
    if args.total_seconds is not None:
        plan = plan.with_total_seconds(args.total_seconds)
    spec = spec_from_args(args)
    latitude = None if args.latitude_deg is None else float(np.deg2rad(args.latitude_deg))
    table = cramer_rao(
        plan,
        spec,
        k_nominal_counts_per_ms2=1.0 / DEFAULT_ACCEL_LSB,
        g=STANDARD_GRAVITY,
        latitude=latitude,
        include_tolerance=args.with_tolerance,
    )
    document = bound_document(table, plan.total_seconds)
    report = bound_report(table, plan.total_seconds)
    if args.gyro == "moves":
        moves = gyro_move_bounds(plan)
        document["gyro_moves"] = moves_document(moves)
        report += moves_report(moves)
    emit(args, document, report)
    return 0


def moves_document(bounds: GyroMoveBounds) -> dict[str, Any]:
    """Return the JSON form of the gyro bounds from the plan's moves."""
    sigma = [[None if np.isnan(v) else float(v) for v in row] for row in bounds.relative_sigma]
    return {
        "S_relative_sigma": sigma,
        "identifiable_columns": {a: bool(bounds.identifiable[j]) for j, a in enumerate("xyz")},
        "seen_by": {a: list(bounds.seen_by[j]) for j, a in enumerate("xyz")},
        "moves": list(bounds.moves),
        "notes": list(bounds.notes),
    }


def moves_report(bounds: GyroMoveBounds) -> str:
    """Format the gyro bounds from the moves: which moves identify which S entries."""
    lines = ["gyro S from the moves (σ as a fraction of the scale factor):"]
    lines += [f"  move {m}" for m in bounds.moves]
    for j, axis in enumerate("xyz"):
        column = bounds.relative_sigma[:, j]
        if not bounds.identifiable[j]:
            lines.append(f"  column {axis} (S_x{axis}, S_y{axis}, S_z{axis}): not identifiable")
            continue
        sig = ", ".join(f"{v:.2g}" for v in column)
        lines.append(f"  column {axis}: σ {sig}; seen by moves {', '.join(bounds.seen_by[j])}")
    lines += [f"  {note}" for note in bounds.notes]
    return "\n".join(lines) + "\n"


def bound_document(table: BoundTable, total_seconds: float) -> dict[str, Any]:
    """Return the JSON form of a bound table."""
    worst = table.worst_case_counts
    return {
        "plan": table.plan,
        "total_seconds": total_seconds,
        "model": _spec_dict(table),
        "parameters": [
            {
                "name": r.name,
                "unit": r.unit,
                "sigma": r.sigma,
                "effect_at_1g_counts": r.effect_counts,
                "reason": r.reason,
            }
            for r in table.rows
        ],
        "worst_case_counts": worst if np.isfinite(worst) else None,
        "worst_parameter": table.worst_parameter,
        "findings": [
            {
                "kind": f.kind,
                "parameters": list(f.parameters),
                "message": f.message,
                "eigenvalue_ratio": f.eigenvalue_ratio,
                "correlation": f.correlation,
            }
            for f in table.separability.findings
        ],
    }


def _spec_dict(table: BoundTable) -> dict[str, Any]:
    s = table.spec
    return {
        "accel_k": s.accel_k,
        "tilt": s.tilt,
        "gyro": s.gyro,
        "gyro_s": s.gyro_s,
        "gyro_g": s.gyro_g,
    }


def bound_report(table: BoundTable, total_seconds: float) -> str:
    """Format the bound table as text (fits 80 columns)."""
    lines = [
        f"plan {table.plan}: {total_seconds:g} s of averaging in all; "
        "white noise 1 count/√Hz, K = I/LSB, zero tilt",
        f"{'parameter':<22}{'σ (own units)':>16} {'unit':<14}{'effect at 1 g':>14}",
    ]
    for r in table.rows:
        name = r.name.replace("base_tilt.", "tilt.")
        if r.sigma is None or r.effect_counts is None:
            lines.append(f"{name:<22}{'—':>16} {r.unit:<14}{'undetermined':>14}")
            continue
        sigma = np.rad2deg(r.sigma) if r.unit == "rad" else r.sigma
        unit = "deg" if r.unit == "rad" else r.unit
        lines.append(f"{name:<22}{sigma:>16.4g} {unit:<14}{r.effect_counts:>9.4g} cnt")
    worst = table.worst_case_counts
    worst_text = f"{worst:.4g} counts" if np.isfinite(worst) else "unbounded"
    lines.append(f"worst-case bound: {worst_text} ({table.worst_parameter})")
    lines.extend(f.message for f in table.separability.findings)
    if not table.separability.findings:
        lines.append("every parameter is identifiable and separable under this plan")
    return "\n".join(lines) + "\n"
