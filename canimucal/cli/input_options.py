"""The input flags of ``solve``, ``analyze``, ``allan`` and ``import-log`` (docs/design.md §7).

Every input goes through the one dispatcher,
:func:`canimucal.runtime.inputs.read_recording`: a recording CSV, an imu_tk pair, an imucal
CSV or a CAN bus log, told apart by content unless ``--format`` names it. A bus log takes
the flags of the "bus log input" group (the node, its PDO mapping, the plan its still
stretches follow, the channel); they are refused for the other formats.
"""

from __future__ import annotations

import argparse
from typing import Any

from canimucal.cli.bus_options import node_id
from canimucal.io.recording import Recording
from canimucal.model.vocabulary.plans import plan_help
from canimucal.runtime.inputs import FORMATS, read_recording

INPUT_HELP = "recording CSV, imu_tk accelerometer file, imucal CSV or CAN bus log"
SECOND_HELP = "imu_tk gyro file, or imucal section JSON (optional)"


def add_input_options(parser: argparse.ArgumentParser, *, plan: bool = True) -> None:
    """``--format``, ``--sample-rate-hz`` and the bus log flags (``plan``: with ``--plan``)."""
    parser.add_argument("--format", choices=FORMATS, help="input format (default: from content)")
    parser.add_argument(
        "--sample-rate-hz", type=float, help="sample rate when the input has none (or is wrong)"
    )
    add_log_options(parser.add_argument_group("bus log input"), plan=plan)


def add_log_options(group: Any, *, plan: bool = True, required_plan: bool = False) -> None:
    """``--node-id``, ``--pdo-map``, ``--log-channel`` and (``plan``) ``--plan``."""
    group.add_argument(
        "--node-id",
        type=node_id,
        metavar="ID",
        help="the IMU's node id (default: the one node the log shows sending TPDO1 and TPDO2)",
    )
    group.add_argument(
        "--pdo-map",
        metavar="JSON",
        help="the node's PDO mapping: a read-params --json document (default: what the log's "
        "SDO uploads show, else the EDS defaults)",
    )
    group.add_argument(
        "--log-channel", metavar="CH", help="the channel of the node, in a log of several buses"
    )
    if plan:
        group.add_argument(
            "--plan",
            metavar="P",
            required=required_plan,
            help="name the still stretches after this plan's positions, in order ("
            + plan_help()
            + "; default: positions without angles)",
        )


def read_input(args: argparse.Namespace, path: str, second: str | None) -> Recording:
    """Read ``path`` (and ``second``) as the flags say, through the one dispatcher."""
    return read_recording(
        path,
        args.format,
        second=second,
        sample_rate_hz=args.sample_rate_hz,
        node_id=args.node_id,
        pdo_map=args.pdo_map,
        plan=getattr(args, "plan", None),
        channel=args.log_channel,
    )
