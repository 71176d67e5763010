"""The model flags shared by `solve` and `plan`: --model, --tilt, --tilt-model, --gyro, --gyro-g."""

from __future__ import annotations

import argparse

from canimucal.errors import InputError
from canimucal.model.layout import GyroSpec, JointSpec


def add_model_options(parser: argparse.ArgumentParser, *, default_tilt: bool) -> None:
    """Add the flags that choose the joint model."""
    parser.add_argument(
        "--model",
        choices=("diag", "full"),
        default="diag",
        help="scale factors only (diag) or with cross-axis terms (full); applies to K and S",
    )
    tilt = parser.add_mutually_exclusive_group()
    tilt.add_argument(
        "--tilt",
        dest="tilt",
        action="store_true",
        default=default_tilt,
        help="estimate the base tilt" + (" (default)" if default_tilt else ""),
    )
    tilt.add_argument("--no-tilt", dest="tilt", action="store_false", help="assume a level base")
    parser.add_argument(
        "--tilt-model",
        choices=("rigid", "additive"),
        default="rigid",
        help="rigid tilted base (DESIGN §2) or the paper's added angles (eq. 15)",
    )
    parser.add_argument(
        "--gyro",
        choices=("none", "mems", "moves", "nav"),
        default=None,
        help="gyro model: bias only (mems), bias and full S from the moves (moves), or bias "
        "and scale from Earth rate (nav)",
    )
    parser.add_argument("--gyro-g", action="store_true", help="estimate the gyro g-sensitivity")
    parser.add_argument(
        "--latitude-deg", type=float, help="latitude (degrees; needed for --gyro nav)"
    )


def spec_from_args(args: argparse.Namespace, *, has_gyro: bool = False) -> JointSpec:
    """Build the :class:`JointSpec` the flags ask for."""
    gyro: GyroSpec = (
        "mems" if args.gyro == "moves" else args.gyro or ("mems" if has_gyro else "none")
    )
    if gyro == "nav" and args.latitude_deg is None:
        raise InputError("--gyro nav needs --latitude-deg (the gyro scale comes from Earth rate)")
    return JointSpec(
        accel_k=args.model,
        tilt=args.tilt_model if args.tilt else "none",
        gyro=gyro,
        gyro_s=args.model,
        gyro_g=bool(args.gyro_g),
    )
