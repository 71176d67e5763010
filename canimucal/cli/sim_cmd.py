"""`canimucal sim`: run the simulated IMU node on a bus until Ctrl-C or SIGTERM.

For a second process or another tool (candump, a CANopen master) on e.g. ``vcan0``. With
``--poses FILE`` the unit follows that pose schedule from the first NMT start. Prints one
line when the node is up (``ready: …``), one when it stops.

The node keeps the wall clock (``wall_clock``, :mod:`canimucal.simnode.producer`): on a host
too slow for its rate it drops samples, as a real unit does, and says how many when it stops;
its world (poses, noise) never runs slower than the bus's time.
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading
from types import FrameType
from typing import Any

import numpy as np

from canimucal.cli.bus_options import (
    add_bus_options,
    add_sim_node_options,
    bus_settings,
    load_sim_truth,
    node_ids,
)
from canimucal.io.atomic import per_node_path
from canimucal.io.plans import read_plan
from canimucal.model.positions import Plan
from canimucal.sim.schedule import set_by_operator


def add_subparser(subparsers: Any) -> None:
    """Register ``sim``."""
    p = subparsers.add_parser(
        "sim",
        help="run the simulated IMU node on a CAN bus until Ctrl-C",
        description="Run the built-in simulated IMU as a CANopen node on a real bus "
        "(e.g. --channel vcan0) until Ctrl-C or SIGTERM.",
    )
    add_bus_options(p, sim=False)
    group = p.add_argument_group("simulated unit")
    add_sim_node_options(group)
    group.add_argument(
        "--poses", metavar="FILE", help="pose schedule (plan JSON/TOML) followed from NMT start"
    )
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    """Start the nodes, print a ready line, wait for Ctrl-C/SIGTERM, stop."""
    import canopen

    from canimucal.device.bus import describe, open_bus
    from canimucal.simnode.node import SimulatedImuNode

    truth = load_sim_truth(args)
    plan: Plan | None = read_plan(args.poses) if args.poses else None
    settings = bus_settings(args)
    bus = open_bus(settings)
    network = canopen.Network(bus)
    network.NOTIFIER_CYCLE = 0.1
    nodes: list[SimulatedImuNode] = []
    stop = threading.Event()
    previous = signal.signal(signal.SIGTERM, _setter(stop))
    try:
        network.connect()
        ids = node_ids(args)
        # the fixture sets each pose within its 1σ; one rigid body: the same errors for all
        placed = None if plan is None else set_by_operator(plan, np.random.default_rng(args.seed))
        for nid in ids:
            state = per_node_path(args.state, nid, len(ids) > 1) if args.state else None
            node = SimulatedImuNode(
                network,
                nid,
                truth,
                state_file=state,
                time_scale=args.time_scale,
                seed=args.seed,
                wall_clock=True,
            )
            if placed is not None:
                node.set_schedule(placed)
            nodes.append(node.start())
        schedule = f", following {len(plan.positions)} poses from NMT start" if plan else ""
        where = describe(settings.resolve())
        print(
            f"ready: simulated IMU node(s) {', '.join(map(str, ids))} (serial {truth.serial}) "
            f"on {where}{schedule}; Ctrl-C to stop",
            flush=True,
        )
        _wait(stop)
    finally:
        signal.signal(signal.SIGTERM, previous)
        for node in nodes:
            node.stop()
        if network.notifier is not None:
            network.notifier.stop(network.NOTIFIER_SHUTDOWN_TIMEOUT)
        bus.shutdown()
    dropped = sum(node.samples_dropped for node in nodes)
    why = f" ({dropped} samples dropped: the host could not send them in time)" if dropped else ""
    print(f"stopped{why}", file=sys.stderr, flush=True)
    return 0


def _wait(stop: threading.Event) -> None:
    """Block until SIGTERM sets ``stop`` or Ctrl-C."""
    try:
        while not stop.wait(0.2):
            pass
    except KeyboardInterrupt:
        pass


def _setter(event: threading.Event) -> Any:
    def handler(signum: int, frame: FrameType | None) -> None:
        event.set()

    return handler
