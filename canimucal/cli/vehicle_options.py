"""``--wheelbase M`` and ``--track M``: the vehicle's size, its tilts worded as heights.

Shared by ``tui``, ``demo`` and ``record``. Either length may be left out (its tilts are then
worded as angles, or the length saved with the unit's mounting map is used,
:func:`canimucal.io.mounting.choose_vehicle_size`).
"""

from __future__ import annotations

import argparse

from canimucal.errors import InputError
from canimucal.model.vehicle_size import VehicleSize


def add_vehicle_size_options(parser: argparse.ArgumentParser) -> None:
    """Add ``--wheelbase`` and ``--track``."""
    parser.add_argument(
        "--wheelbase",
        type=float,
        metavar="M",
        help="front to rear axle, metres: front and rear tilts are worded as heights (raise "
        "the front wheels 0.61 m (10°) on 3.5 m); saved with the unit's mounting map",
    )
    parser.add_argument(
        "--track",
        type=float,
        metavar="M",
        help="left to right wheels, metres: side tilts are worded as heights; saved with the "
        "unit's mounting map",
    )


def vehicle_size_from_args(args: argparse.Namespace) -> VehicleSize | None:
    """Return the size the flags give (None: neither flag), exit 2 on a length that is not one."""
    wheelbase, track = getattr(args, "wheelbase", None), getattr(args, "track", None)
    if wheelbase is None and track is None:
        return None
    try:
        return VehicleSize(wheelbase, track)
    except InputError as exc:  # worded with the flags
        text = str(exc).replace("wheelbase_m", "--wheelbase").replace("track_m", "--track")
        raise InputError(text) from None
