"""The model flags shared by `solve` and `plan`: --model, --tilt, --tilt-model, --gyro, --gyro-g."""

from __future__ import annotations

import argparse

from canimucal.analysis.session_model import ModelChoice
from canimucal.model.layout import JointSpec


def add_model_options(
    parser: argparse.ArgumentParser,
    *,
    default_tilt: bool | None,
    default_model: str | None = "diag",
) -> None:
    """Add the flags that choose the joint model.

    ``default_tilt`` and ``default_model`` None: each flag left out reads None, for the
    caller to fill in (``plan``: the model the plan's session fits).
    """
    session = " (default: what the plan's session fits)"
    parser.add_argument(
        "--model",
        choices=("diag", "full"),
        default=default_model,
        help="scale factors only (diag) or with cross-axis terms (full); applies to K and S"
        + (session if default_model is None else ""),
    )
    tilt = parser.add_mutually_exclusive_group()
    tilt.add_argument(
        "--tilt",
        dest="tilt",
        action="store_true",
        default=default_tilt,
        help="estimate the base tilt"
        + (session if default_tilt is None else " (default)" if default_tilt else ""),
    )
    tilt.add_argument("--no-tilt", dest="tilt", action="store_false", help="assume a level base")
    parser.add_argument(
        "--tilt-model",
        choices=("rigid", "additive"),
        default="rigid",
        help="rigid tilted base (docs/design.md §2) or the paper's added angles (eq. 15)",
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


def choice_from_args(args: argparse.Namespace) -> ModelChoice:
    """Build the :class:`ModelChoice` the flags ask for."""
    return ModelChoice(
        model=args.model,
        tilt=args.tilt,
        tilt_model=args.tilt_model,
        gyro=args.gyro,
        gyro_g=bool(args.gyro_g),
        latitude_deg=args.latitude_deg,
        g=getattr(args, "g", None),
        tolerance_deg=getattr(args, "tolerance_deg", None),
        prior_k_sigma=getattr(args, "prior_k_sigma", None),
        prior_k=getattr(args, "prior_k", None),
    )


def spec_from_args(args: argparse.Namespace, *, has_gyro: bool = False) -> JointSpec:
    """Build the :class:`JointSpec` the flags ask for."""
    return choice_from_args(args).spec(has_gyro=has_gyro)
