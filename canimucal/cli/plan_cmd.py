"""`canimucal plan`: a plan's Cramér–Rao bounds and what it cannot determine (docs/design.md §3)."""

from __future__ import annotations

import argparse
import textwrap
from dataclasses import replace
from typing import Any

import numpy as np

from canimucal.analysis.gyro_bounds import GyroMoveBounds, gyro_move_bounds
from canimucal.analysis.static_noise import static_rows
from canimucal.cli.output import add_json_option, check_outputs, emit
from canimucal.cli.spec_options import add_model_options, spec_from_args
from canimucal.cli.user_config import user_acceptance
from canimucal.errors import InputError
from canimucal.io.grouping import position_rows
from canimucal.io.plans import plan_to_dict, resolve_plan
from canimucal.model.layout import JointSpec
from canimucal.model.plan import BoundTable
from canimucal.model.positions import Plan
from canimucal.model.vocabulary.plans import (
    CUSTOM,
    DEFAULT_PLAN,
    PLANS,
    builtin_names,
    builtin_plan,
    plan_help,
)
from canimucal.procedure.averaging import (
    AveragingPolicy,
    PlanSchedule,
    averaged_sensors,
    choose_time,
    describe_rule,
    later_budget_s,
    scheduled_plan,
)
from canimucal.runtime.inputs import read_recording
from canimucal.runtime.plan_forecast import (
    LimitForecast,
    forecast,
    forecast_document,
    forecast_lines,
    plan_bounds,
    schedule,
    session_spec,
    table_cells,
    trim_forecast,
)

PLAN_SCHEMA = "canimucal.plan/1"
"""``plan --json``: one plan's bounds (docs/design.md §5)."""
PLAN_COMPARISON_SCHEMA = "canimucal.plan-comparison/1"
"""``plan --compare --json``: every built-in plan's bounds, each a ``canimucal.plan/1``."""


def add_subparser(subparsers: Any) -> None:
    """Register ``plan``."""
    p = subparsers.add_parser(
        "plan",
        help="Cramér–Rao bound of every parameter for a plan",
        description="Print the Cramér–Rao bound of every parameter of a plan (white noise "
        "1 count/√Hz, K = I/LSB, zero tilt) at the seconds its session averages each "
        "position, for the model that session fits, its positions and operator minutes, "
        "and the combinations it cannot determine or only poorly separates; the TUI's plan "
        "screen shows the same figures. --compare ranks the built-in plans by worst bound "
        "and operator minutes.",
    )
    p.add_argument(
        "--plan",
        default=DEFAULT_PLAN,
        help=plan_help() + " (JSON/TOML)",
    )
    p.add_argument(
        "--compare",
        action="store_true",
        help="compare every built-in plan (and --plan when it is a file)",
    )
    p.add_argument(
        "--prior-k-sigma",
        type=float,
        metavar="FRACTION",
        help="relative 1σ of the factory K held as a prior (default: the plan's own, "
        "vehicle 0.01; others none)",
    )
    add_model_options(p, default_tilt=None, default_model=None)
    timing = p.add_mutually_exclusive_group()
    timing.add_argument(
        "--seconds",
        type=float,
        metavar="S",
        help="average every position S seconds, the first included (as the TUI's and "
        "demo's --seconds; default: the session's rule, at least 120 s for the first "
        "position, then each position's seconds in the plan)",
    )
    timing.add_argument(
        "--total-seconds",
        type=float,
        help="spread this total averaging time equally over the positions",
    )
    p.add_argument(
        "--with-tolerance",
        action="store_true",
        help="include each position's angle-setting tolerance in the bound",
    )
    p.add_argument(
        "--noise",
        metavar="RECORDING",
        help="a still recording of the unit (any format analyze reads): print the averaging "
        "time the procedure would choose from it, per axis (accelerometer and, unless "
        "--gyro none, gyro: the procedure's default gyro model is mems)",
    )
    add_json_option(p)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    """Compute and print the bound table."""
    check_outputs(args)
    for flag, value in (("--seconds", args.seconds), ("--total-seconds", args.total_seconds)):
        if value is not None and not (np.isfinite(value) and value > 0):
            raise InputError(f"{flag} must be > 0, got {value:g}")
    if args.compare:
        compare = argparse.Namespace(**vars(args))  # one model for every plan: diag K + tilt
        compare.model = args.model or "diag"
        compare.tilt = True if args.tilt is None else args.tilt
        spec = spec_from_args(compare)
        plans = [builtin_plan(name) for name in builtin_names()]
        if args.plan not in builtin_names():
            plans.append(resolve_plan(args.plan))
        tables = [(plan, _table(args, plan, spec)) for plan in plans]
        compared = {
            "schema": PLAN_COMPARISON_SCHEMA,
            "plans": [bound_document(t, p, _schedule(args, p)) for p, t in tables],
        }
        emit(args, compared, comparison_report(tables, [_schedule(args, p) for p in plans]))
        return 0
    plan = resolve_plan(args.plan)
    spec = _plan_spec(args, plan)
    table = _table(args, plan, spec)
    times = _schedule(args, plan)
    document = bound_document(table, plan, times)
    report = bound_report(table, plan, times)
    if args.gyro == "moves":
        moves = gyro_move_bounds(plan)
        document["gyro_moves"] = moves_document(moves)
        report += moves_report(moves)
    averaging, text = _averaging(
        args.noise, averaged_sensors(args.gyro or "mems"), _policy(args, plan), plan
    )
    document["averaging"] = averaging
    report += text
    rows = _acceptance_forecast(args, plan, spec)
    document["acceptance"] = forecast_document(rows)
    trim = trim_forecast(
        plan,
        session_spec(_plan_name(plan), spec.gyro),
        policy=_policy(args, plan),
        prior_k_sigma=args.prior_k_sigma,
    )
    report += "\n".join(forecast_lines(rows, plan.name, trim=trim)) + "\n"
    emit(args, document, report)
    return 0


def _plan_name(plan: Plan) -> str:
    """Return the registry's name of ``plan`` (``custom`` for a plan file)."""
    return plan.name if plan.name in builtin_names() else CUSTOM


def _plan_spec(args: argparse.Namespace, plan: Plan) -> JointSpec:
    """Return the flags' model, each flag left out taken from what the plan's session fits."""
    session = session_spec(_plan_name(plan))
    filled = argparse.Namespace(**vars(args))
    filled.model = args.model or session.accel_k
    filled.tilt = session.tilt != "none" if args.tilt is None else args.tilt
    return spec_from_args(filled)


def _policy(args: argparse.Namespace, plan: Plan) -> AveragingPolicy:
    """Return the session's averaging rule, or each position at ``--seconds`` (or a share)."""
    if args.seconds is not None:
        return AveragingPolicy(fixed_s=args.seconds)
    if args.total_seconds is not None:
        return AveragingPolicy(fixed_s=args.total_seconds / len(plan.positions))
    return AveragingPolicy()


def _schedule(args: argparse.Namespace, plan: Plan) -> PlanSchedule:
    return schedule(plan, _policy(args, plan))


def _averaging(
    noise: str | None, sensors: tuple[str, ...], policy: AveragingPolicy, plan: Plan
) -> tuple[dict[str, Any], str]:
    """Describe the procedure's averaging rule, and its per-axis result on a still recording.

    ``sensors``: those whose axes decide (the procedure's gyro model, ``mems`` by default);
    the noise's choice is clipped to the plan's seconds, as the session clips it.
    """
    rule = describe_rule(policy, sensors)
    doc: dict[str, Any] = {"rule": rule}
    text = textwrap.fill(f"averaging: {rule}", 80, subsequent_indent="  ") + "\n"
    if noise is None:
        return doc, text
    rec = read_recording(noise)
    rows = static_rows(rec)
    if rows is None:
        rows = max(position_rows(rec)[0], key=len, default=np.arange(0))
    samples = {
        "accel": [np.asarray(rec.accel[rows], dtype=np.float64)],
        "gyro": [np.asarray(rec.gyro[rows], dtype=np.float64)],
    }
    event = choose_time(
        AveragingPolicy(), samples, rec.sample_rate_hz, sensors, later_budget_s(plan)
    )
    if event.source != "noise":
        raise InputError(f"--noise: {noise} has too few still samples for an Allan deviation")
    doc.update(
        seconds=event.seconds,
        optima_s={name: list(values) for name, values in event.sensor_optima},
        loss={name: list(values) for name, values in event.sensor_loss},
        limiting_axis=event.limiting_axis,
    )
    later = f"from {noise}: later positions {event.describe()}"
    text += textwrap.fill(later, 80, initial_indent="  ", subsequent_indent="    ") + "\n"
    return doc, text


def _acceptance_forecast(
    args: argparse.Namespace, plan: Plan, spec: JointSpec
) -> list[LimitForecast]:
    """Each acceptance limit in force for ``plan`` beside the σ it predicts (runtime's forecast).

    A built-in plan is judged with the model its session fits (the plan registry's); the
    limits are the user's ``acceptance.toml`` over the plan's own defaults (docs/design.md §3).
    """
    name = _plan_name(plan)
    session = session_spec(name, spec.gyro)
    limits = user_acceptance().limits(name)
    return forecast(
        plan, limits, session, policy=_policy(args, plan), prior_k_sigma=args.prior_k_sigma
    )


def _with_trim(plan: Plan, spec: JointSpec) -> JointSpec:
    """``spec`` with the mounting trim when ``plan`` is a built-in plan that fits it."""
    entry = PLANS.get(plan.name)
    if entry is None or entry.plan is None or not entry.trim:
        return spec
    return replace(spec, trim=True)


def _table(args: argparse.Namespace, plan: Plan, spec: JointSpec) -> BoundTable:
    latitude = None if args.latitude_deg is None else float(np.deg2rad(args.latitude_deg))
    if args.prior_k_sigma is not None and not args.prior_k_sigma > 0:
        raise InputError(f"--prior-k-sigma must be > 0, got {args.prior_k_sigma:g}")
    return plan_bounds(
        plan,
        _with_trim(plan, spec),  # the vehicle plan's mounting trim (docs/method.md §3)
        policy=_policy(args, plan),
        latitude=latitude,
        include_tolerance=args.with_tolerance,
        prior_k_sigma=args.prior_k_sigma,
    )


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


def bound_document(table: BoundTable, plan: Plan, times: PlanSchedule) -> dict[str, Any]:
    """Return the JSON form of a bound table, with the plan's positions and operator time.

    ``positions`` are the plan's own (a custom plan file's keys); ``seconds_per_position``,
    ``total_seconds`` and ``operator_minutes`` the session's times (``times``).
    """
    worst = table.worst_case_counts
    entry = PLANS.get(table.plan)
    return {
        "schema": PLAN_SCHEMA,
        "plan": table.plan,
        **({"description": entry.description} if entry is not None else {}),
        "total_seconds": times.total_seconds,
        "operator_minutes": times.operator_minutes,
        "seconds_per_position": list(times.seconds),
        "positions": plan_to_dict(plan)["positions"],
        "model": _spec_dict(table),
        "parameters": [
            {
                "name": r.name,
                "unit": r.unit,
                "sigma": r.sigma,
                "effect_at_1g_counts": r.effect_counts,
                "reason": r.reason,
                **({"prior": {"sigma": r.prior_sigma}} if r.prior_sigma is not None else {}),
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


def bound_report(table: BoundTable, plan: Plan, times: PlanSchedule) -> str:
    """Format the bound table, the positions and the priors as text (fits 80 columns)."""
    entry = PLANS.get(table.plan)
    lines = [
        f"plan {table.plan}: {times.totals_words()}",
        *([entry.description] if entry is not None else []),
        *textwrap.wrap(f"times: {times.times_words()}", 80, subsequent_indent="  "),
        "bounds at these times, white noise 1 count/√Hz, K = I/LSB, zero tilt",
        *_position_lines(plan, times),
        f"{'parameter':<22}{'σ (own units)':>16} {'unit':<14}{'effect at 1 g':>14}",
    ]
    for r, (name, sigma, unit, effect) in zip(table.rows, table_cells(table), strict=True):
        if r.sigma is None or r.effect_counts is None:
            lines.append(f"{name:<22}{sigma:>16} {unit:<14}{effect:>14}")
            continue
        mark = " *" if r.prior_sigma is not None else ""
        lines.append(f"{name:<22}{sigma:>16} {unit:<14}{effect:>9} cnt{mark}")
    priors = [r for r in table.rows if r.prior_sigma is not None]
    if priors:
        lines.append(
            f"* prior: factory K ± {priors[0].prior_sigma:.4g} counts/(m/s²) (1σ), "
            "which these poses cannot separate"
        )
    worst = table.worst_case_counts
    worst_text = f"{worst:.4g} counts" if np.isfinite(worst) else "unbounded"
    lines.append(f"worst-case bound: {worst_text} ({table.worst_parameter})")
    for finding in table.separability.findings:
        lines += textwrap.wrap(finding.message, 80, subsequent_indent="  ")
    if not table.separability.findings:
        lines.append("every parameter is identifiable and separable under this plan")
    return "\n".join(lines) + "\n"


def _position_lines(plan: Plan, times: PlanSchedule) -> list[str]:
    lines = []
    positions = plan_to_dict(scheduled_plan(plan, times))["positions"]
    for k, p in enumerate(positions, start=1):
        turn = f"psi {p['psi_deg']:g}°"
        tolerance = f"±{p['tolerance_deg']:g}°"
        if "psi_tolerance_deg" in p:
            tolerance += f" (turn ±{p['psi_tolerance_deg']:g}°)"
        lines.append(
            f"  {k:>2}. alpha {p['alpha_deg']:g}°, beta {p['beta_deg']:g}°, {turn}, "
            f"{p['seconds']:g} s, {tolerance}"
        )
    return lines


def comparison_report(tables: list[tuple[Plan, BoundTable]], schedules: list[PlanSchedule]) -> str:
    """One line per plan: worst bound, its parameter, operator minutes, largest tilt, prior."""
    lines = [
        f"{'plan':<13}{'worst bound':>12} {'parameter':<16}{'minutes':>8}"
        f"{'max tilt':>9} {'prior':<12}"
    ]
    for (plan, table), times in zip(tables, schedules, strict=True):
        worst = table.worst_case_counts
        worst_text = f"{worst:.3g} cnt" if np.isfinite(worst) else "unbounded"
        tilt = max(max(abs(p.alpha), abs(p.beta)) for p in plan.positions)
        prior = "none" if plan.prior_k_sigma is None else f"K ±{plan.prior_k_sigma:.0%}"
        if any(r.prior_sigma is not None for r in table.rows) and plan.prior_k_sigma is None:
            prior = "K (flag)"
        lines.append(
            f"{plan.name:<13}{worst_text:>12} {table.worst_parameter:<16}"
            f"{times.operator_minutes:>8.0f}{np.rad2deg(tilt):>8.0f}° {prior:<12}"
        )
    lines.append("worst bound: largest effect at 1 g of any parameter (counts), 1σ")
    return "\n".join(lines) + "\n"
