"""`canimucal demo`: the guided procedure end to end against simulated IMU node(s) over CAN.

``--headless``: the simulated node(s) (``--nodes N``, ids 0x10, 0x11, …, one truth each:
``--truth FILE`` or drawn at random from ``--seed``) sit on python-can's ``virtual`` bus in
this process; an automatic operator runs the same procedure the TUI runs (skips the warm-up,
confirms each pose — the simulated unit is moved there —, accepts each position, solves,
writes with the transactional write, verifies at two poses). ``--seconds S`` averages every
position S seconds (skipping the long first recording); ``--time-scale`` runs the simulated
clock faster than the wall clock. Into ``--out`` (the tool's own directory: files there are
replaced) go per node the recording CSV, the verification CSV, the calibration JSON with the
``readback`` block (docs/design.md §5), the certificate, the truth and the device backup. Then it
prints each value read back from the device beside the truth, with σ and the deviation in σ.

Without ``--headless`` the TUI (:mod:`canimucal.tui`, imported lazily) runs the same
procedure on the same simulated node(s) with a person as the operator: confirming a pose
moves the simulated unit there. Its files go to ``--out`` as well. Without a terminal
(stdin or stdout redirected, as in ``make demo`` under CI) it runs headless, with a note.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
from pathlib import Path
from typing import Any

import numpy as np

from canimucal.cli.output import add_json_option, check_outputs, dumps, emit
from canimucal.cli.user_config import user_acceptance
from canimucal.cli.vehicle_options import add_vehicle_size_options, vehicle_size_from_args
from canimucal.io.atomic import make_directory, write_text_atomic
from canimucal.io.plans import resolve_plan
from canimucal.io.truth import load_truth
from canimucal.model.positions import Plan
from canimucal.model.vocabulary.plans import CUSTOM, DEFAULT_PLAN, PLANS, builtin_names, plan_help
from canimucal.procedure import events as ev
from canimucal.procedure.averaging import AveragingPolicy
from canimucal.runtime.certificate import verified_line
from canimucal.runtime.operator import run_automatic
from canimucal.runtime.readback_check import comparison_table, readback_deviations
from canimucal.runtime.resume import load_resume_state, recorded_plan, resumed_message
from canimucal.runtime.session import Session, output_name
from canimucal.runtime.wiring import demo_settings, open_devices
from canimucal.signals import EXIT_INTERRUPTED
from canimucal.sim.truth import Truth

log = logging.getLogger(__name__)

DEMO_NODES_SCHEMA = "canimucal.demo-nodes/1"
"""``demo --nodes N --json`` with N > 1: ``nodes`` maps each node id to its calibration JSON
(one node: the calibration JSON itself)."""
DEFAULT_TIME_SCALE = 20.0
DEMO_GYRO_G_MAX = 0.5
"""With ``--gyro-g`` a random truth's G entries are uniform in ±this (counts per m/s²)."""


def add_subparser(subparsers: Any) -> None:
    """Register ``demo``."""
    p = subparsers.add_parser(
        "demo",
        help="calibrate the built-in simulated IMU end to end (guided procedure over CAN)",
        description="Run the guided calibration against simulated IMU node(s) on a virtual "
        "CAN bus, write the result into them and compare what they hold with the truth.",
    )
    p.add_argument("--headless", action="store_true", help="no TUI: an automatic operator")
    p.add_argument(
        "--plan",
        help=plan_help() + f" (default {DEFAULT_PLAN}; with --resume, the recording's)",
    )
    p.add_argument("--truth", help="truth JSON for the simulated unit(s) (default: random)")
    p.add_argument("--seed", type=int, default=2026, help="random seed (truth and noise)")
    p.add_argument("--seconds", type=float, help="averaging seconds of every position")
    add_vehicle_size_options(p)  # the demo's simulated unit: used, not saved
    p.add_argument("--nodes", type=int, default=1, help="simulated nodes on one rigid body")
    p.add_argument("--gyro", choices=("mems", "nav"), default="mems", help="gyro grade")
    p.add_argument(
        "--gyro-g",
        action="store_true",
        help="also estimate the gyro's g-sensitivity G from the static positions (where the "
        "plan's positions determine it, e.g. five or recommended) and write it; a random "
        "truth then has G within ±0.5 counts per m/s² to find",
    )
    p.add_argument(
        "--time-scale",
        type=float,
        default=DEFAULT_TIME_SCALE,
        help=f"simulated seconds per wall second (default {DEFAULT_TIME_SCALE:g})",
    )
    p.add_argument("--out", default="demo-out", help="directory for the demo's files")
    p.add_argument("--operator", help="operator's name, for the certificate")
    p.add_argument("--site", help="where the calibration was done, for the certificate")
    p.add_argument(
        "--resume",
        metavar="DIR",
        help="go on with the interrupted session in DIR (same plan and seed or truth; "
        "headless only; its files go to DIR)",
    )
    add_json_option(p)
    p.set_defaults(run=run)


def _truths(args: argparse.Namespace) -> list[Truth]:
    if not 1 <= args.nodes <= 8:
        from canimucal.errors import InputError

        raise InputError(f"--nodes must be 1..8, got {args.nodes}")
    if args.truth:
        base = load_truth(args.truth).to_dict()
        return [Truth.from_dict({**base, "serial": base["serial"] + i}) for i in range(args.nodes)]
    rng = np.random.default_rng(args.seed)
    limits = plan_truth_limits(args.plan)
    if args.gyro_g:
        limits.setdefault("gyro_g_max", DEMO_GYRO_G_MAX)
    if limits:
        print(
            f"note: random truth drawn within what plan '{args.plan}' can determine ({limits})",
            file=sys.stderr,
        )
    return [Truth.random(rng, **limits) for _ in range(args.nodes)]


def plan_truth_limits(name: str) -> dict[str, float]:
    """Return what a random truth for plan ``name`` leaves out: what its positions cannot tell.

    From the plan registry: a diagonal K, no cross-axis terms; no tilt, no base tilt; K held
    at a prior of relative σ, no cross-axis terms and scale errors uniform in ±√3 σ (the
    prior's own spread, to 0.1 ‰: ±1.73 % for the vehicle plan's σ of 1 %).
    """
    entry = PLANS.get(name)
    limits: dict[str, float] = {}
    if entry is None:
        return limits
    if entry.accel_k == "diag" or entry.holds_k_prior:
        limits["cross_axis_max"] = 0.0
    if entry.tilt == "none":
        limits["tilt_max_deg"] = 0.0
    if entry.plan is not None and entry.plan.prior_k_sigma is not None:
        limits["scale_error_max"] = round(float(np.sqrt(3.0)) * entry.plan.prior_k_sigma, 4)
    return limits


def _check_numbers(args: argparse.Namespace) -> None:
    from canimucal.errors import InputError

    if args.seconds is not None and not args.seconds > 0:
        raise InputError(f"--seconds must be positive, got {args.seconds}")
    if not args.time_scale > 0:
        raise InputError(f"--time-scale must be positive, got {args.time_scale}")
    vehicle_size_from_args(args)  # a length that is not one: exit 2 before any work


def run(args: argparse.Namespace) -> int:
    """Run the demo and print the comparison of the read-back values with the truth."""
    check_outputs(args)
    _check_numbers(args)
    if args.plan is None:  # --resume goes on with the plan its recording names
        args.plan = recorded_plan(args.resume).name if args.resume else DEFAULT_PLAN
    plan = resolve_plan(args.plan)
    plan_name = plan.name if plan.name in builtin_names() else CUSTOM
    truths = _truths(args)
    out = make_directory(args.resume or args.out)
    if args.resume:  # a different plan or an unreadable recording: exit 2 before any work
        load_resume_state(out, plan)
    if not args.headless and _terminal():
        return _run_tui(args, plan, plan_name, truths, out)
    if not args.headless:
        print("note: no terminal; running the headless demo", file=sys.stderr)
    policy = AveragingPolicy(fixed_s=args.seconds)
    verify_s = min(args.seconds, 10.0) if args.seconds else 10.0
    settings = demo_settings(truths, time_scale=args.time_scale, seed=args.seed + 1)
    with open_devices(settings) as rig:
        session = rig.session(
            plan,
            out,
            plan_name=plan_name,
            limits=user_acceptance().limits(plan_name),
            gyro=args.gyro,
            gyro_g=args.gyro_g,
            averaging=policy,
            warmup=False,
            verify_seconds=verify_s,
            resume=bool(args.resume),
            overwrite=True,
            operator=args.operator,
            site_name=args.site,
            vehicle_size=vehicle_size_from_args(args),
            remember_size=False,
        )
        resumed = session.procedure.config.resume_from
        if resumed is not None:
            print(resumed_message(resumed), file=sys.stderr)
        history = run_automatic(session, write_anyway=True, deadline_s=_deadline_s(plan, args))
        truth_by_node = dict(rig.truths)
    documents, report = _results(session, history, truth_by_node, out)
    if _cancelled(history):
        return _report_cancelled(args, history, report, out)
    several = {"schema": DEMO_NODES_SCHEMA, "nodes": documents}
    document: Any = next(iter(documents.values())) if len(documents) == 1 else several
    emit(args, document, report)
    return 0 if all("readback" in d for d in documents.values()) else 3


def _cancelled(history: list[ev.Event]) -> bool:
    return any(isinstance(e, ev.ProcedureFinished) and e.cancelled for e in history)


def _report_cancelled(
    args: argparse.Namespace, history: list[ev.Event], report: str, out: Path
) -> int:
    """Tell why a session was cancelled (stderr), write no calibration JSON, return 130.

    The exit status of an interrupted session (docs/design.md §7): what was recorded is kept
    in ``out``; nothing was written to the node.
    """
    refusals = [e for e in history if isinstance(e, ev.PoseRefused)]
    why = f" (last refusal: {refusals[-1].message})" if refusals else ""
    if args.json != "-":
        print(report)
    print(
        f"error: procedure cancelled{why}; no calibration written, the recording is kept in {out}",
        file=sys.stderr,
    )
    return EXIT_INTERRUPTED


def _deadline_s(plan: Plan, args: argparse.Namespace) -> float:
    """Return the wall seconds after which the automatic operator gives up.

    Four times the sample time the plan needs (at most 120 s a position, settling, the two
    verification poses) at the time scale, plus two minutes.
    """
    per_position_s = (args.seconds or 120.0) + 10.0
    sample_s = (len(plan.positions) + 2) * per_position_s
    return 120.0 + 4.0 * sample_s / args.time_scale


def _terminal() -> bool:
    """Whether stdin and stdout are a terminal (the TUI needs one)."""
    return sys.stdin is not None and sys.stdin.isatty() and sys.stdout.isatty()


def _run_tui(
    args: argparse.Namespace, plan: Plan, plan_name: str, truths: list[Truth], out: Path
) -> int:
    """Open the TUI on a demo source; files go to ``out``."""
    from canimucal.tui.app import make_app
    from canimucal.tui.source import demo_source

    seconds = args.seconds
    source = demo_source(truths, out, time_scale=args.time_scale, seed=args.seed + 1)
    source.seconds = seconds
    source.verify_seconds = min(seconds, 10.0) if seconds else 10.0
    source.acceptance = user_acceptance()
    source.resume = bool(args.resume)
    source.operator, source.site_name = args.operator, args.site
    source.gyro_g = args.gyro_g
    source.vehicle_size, source.remember_size = vehicle_size_from_args(args), False
    custom = plan if plan_name == CUSTOM else None
    app = make_app(source, plan_name=plan_name, gyro=args.gyro, custom_plan=custom)
    try:
        app.run()
    finally:
        source.close()
    print(f"demo files in {out}")
    return int(app.return_code or 0)


def _results(
    session: Session, history: list[ev.Event], truths: dict[int, Truth], out: Path
) -> tuple[dict[str, Any], str]:
    lines = [_narrative(e) for e in history]
    lines = [line for line in lines if line]
    documents: dict[str, Any] = {}
    for node_id, link in session.links.items():
        truth_path = output_name(out, "truth", node_id, session.several, ".json")
        write_text_atomic(truth_path, dumps(truths[node_id].to_dict()), overwrite=True)
        if link.record_path is None:
            continue
        record = json.loads(link.record_path.read_text())
        documents[str(node_id)] = record
        verdict = session.verification_verdict(node_id)
        if verdict:
            lines.append(f"node {node_id} verification: {verdict}")
        lines += [f"node {node_id} (serial {link.identity.serial}): read back from the device"]
        lines.append(comparison_table(readback_deviations(record, truths[node_id])))
        lines.append(f"wrote {link.record_path}, {link.certificate_path}, {truth_path}")
    return documents, "\n".join(lines)


def _narrative(event: ev.Event) -> str:
    """One line per event worth telling (None for the rest)."""
    if isinstance(event, ev.PoseInstructed):
        words = event.words.replace("\n", " ")  # one step a line in the TUI, one line here
        if event.verification:
            return f"{words} ({event.seconds:g} s)"
        return f"position {event.index + 1}/{event.total}: {words} ({event.seconds:g} s)"
    if isinstance(event, ev.PositionAveraged):
        parts = [f"n={a.n} lost={a.lost}" for a in event.averages.values()]
        return f"  averaged position {event.index + 1}: " + ", ".join(parts)
    if isinstance(event, ev.PositionRejected | ev.PoseRefused):
        text = event.reason if isinstance(event, ev.PositionRejected) else event.message
        return f"  position {event.index + 1} rejected: {text}"
    if isinstance(event, ev.AveragingTimeChosen):
        return f"  averaging time {event.describe()}"
    if isinstance(event, ev.Solved):
        verdicts = [
            f"node {n}: " + ("passed" if a.passed else "NOT passed (demo writes anyway)")
            for n, a in event.acceptance.items()
        ]
        return "solved; acceptance limits " + "; ".join(verdicts)
    if isinstance(event, ev.WriteFinished):
        return f"write node {event.node_id}: {event.message}"
    if isinstance(event, ev.LevelChecked):
        return (
            f"level check node {event.node_id} ({event.stage}): |f|-g nominal "
            f"{event.norm_error_nominal_ms2:+.4f} m/s², calibrated "
            f"{event.norm_error_calibrated_ms2:+.4f} m/s²; tilt calibrated "
            f"{event.tilt_calibrated_deg[0]:+.3f}°, {event.tilt_calibrated_deg[1]:+.3f}°"
        )
    if isinstance(event, ev.PoseVerified):
        return f"  {verified_line(event)}"
    if isinstance(event, ev.ProcedureFinished) and event.cancelled:
        return "procedure cancelled"
    return ""
