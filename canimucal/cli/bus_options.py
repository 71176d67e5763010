"""The bus flags every device command shares (DESIGN §7) and the session they open.

``--interface --channel --bitrate`` follow python-can (its config file, ``--can-config``, and
``CAN_*`` environment fill in what the flags leave out; ``--interface`` defaults to
``socketcan`` when only a channel is known, see :mod:`canimucal.device.bus`). ``--node-id``
may repeat: one client per node. ``--sim`` instead attaches the built-in simulated IMU
in-process on a private python-can ``virtual`` bus (``--truth``/``--state``/``--time-scale``
configure it), so every command can be tried without hardware.

The session is quiet on a live bus: NMT only to the target nodes (sent by the client when
it streams), no SYNC unless ``--sync-producer``.
"""

from __future__ import annotations

import argparse
import logging
import os
import socket
import uuid
from pathlib import Path
from types import TracebackType
from typing import TYPE_CHECKING, Any

from canimucal.errors import InputError
from canimucal.io.truth import load_truth
from canimucal.sim.truth import Truth

if TYPE_CHECKING:  # the CAN stack loads only when a device command runs (fast --help)
    import can
    import canopen

    from canimucal.device.bus import BusSettings
    from canimucal.device.client import ImuClient
    from canimucal.simnode.node import SimulatedImuNode

log = logging.getLogger(__name__)

DEFAULT_NODE_ID = 0x10
FIND_NODE_TIMEOUT_S = 1.5
"""How long to wait for a heartbeat (0x1017 defaults to 1000 ms) before probing by SDO."""
NOTIFIER_CYCLE_S = 0.1
RECEIVE_BUFFER_BYTES = 4 << 20
"""Socket receive buffer asked for on SocketCAN (the default ~200 kB holds well under a
second of 200 Hz TPDOs once a busy or emulated machine stalls the receive thread)."""


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


def per_node_path(path: str | os.PathLike[str], node: int, several: bool) -> Path:
    """``NAME.node<ID>.EXT`` when there are several nodes, else ``path`` itself."""
    target = Path(path)
    if not several:
        return target
    return target.with_name(f"{target.stem}.node{node}{target.suffix}")


def load_sim_truth(args: argparse.Namespace) -> Truth:
    """Load the ``--truth`` file, or a nominal unit."""
    return load_truth(args.truth) if args.truth else Truth.from_dict({})


class DeviceSession:
    """The bus, the canopen network and one :class:`ImuClient` per node (context manager).

    With ``--sim`` it also owns the simulated nodes (``sim_nodes``, by node id) on a
    private virtual bus. ``where`` names the bus for messages.
    """

    def __init__(self, args: argparse.Namespace, *, find: bool = True) -> None:
        from canimucal.device.bus import describe, open_bus
        from canimucal.device.client import ImuClient

        self.ids = node_ids(args)
        self.sim_nodes: dict[int, SimulatedImuNode] = {}
        self.clients: dict[int, ImuClient] = {}
        self._buses: list[can.BusABC] = []
        self._networks: list[canopen.Network] = []
        self.truth: Truth | None = None
        try:
            if getattr(args, "sim", False):
                bus = self._open_sim(args)
            else:
                bus = open_bus(bus_settings(args))
                self._buses.append(bus)
                enlarge_receive_buffer(bus)
            self.where = "simulated IMU (in-process virtual bus)" if self.sim_nodes else ""
            bitrate = getattr(args, "bitrate", None)
            if not self.where:
                config = bus_settings(args).resolve()
                self.where = describe(config)
                bitrate = bitrate or config.get("bitrate")
            network = self._network(bus)
            census = HeartbeatCensus(network)
            for nid in self.ids:
                self.clients[nid] = ImuClient(
                    network,
                    nid,
                    sdo_timeout_s=args.sdo_timeout,
                    sync_producer=bool(args.sync_producer),
                    bitrate_bps=int(bitrate) if bitrate else None,
                )
                if find and not self.sim_nodes:
                    how = self._find(nid, census)
                    log.info("node %d found by %s", nid, how)
        except BaseException:
            self.close()
            raise

    def _find(self, nid: int, census: HeartbeatCensus) -> str:
        """Find node ``nid``; when it is not there, name the nodes that are heartbeating."""
        from canimucal.errors import NoDeviceError

        try:
            return self.clients[nid].find_node(FIND_NODE_TIMEOUT_S)
        except NoDeviceError as exc:
            others = sorted(census.heard - {nid})
            if others:
                heard = ", ".join(f"{n} (0x{n:02X})" for n in others)
                hint = f"heartbeating on {self.where}: node {heard}; check --node-id"
            else:
                hint = f"no node is heartbeating on {self.where}: check power, wiring, bit rate"
            raise NoDeviceError(f"{exc}; {hint}") from exc

    def _network(self, bus: can.BusABC) -> canopen.Network:
        import canopen

        network = canopen.Network(bus)
        network.NOTIFIER_CYCLE = NOTIFIER_CYCLE_S
        network.connect()
        self._networks.append(network)
        return network

    def _open_sim(self, args: argparse.Namespace) -> can.BusABC:
        """Start the simulated nodes on a private virtual bus; return the client's bus."""
        import can

        from canimucal.simnode.node import SimulatedImuNode

        channel = f"canimucal-sim-{os.getpid()}-{uuid.uuid4().hex[:8]}"
        self.truth = load_sim_truth(args)
        node_bus = can.Bus(interface="virtual", channel=channel)
        self._buses.append(node_bus)
        node_network = self._network(node_bus)
        several = len(self.ids) > 1
        for nid in self.ids:
            state = per_node_path(args.state, nid, several) if args.state else None
            node = SimulatedImuNode(
                node_network,
                nid,
                self.truth,
                state_file=state,
                time_scale=args.time_scale,
                seed=args.seed,
            )
            self.sim_nodes[nid] = node.start()
        client_bus = can.Bus(interface="virtual", channel=channel)
        self._buses.append(client_bus)
        return client_bus

    def close(self) -> None:
        """Close the clients, stop the simulated nodes and notifiers, shut the buses down."""
        for client in self.clients.values():
            try:
                client.close()
            except Exception as exc:  # closing must go on for the other resources
                log.warning("closing node %d: %s", client.node_id, exc)
        for node in self.sim_nodes.values():
            node.stop()
        for network in self._networks:
            if network.notifier is not None:
                network.notifier.stop(network.NOTIFIER_SHUTDOWN_TIMEOUT)
        for bus in self._buses:
            bus.shutdown()
        self.clients, self.sim_nodes, self._networks, self._buses = {}, {}, [], []

    def __enter__(self) -> DeviceSession:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()


class HeartbeatCensus:
    """The node ids whose heartbeat or boot-up (0x701–0x77F) has been seen on a network."""

    def __init__(self, network: canopen.Network) -> None:
        self.heard: set[int] = set()
        for nid in range(1, 128):
            network.subscribe(0x700 + nid, self._seen)

    def _seen(self, can_id: int, data: bytearray, timestamp: float) -> None:
        self.heard.add(can_id - 0x700)


def enlarge_receive_buffer(bus: Any, size: int = RECEIVE_BUFFER_BYTES) -> int | None:
    """Raise a SocketCAN bus's receive buffer; return the size granted (None: not SocketCAN).

    ``SO_RCVBUFFORCE`` as root, else ``SO_RCVBUF`` (capped by ``net.core.rmem_max``).
    """
    sock = getattr(bus, "socket", None)
    if not isinstance(sock, socket.socket):
        return None
    for option in (getattr(socket, "SO_RCVBUFFORCE", None), socket.SO_RCVBUF):
        if option is None:
            continue
        try:
            sock.setsockopt(socket.SOL_SOCKET, option, size)
            break
        except OSError:
            continue
    granted = int(sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF))
    log.info("CAN socket receive buffer: %d bytes", granted)
    return granted


def require_single_stdout(args: argparse.Namespace, count: int) -> None:
    """Refuse ``--json -`` for several nodes (each node needs its own file)."""
    if count > 1 and getattr(args, "json", None) == "-":
        raise InputError("--json - takes one node; give a file name for several --node-id")
