"""The bus flags every device command shares (docs/design.md §7) and the devices they open.

``--interface --channel --bitrate`` follow python-can (its config file, ``--can-config``, and
``CAN_*`` environment fill in what the flags leave out; ``--interface`` defaults to
``socketcan`` when only a channel is known, see :mod:`canimucal.device.bus`). ``--node-id``
may repeat: one client per node. ``--sim`` instead attaches the built-in simulated IMU
in-process on a private python-can ``virtual`` bus (``--truth``/``--state``/``--time-scale``
configure it), so every command can be tried without hardware.

The flags become :class:`~canimucal.runtime.wiring.DeviceSettings`; opening them is the
wiring path the demo and the TUI share.
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path
from typing import TYPE_CHECKING, Any

from canimucal.errors import InputError
from canimucal.io.truth import load_truth
from canimucal.sim.truth import Truth

if TYPE_CHECKING:  # the CAN stack loads only when a device command runs (fast --help)
    from canimucal.device.bus import BusSettings
    from canimucal.runtime.wiring import Devices, DeviceSettings

log = logging.getLogger(__name__)

DEFAULT_NODE_ID = 0x10


def node_id(text: str) -> int:
    """Parse a node id (decimal or 0x hex) in 1..127 for argparse."""
    try:
        value = int(text, 0)
    except ValueError:
        raise argparse.ArgumentTypeError(f"node id must be an integer, got {text!r}") from None
    if not 1 <= value <= 127:
        raise argparse.ArgumentTypeError(f"node id must be 1..127, got {value}")
    return value


def positive_float(text: str) -> float:
    """Parse a finite number > 0 for argparse."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not (value > 0.0 and value < float("inf")):
        raise argparse.ArgumentTypeError(f"must be a positive number, got {text}")
    return value


def add_bus_options(parser: argparse.ArgumentParser, *, sim: bool = True) -> None:
    """Add the bus flags; with ``sim`` also ``--sim`` and the simulated node's flags."""
    bus = parser.add_argument_group("CAN bus (python-can)")
    bus.add_argument("--interface", help="python-can interface (default socketcan with --channel)")
    bus.add_argument("--channel", help="CAN channel, e.g. vcan0 or can0")
    bus.add_argument(
        "--bitrate",
        type=int,
        help="bit rate, bit/s (interfaces that set it; bus load: 500 kbit/s assumed without)",
    )
    bus.add_argument("--can-config", metavar="PATH", help="python-can config file")
    bus.add_argument(
        "--node-id",
        type=node_id,
        action="append",
        metavar="ID",
        help="CANopen node id of the IMU (default 16 = 0x10); repeat for several nodes",
    )
    bus.add_argument(
        "--sync-producer", action="store_true", help="send SYNC (only if no one else does)"
    )
    bus.add_argument(
        "--sdo-timeout",
        type=positive_float,
        metavar="S",
        help="SDO response timeout, s (default 0.5; 2 in the CAN VM)",
    )
    if not sim:
        return
    group = parser.add_argument_group("built-in simulated IMU")
    group.add_argument(
        "--sim", action="store_true", help="attach the simulated IMU in-process (no hardware)"
    )
    add_sim_node_options(group)


def add_sim_node_options(group: Any) -> None:
    """``--truth``, ``--state``, ``--time-scale``, ``--seed`` of a simulated node."""
    group.add_argument("--truth", metavar="FILE", help="truth JSON of the simulated unit")
    group.add_argument(
        "--state", metavar="FILE", help="the simulated node's non-volatile memory (JSON)"
    )
    group.add_argument(
        "--time-scale",
        type=positive_float,
        default=1.0,
        metavar="X",
        help="simulated seconds per wall second (default 1)",
    )
    group.add_argument("--seed", type=int, help="noise seed of the simulated unit")


def node_ids(args: argparse.Namespace) -> list[int]:
    """Return the ``--node-id`` values, deduplicated in order (default 0x10)."""
    return list(dict.fromkeys(args.node_id or [DEFAULT_NODE_ID]))


def bus_settings(args: argparse.Namespace) -> BusSettings:
    """:class:`BusSettings` from the flags (python-can fills in the rest)."""
    from canimucal.device.bus import BusSettings

    return BusSettings(
        interface=args.interface,
        channel=args.channel,
        bitrate=args.bitrate,
        config_path=args.can_config,
    )


def load_sim_truth(args: argparse.Namespace) -> Truth:
    """Load the ``--truth`` file, or a nominal unit."""
    return load_truth(args.truth) if args.truth else Truth.from_dict({})


def device_settings(args: argparse.Namespace, *, find: bool = True) -> DeviceSettings:
    """Build the :class:`DeviceSettings` the flags describe (``--sim``: the simulated IMU)."""
    from canimucal.runtime.wiring import DeviceSettings, SimSettings

    sim = None
    if getattr(args, "sim", False):
        sim = SimSettings(
            truths=(load_sim_truth(args),),
            state=Path(args.state) if args.state else None,
            time_scale=args.time_scale,
            seed=args.seed,
        )
    return DeviceSettings(
        node_ids=tuple(node_ids(args)),
        bus=bus_settings(args),
        sim=sim,
        sdo_timeout_s=args.sdo_timeout,
        sync_producer=bool(args.sync_producer),
        find=find,
        bus_logs=tuple(Path(p) for p in getattr(args, "can_log", None) or ()),
        overwrite_logs=bool(getattr(args, "overwrite", False)),
    )


def open_from_args(args: argparse.Namespace, *, find: bool = True) -> Devices:
    """Open the devices the flags describe (the wiring path of :mod:`canimucal.runtime.wiring`)."""
    from canimucal.runtime.wiring import open_devices

    return open_devices(device_settings(args, find=find))


def require_single_stdout(args: argparse.Namespace, count: int) -> None:
    """Refuse ``--json -`` for several nodes (each node needs its own file)."""
    if count > 1 and getattr(args, "json", None) == "-":
        raise InputError("--json - takes one node; give a file name for several --node-id")
