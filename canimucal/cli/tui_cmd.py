"""`canimucal tui` (and `canimucal` with no subcommand): the guided calibration in the TUI.

The bus flags are those of every device command (:mod:`canimucal.cli.bus_options`);
``--sim`` attaches the built-in simulated IMU (confirming a pose then moves it). The site
(``--g`` or ``--latitude-deg``/``--height-m`` for normal gravity, ``--heading-deg``) goes
into the records; without ``--site``, ``--latitude-deg`` and ``--g`` the TUI asks operator
and site before the first position, offering the last answer (g is never assumed); files go
to ``--out``. Textual is imported only when the TUI runs.
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from canimucal.cli.bus_options import add_bus_options, device_settings, node_ids
from canimucal.cli.vehicle_options import add_vehicle_size_options, vehicle_size_from_args
from canimucal.errors import InputError
from canimucal.io.mounting import BODY
from canimucal.io.plans import resolve_plan
from canimucal.model.gravity import normal_gravity
from canimucal.model.mounting import MountingMap
from canimucal.model.positions import Plan
from canimucal.model.vocabulary.plans import CUSTOM, DEFAULT_PLAN, builtin_names, plan_help
from canimucal.user_dirs import state_dir

if TYPE_CHECKING:
    from canimucal.tui.source import DeviceSource

log = logging.getLogger(__name__)


def add_subparser(subparsers: Any) -> None:
    """Register ``tui``."""
    p = subparsers.add_parser(
        "tui",
        help="the guided calibration in the terminal UI (also: canimucal with no command)",
        description="Connect to the IMU node(s), choose a plan, follow the guided procedure, "
        "review the result and write it transactionally.",
    )
    add_bus_options(p)
    p.add_argument(
        "--plan",
        help=plan_help() + f" (default {DEFAULT_PLAN}; with --resume, the recording's)",
    )
    p.add_argument("--gyro", choices=("mems", "nav"), default="mems", help="gyro grade")
    p.add_argument(
        "--gyro-g",
        action="store_true",
        help="also estimate the gyro's g-sensitivity G from the static positions (where the "
        "plan's positions determine it, e.g. five or recommended) and write it",
    )
    p.add_argument("--out", default="canimucal-out", help="directory for records and recordings")
    p.add_argument("--backup-dir", help="where device backups go (default: XDG state dir)")
    p.add_argument("--g", type=float, help="local gravity, m/s² (else from latitude and height)")
    p.add_argument("--latitude-deg", type=float, help="latitude, degrees (nav gyro needs it)")
    p.add_argument("--height-m", type=float, default=0.0, help="height above the ellipsoid, m")
    p.add_argument("--heading-deg", type=float, default=0.0, help="azimuth of body z, degrees")
    p.add_argument("--seconds", type=float, help="averaging seconds of every position")
    p.add_argument("--operator", help="operator's name, for the certificate")
    p.add_argument("--site", help="where the calibration was done, for the certificate")
    p.add_argument("--no-warmup", action="store_true", help="do not wait for warm-up")
    p.add_argument(
        "--mount",
        metavar="MAP",
        help="how the unit sits in the vehicle, e.g. x=forward,y=down,z=left (each unit axis: "
        "forward, back, left, right, up or down); saved for the unit's serial when none is; "
        "'body' words the instructions in the unit's axes",
    )
    p.add_argument(
        "--replace-mount",
        action="store_true",
        help="replace the mounting map (and the vehicle size) saved for the unit's serial "
        "with --mount's (and --wheelbase's, --track's)",
    )
    add_vehicle_size_options(p)
    p.add_argument(
        "--prior-k",
        metavar="FILE",
        help="factory K for a plan that holds K at a prior (a calibration JSON or read-params "
        "--json output); default: the K the node applies now, read from 0x2101 (or 0x2010:01)",
    )
    p.add_argument(
        "--prior-k-sigma",
        type=float,
        help="relative 1σ of that K (default: the plan's, 0.01 for vehicle)",
    )
    p.add_argument(
        "--resume",
        metavar="DIR",
        help="go on with the interrupted session in DIR (its plan unless --plan; its files "
        "go to DIR)",
    )
    p.set_defaults(run=run)


def asks_site(args: argparse.Namespace) -> bool:
    """Return whether the TUI asks operator and site first (no flag gave the site)."""
    return args.g is None and args.latitude_deg is None and args.site is None


def _site(args: argparse.Namespace) -> Any:
    from canimucal.analysis.calibrate import SiteConditions

    if asks_site(args):
        return None  # the TUI asks (g is never assumed)
    latitude = None if args.latitude_deg is None else float(np.deg2rad(args.latitude_deg))
    if args.g is not None:
        g = float(args.g)
    elif latitude is not None:
        g = normal_gravity(latitude, args.height_m)
    else:  # --site without --g or --latitude-deg: the named site's g is not known
        raise InputError(
            f"--site {args.site!r} needs --g or --latitude-deg (g is never assumed); "
            "without the three flags the TUI asks"
        )
    if args.gyro == "nav" and latitude is None:
        raise InputError("--gyro nav needs --latitude-deg (the Earth rate depends on it)")
    return SiteConditions(
        g=g,
        latitude=latitude,
        heading=float(np.deg2rad(args.heading_deg)),
        height_m=args.height_m,
    )


def _where(args: argparse.Namespace) -> str:
    if args.sim:
        return "simulated IMU (in-process virtual bus)"
    parts = [args.interface or "python-can default interface", args.channel or ""]
    return " ".join(p for p in parts if p) + f" · nodes {', '.join(map(str, node_ids(args)))}"


def plan_choice(name_or_path: str) -> tuple[Plan, str]:
    """Return the plan ``--plan`` names and its name in the TUI (a built-in's, else custom)."""
    plan = resolve_plan(name_or_path)
    return plan, plan.name if plan.name in builtin_names() else CUSTOM


def device_source(args: argparse.Namespace) -> DeviceSource:
    """Return the TUI's source of nodes and sessions the flags describe (nothing opened yet)."""
    from canimucal.cli.user_config import user_acceptance
    from canimucal.io.site_memory import LAST_SITE_FILE
    from canimucal.tui.source import DeviceSource

    if args.seconds is not None and not args.seconds > 0:
        raise InputError(f"--seconds must be positive, got {args.seconds}")
    size = vehicle_size_from_args(args)
    if args.replace_mount and args.mount in (None, BODY) and size is None:
        raise InputError("--replace-mount needs --mount MAP or --wheelbase/--track (what to save)")
    if args.prior_k_sigma is not None and not args.prior_k_sigma > 0:
        raise InputError(f"--prior-k-sigma must be > 0, got {args.prior_k_sigma:g}")
    if args.prior_k is not None:
        from canimucal.analysis.session_model import read_factory_k

        read_factory_k(args.prior_k)  # a bad file: exit 2 before the TUI opens
    return DeviceSource(
        device_settings(args, find=False),
        Path(args.resume or args.out),
        _where(args),
        site=_site(args),
        backup_dir=Path(args.backup_dir) if args.backup_dir else None,
        warmup=not args.no_warmup,
        seconds=args.seconds,
        operator=args.operator,
        site_name=args.site,
        resume=bool(args.resume),
        mount=mount_choice(args.mount),
        replace_mount=args.replace_mount,
        vehicle_size=size,
        prior_k=args.prior_k,
        prior_k_sigma=args.prior_k_sigma,
        gyro_g=bool(args.gyro_g),
        acceptance=user_acceptance(),
        ask_site=asks_site(args),
        last_site_file=state_dir() / LAST_SITE_FILE,
        heading=float(np.deg2rad(args.heading_deg)),
    )


def mount_choice(text: str | None) -> MountingMap | str | None:
    """Return ``--mount`` parsed: a map, ``"body"`` or None (a bad map is exit 2 here)."""
    if text is None or text.strip().lower() == BODY:
        return None if text is None else BODY
    return MountingMap.parse(text)


def run(args: argparse.Namespace) -> int:
    """Open the TUI on the bus the flags name."""
    from canimucal.runtime.resume import load_resume_state, recorded_plan
    from canimucal.tui.app import make_app

    if args.plan is None:  # --resume goes on with the plan its recording names
        args.plan = recorded_plan(args.resume).name if args.resume else DEFAULT_PLAN
    plan, plan_name = plan_choice(args.plan)
    if args.resume:  # a different plan or an unreadable recording: exit 2 before the TUI
        load_resume_state(args.resume, plan)
    source = device_source(args)
    custom = plan if plan_name == CUSTOM else None
    app = make_app(source, plan_name=plan_name, gyro=args.gyro, custom_plan=custom)
    try:
        app.run()
    finally:
        source.close()
    return int(app.return_code or 0)
