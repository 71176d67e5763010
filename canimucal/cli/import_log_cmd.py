"""`canimucal import-log LOG --out REC.csv`: one IMU node's recording out of a CAN bus log.

Any log python-can reads (candump ``.log``, ``.asc``, ``.blf``, ``.trc``, python-can's
``.csv``/``.db``, ``.mf4`` with asammdf): the node's TPDOs are paired by the client's own
decoder, its positions found by stillness (named after ``--plan``'s positions in order, each
pose-checked as ``record`` checks it) or by the plan's schedule (``--follow-schedule``), and
the header filled from what the log shows (:mod:`canimucal.runtime.log_import`). Prints what
was found, the losses and duplicates, and where each header value came from.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path
from typing import Any

from canimucal.cli.input_options import add_log_options
from canimucal.cli.record_cmd import GUARD_S, POSE_TRANSIENT_S, add_site_options, site_flags
from canimucal.device.log_formats import FORMAT_NAMES
from canimucal.errors import InputError
from canimucal.io.atomic import refuse_existing
from canimucal.io.plans import resolve_plan
from canimucal.io.recording_writer import write_recording
from canimucal.runtime.log_import import LogImport, import_bus_log


def add_subparser(subparsers: Any) -> None:
    """Register ``import-log``."""
    p = subparsers.add_parser(
        "import-log",
        help="turn a CAN bus log into a recording CSV",
        description="Decode one IMU node's samples from a CAN bus log (any format python-can "
        "reads: " + ", ".join(f"{s} {n}" for s, n in FORMAT_NAMES.items()) + ") into the "
        "recording CSV (docs/design.md §5): lost and duplicate frames counted as the client "
        "counts them live, positions found by stillness (or by the plan's schedule), the "
        "header filled from the log (node id, sample rate, serial, nominal LSBs).",
    )
    p.add_argument("log", help="the bus log")
    p.add_argument("--out", required=True, metavar="REC.csv", help="recording CSV to write")
    p.add_argument("--overwrite", action="store_true", help="replace REC.csv if it exists")
    add_log_options(p.add_argument_group("the node and its positions"))
    p.add_argument(
        "--seconds", type=float, help="seconds per position of the plan (default: the plan's)"
    )
    p.add_argument(
        "--follow-schedule",
        action="store_true",
        help="the unit followed the plan by itself from its NMT start (sim --poses, a rig): "
        "label by the schedule, as record --follow-schedule does, not by stillness",
    )
    p.add_argument(
        "--transient-s",
        type=float,
        default=POSE_TRANSIENT_S,
        help=f"move time between scheduled poses (default {POSE_TRANSIENT_S:g} s)",
    )
    p.add_argument(
        "--no-pose-check",
        action="store_true",
        help="take the still stretches as the plan's positions in order, unchecked",
    )
    p.add_argument(
        "--sample-rate-hz",
        type=float,
        help="the node's sample rate (default: 0x2010:03 in the log, else the log's times)",
    )
    add_site_options(p)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    """Import and report."""
    out = Path(args.out)
    refuse_existing(out, overwrite=args.overwrite)
    plan = resolve_plan(args.plan) if args.plan else None
    if args.seconds is not None:
        if plan is None or not (math.isfinite(args.seconds) and args.seconds > 0):
            raise InputError("--seconds takes a positive number of seconds, with --plan")
        plan = plan.with_total_seconds(args.seconds * len(plan.positions))
    if args.follow_schedule and plan is None:
        raise InputError("--follow-schedule needs the --plan the unit followed")
    if not (math.isfinite(args.transient_s) and args.transient_s >= 0):
        raise InputError(f"--transient-s must be ≥ 0, got {args.transient_s}")
    result = import_bus_log(
        args.log,
        node_id=args.node_id,
        pdo_map=args.pdo_map,
        plan=plan,
        sample_rate_hz=args.sample_rate_hz,
        header=site_flags(args),
        channel=args.log_channel,
        pose_check=not args.no_pose_check,
        follow_schedule=args.follow_schedule,
        transient_s=args.transient_s,
        guard_s=GUARD_S,
    )
    write_recording(out, result.recording, overwrite=args.overwrite)
    print(report(result, str(out)), end="")
    return 0


def report(result: LogImport, out: str) -> str:
    """Say what the import found: rows, positions, losses, where the header came from."""
    block, rec = result.samples.block, result.recording
    labelled = int((rec.position >= 0).sum())
    how = result.sources.get("positions", "stillness")
    lines = [
        f"node {result.node_id}: {result.node_frames} of the {result.frames} frames of "
        f"{rec.source} ({FORMAT_NAMES[result.log_format]}"
        + (f", channel {result.channel}" if result.several_channels else "")
        + ")",
        f"wrote {rec.n_rows} rows to {out} ({labelled} in {result.positions} positions: {how})",
        f"lost {block.lost_samples} samples, {block.lost_accel} accel and {block.lost_gyro} "
        f"gyro halves; {block.duplicates} duplicate, {block.late} late, {block.malformed} "
        f"malformed; {result.samples.reboots} reboots",
    ]
    header = []
    for key in ("sample_rate_hz", "device_serial", "accel_lsb", "gyro_lsb"):
        if key in rec.header:
            source = result.sources.get(key, "")
            header.append(f"{key} {rec.header[key]:g} ({source})" if source else key)
        else:
            header.append(f"{key} not in the log")
    lines.append("header: " + "; ".join(header))
    lines.append(f"PDO mapping: {result.sources.get('mapping', '?')}")
    for stretch in result.stretches:
        if stretch.position < 0:
            lines.append(f"still {stretch.t0:.1f}–{stretch.t1:.1f} s, no position: {stretch.why}")
    return "\n".join(lines) + "\n"
