"""`canimucal record OUT.csv`: record one position or a whole plan into the recording CSV.

One position: ``--position I --alpha-deg A --beta-deg B [--psi-deg P] --seconds S``
(``--append`` adds it to an existing recording). A whole plan: ``--plan P`` prompts the
operator pose by pose on stdin, or, with ``--sim`` or ``--follow-schedule``, follows the
pose schedule the unit runs by itself from the NMT start (``canimucal sim --poses P``).
Ctrl-C keeps what was recorded (exit 130). Several ``--node-id``: ``OUT.node<ID>.csv``.
``--can-log FILE`` (may repeat) also writes every frame of the bus, received and sent, through
python-can's writer for the file's suffix (:mod:`canimucal.device.bus_log`); ``import-log``
turns such a log back into a recording.
A plan that holds K at a prior (``vehicle``) records the K each node applies now (read from
the node, :func:`canimucal.device.factory_k.device_k`) in the header, for ``solve``.
"""

from __future__ import annotations

import argparse
import contextlib
import math
import sys
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from canimucal.cli.bus_options import add_bus_options, node_ids, open_from_args
from canimucal.cli.vehicle_options import add_vehicle_size_options, vehicle_size_from_args
from canimucal.device.log_formats import check_log_target
from canimucal.errors import DeviceError, InputError
from canimucal.io.atomic import per_node_path, refuse_existing
from canimucal.io.plans import resolve_plan
from canimucal.io.recording import HeaderValue
from canimucal.io.recording_writer import RecordingWriter
from canimucal.model.mounting import MountingMap
from canimucal.model.positions import DEFAULT_SECONDS, Plan, PlannedPosition
from canimucal.model.vehicle_size import VehicleSize
from canimucal.model.vocabulary.plans import CUSTOM, builtin_names, plan_help
from canimucal.sim.schedule import set_by_operator
from canimucal.sim.truth import Truth

if TYPE_CHECKING:
    from canimucal.device.client import ImuClient
    from canimucal.runtime.recorder import NodeTally, Recorder
    from canimucal.runtime.wiring import Devices

POSE_TRANSIENT_S = 1.0
"""Default move time between scheduled poses, as ``sim_node.POSE_TRANSIENT_S``."""
GUARD_S = 0.5
"""Scheduled samples this close to a move stay unlabelled (``recorder.DEFAULT_GUARD_S``)."""


def add_subparser(subparsers: Any) -> None:
    """Register ``record``."""
    p = subparsers.add_parser(
        "record",
        help="record one position or a whole plan from the IMU node(s)",
        description="Record raw samples into the recording CSV (docs/design.md §5), labelled by "
        "position: one position, or a whole plan pose by pose.",
    )
    p.add_argument("output", help="recording CSV to write")
    what = p.add_mutually_exclusive_group(required=True)
    what.add_argument("--position", type=int, metavar="I", help="index of this position")
    what.add_argument("--plan", metavar="P", help=plan_help())
    p.add_argument("--alpha-deg", type=float, help="tilt alpha of the position (deg)")
    p.add_argument("--beta-deg", type=float, help="tilt beta of the position (deg)")
    p.add_argument("--psi-deg", type=float, default=0.0, help="turn psi (deg, default 0)")
    p.add_argument("--seconds", type=float, help="seconds per position (default: the plan's)")
    p.add_argument("--append", action="store_true", help="add the position to OUT.csv")
    p.add_argument("--overwrite", action="store_true", help="replace OUT.csv if it exists")
    p.add_argument(
        "--gyro-g",
        action="store_true",
        help="name the gyro's g-sensitivity G in the header (gyro_g), so that solve estimates "
        "it where the positions determine it",
    )
    p.add_argument(
        "--follow-schedule",
        action="store_true",
        help="the unit follows the plan by itself from NMT start (sim --poses): no prompts",
    )
    p.add_argument(
        "--settle-s", type=float, default=1.5, help="seconds skipped after each pose is set"
    )
    p.add_argument(
        "--no-pose-check",
        action="store_true",
        help="record without checking that the unit is at each pose (5° first, then 3°)",
    )
    p.add_argument(
        "--can-log",
        action="append",
        metavar="FILE",
        help="also write the raw bus traffic to FILE through python-can's writer for its "
        "suffix (.log candump, .asc, .blf, .trc, .csv, .db, .mf4; .gz compresses text "
        "formats); may repeat",
    )
    p.add_argument(
        "--transient-s",
        type=float,
        default=POSE_TRANSIENT_S,
        help=f"move time between scheduled poses (default {POSE_TRANSIENT_S:g} s)",
    )
    p.add_argument(
        "--mount",
        metavar="MAP",
        help="how the unit sits in the vehicle (x=forward,y=down,z=left; 'body': the unit's "
        "axes): --plan's poses are then worded for the vehicle, as the vehicle plan is by "
        "default (the map saved for the unit's serial, else that default)",
    )
    add_vehicle_size_options(p)
    add_site_options(p)
    add_bus_options(p)
    p.set_defaults(run=run)


SITE_KEYS = ("g", "latitude_deg", "height_m", "heading_deg")
"""The recording header's site keys, each a flag (``--latitude-deg``)."""


def add_site_options(parser: argparse.ArgumentParser) -> None:
    """``--g``, ``--latitude-deg``, ``--height-m``, ``--heading-deg``: the header's site."""
    site = parser.add_argument_group("site (recording header)")
    site.add_argument("--g", type=float, help="local gravity, m/s²")
    site.add_argument("--latitude-deg", type=float, help="latitude (deg)")
    site.add_argument("--height-m", type=float, help="height (m)")
    site.add_argument("--heading-deg", type=float, help="azimuth of body z (deg)")


def site_flags(args: argparse.Namespace) -> dict[str, float]:
    """Return the site the flags give (finite numbers; the header checks ranges)."""
    site = {key: getattr(args, key) for key in SITE_KEYS}
    for key, value in site.items():
        _finite("--" + key.replace("_", "-"), value)
    return {key: float(value) for key, value in site.items() if value is not None}


def _finite(name: str, value: float | None) -> None:
    if value is not None and not math.isfinite(value):
        raise InputError(f"{name} must be a finite number, got {value}")


def check_args(args: argparse.Namespace) -> Plan:
    """Check the flags and outputs before connecting; return the plan to record."""
    for name in ("alpha_deg", "beta_deg", "psi_deg", "seconds", "settle_s", "transient_s"):
        _finite("--" + name.replace("_", "-"), getattr(args, name))
    if args.seconds is not None and args.seconds <= 0:
        raise InputError(f"--seconds must be > 0, got {args.seconds:g}")
    if args.settle_s < 0 or args.transient_s < 0:
        raise InputError("--settle-s and --transient-s must be ≥ 0")
    if args.append and args.overwrite:
        raise InputError("--append and --overwrite exclude each other")
    vehicle_size_from_args(args)  # a length that is not one, or a bad map: exit 2 here
    if args.mount is not None and args.mount.strip().lower() != "body":
        MountingMap.parse(args.mount)
    if args.position is not None:
        plan = _single_position_plan(args)
    else:
        if args.append:
            raise InputError("--append records one position (--position), not a plan")
        plan = resolve_plan(args.plan)
        if args.seconds is not None:
            plan = plan.with_total_seconds(args.seconds * len(plan.positions))
    logs = [Path(p) for p in args.can_log or ()]
    if len(set(logs)) != len(logs):
        raise InputError("--can-log names the same file twice")
    for log in logs:  # a log is never appended to, with --append neither
        check_log_target(log, overwrite=args.overwrite)
    ids = node_ids(args)
    for nid in ids:
        path = per_node_path(args.output, nid, len(ids) > 1)
        if args.append:
            if not path.is_file():
                raise InputError(f"cannot append: {path} does not exist")
        else:
            refuse_existing(path, overwrite=args.overwrite)
    return plan


def _single_position_plan(args: argparse.Namespace) -> Plan:
    if args.position < 0:
        raise InputError(f"--position must be ≥ 0, got {args.position}")
    if args.alpha_deg is None or args.beta_deg is None:
        raise InputError("--position needs --alpha-deg and --beta-deg")
    seconds = args.seconds if args.seconds is not None else DEFAULT_SECONDS
    alpha, beta, psi = np.deg2rad([args.alpha_deg, args.beta_deg, args.psi_deg])
    return Plan(CUSTOM, (PlannedPosition(alpha, beta, psi, seconds=seconds),))


def header_for(
    client: ImuClient, args: argparse.Namespace, truth: Truth | None
) -> dict[str, HeaderValue]:
    """Build the header: rate, node, serial, nominal LSBs, site (flags, else the sim truth)."""
    accel_lsb, gyro_lsb = client.nominal_lsb()
    header: dict[str, HeaderValue] = {
        "sample_rate_hz": float(client.output_data_rate()),
        "node_id": client.node_id,
        "device_serial": client.identity().serial,
        "accel_lsb": accel_lsb,
        "gyro_lsb": gyro_lsb,
    }
    site = {
        "g": args.g,
        "latitude_deg": args.latitude_deg,
        "height_m": args.height_m,
        "heading_deg": args.heading_deg,
    }
    if truth is not None:  # the simulated unit's site, unless the flags say otherwise
        known = {
            "g": truth.g,
            "latitude_deg": float(np.rad2deg(truth.latitude)),
            "heading_deg": float(np.rad2deg(truth.heading)),
        }
        site = {k: (v if v is not None else known.get(k)) for k, v in site.items()}
    header.update({k: float(v) for k, v in site.items() if v is not None})
    return header


def run(args: argparse.Namespace) -> int:
    """Record and report."""
    from canimucal.device.bus import default_sdo_timeout_s
    from canimucal.runtime.recorder import Recorder
    from canimucal.runtime.session import k_prior_header

    plan = check_args(args)
    with open_from_args(args) as session, contextlib.ExitStack() as files:
        session.refuse_second_answerers("nothing recorded")  # before any file is made
        several = len(session.clients) > 1
        channels = []
        # a plan that holds K at a prior: the K each node applies now, for solve (docs/design.md §3)
        priors = session.k_priors(plan) if args.position is None else {}
        for nid, client in session.clients.items():
            header = header_for(client, args, session.truths.get(nid))
            if args.position is None:  # a whole plan: name it and its tolerance (docs/design.md §5)
                header["plan"] = plan.name
                tolerance = max(p.tolerance for p in plan.positions)
                header["tolerance_deg"] = round(float(np.rad2deg(tolerance)), 10)
                if nid in priors:
                    lsb = float(header["accel_lsb"])
                    header.update(k_prior_header(priors[nid], plan, lsb))
            if args.gyro_g:  # solve then estimates G, as after such a session (docs/design.md §5)
                header["gyro_g"] = True
            path = per_node_path(args.output, nid, several)
            writer = RecordingWriter.open(
                path, header, overwrite=args.overwrite, append=args.append
            )
            files.enter_context(writer)
            channels.append((client, writer, float(header["sample_rate_hz"])))
        # a node silent for 10 SDO timeouts has stopped (5 s; 20 s in the slow CAN VM)
        idle_s = 10.0 * (args.sdo_timeout or default_sdo_timeout_s())
        # the rate a device claims is checked against its samples' arrival; never the built-in
        # simulated node's: its claim is exact in simulated time, and its clock runs scaled,
        # or slower than the wall on a host that lags, so its arrival rate says nothing
        recorder = Recorder(channels, idle_timeout_s=idle_s, check_rate=not args.sim)
        try:
            _record(args, session, recorder, plan)
        except DeviceError:
            recorder.stop()
            if not any(w.rows_written for _, w, _ in channels):  # refused before any row:
                for _, writer, _ in channels:  # no header-only file, no "wrote 0 rows"
                    writer.discard()
            raise
        finally:
            try:
                recorder.stop()
            finally:
                writers = [w for _, w, _ in channels]
                if not any(w.failed or w.discarded for w in writers):
                    print(report(recorder.tallies, [w.path for w in writers]), end="")
    if session.bus_log_failures:  # known once the devices are closed
        raise InputError("; ".join(session.bus_log_failures))
    for path, frames in session.bus_log.written if session.bus_log else ():
        print(f"bus log: wrote {frames} frames to {path}")
    return 0


def _record(args: argparse.Namespace, session: Devices, recorder: Recorder, plan: Plan) -> None:
    scheduled = args.position is None and (args.sim or args.follow_schedule)
    if session.sim_nodes:  # the operator's hands, in-process: each pose set within its 1σ
        placed = set_by_operator(plan, np.random.default_rng(args.seed))
    for node in session.sim_nodes.values():  # one rigid body: the same pose errors for all
        if scheduled:
            node.set_schedule(placed)
        elif args.position is not None:
            first = placed.positions[0]
            node.set_pose(first.alpha, first.beta, first.psi)
    recorder.start()
    if args.position is not None:
        settle = args.settle_s
        if not args.no_pose_check:
            checks = recorder.check_pose(plan.positions[0], settle_s=args.settle_s)
            bad = [c.message() for c in checks if not c.passed]
            if bad:
                raise InputError(
                    f"position {args.position} refused: {bad[0]} (--no-pose-check to record "
                    "it anyway)"
                )
            settle = 0.0
        recorder.record_pose(args.position, plan.positions[0], settle_s=settle)
    elif scheduled:
        print(f"following the unit's schedule: {len(plan.positions)} positions", flush=True)
        recorder.record_scheduled(plan, transient_s=args.transient_s, guard_s=GUARD_S)
    else:
        refused = None if args.no_pose_check else _refused
        prompt = _prompter(*_wording(args, session, plan))
        recorder.record_prompted(plan, prompt, settle_s=args.settle_s, refused=refused)


def _wording(
    args: argparse.Namespace, session: Devices, plan: Plan
) -> tuple[MountingMap | None, VehicleSize | None]:
    """Return the map and size that word the prompts, chosen as a session chooses them."""
    from canimucal.io.mounting import BODY, choose_vehicle_size
    from canimucal.runtime.wiring import instruction_mounting

    serial = next(iter(session.identities().values())).serial
    name = plan.name if plan.name in builtin_names() else CUSTOM
    text = args.mount.strip() if args.mount is not None else None
    mount = BODY if text is not None and text.lower() == BODY else text
    mounting, note = instruction_mounting(name, serial, mount, False)
    if mounting is None:
        return None, None
    sized = choose_vehicle_size(serial, vehicle_size_from_args(args))
    for line in (note, sized.note):
        if line:
            print(f"note: {line}", flush=True)
    return mounting, sized.size


def _prompter(
    mounting: MountingMap | None, size: VehicleSize | None
) -> Callable[[int, PlannedPosition], None]:
    """Return the prompt of each pose: its angles, and for a vehicle the TUI's words."""
    from canimucal.procedure.posecheck import describe_pose

    def prompt(index: int, position: PlannedPosition) -> None:
        alpha, beta, psi = np.rad2deg(position.angles)
        angles = f"alpha {alpha:g} beta {beta:g} psi {psi:g} deg"
        if mounting is None:
            what = f"put the unit at {angles}"
        else:
            words = " ".join(describe_pose(position, mounting, size).split())
            what = f"{words} ({angles})"
        print(f"position {index}: {what}, press Enter ({position.seconds:g} s)", flush=True)
        if not sys.stdin.readline():
            raise InputError("no operator input: stdin closed (use --follow-schedule or --sim)")

    return prompt


def _refused(index: int, why: str) -> None:
    print(f"position {index} refused, not recorded: {why}; set the pose again", flush=True)


SECOND_TRIGGER_ADVICE = (
    "the node sends its samples twice (a second send trigger, e.g. a TPDO event timer beside "
    "data-ready sending: set 0x1800:05 and 0x1801:05 to 0, docs/firmware.md §4)"
)


def report(tallies: list[NodeTally], paths: list[Path]) -> str:
    """Rows, labelled rows, losses and the TPDO timer skew per node."""
    lines = []
    for tally, path in zip(tallies, paths, strict=True):
        skew = "not measured" if tally.skew_ppm is None else f"{tally.skew_ppm:+.0f} ppm"
        if tally.second_trigger:
            skew = f"not measured: {SECOND_TRIGGER_ADVICE}"
        sends = f", {tally.duplicate_sends} duplicate sends" if tally.duplicate_sends else ""
        lines.append(
            f"node {tally.node_id}: wrote {tally.rows} rows to {path} ({tally.labelled} in "
            f"positions); lost {tally.lost_samples} samples, {tally.lost_accel} accel and "
            f"{tally.lost_gyro} gyro halves; {tally.duplicates} duplicate, {tally.late} late"
            f"{sends}; timer skew {skew}"
        )
    return "\n".join(lines) + "\n"
