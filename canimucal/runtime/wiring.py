"""The one wiring path: settings → open devices → session, for the CLI, the demo and the TUI.

:class:`DeviceSettings` says what to open: a CAN bus (python-can settings) with one client per
node id, or the built-in simulated IMU(s) on a private python-can ``virtual`` bus.
:func:`open_devices` opens it into :class:`Devices` (buses, canopen networks, one
:class:`~canimucal.device.client.ImuClient` per node, the simulated nodes), and
:meth:`Devices.session` builds the guided :class:`~canimucal.runtime.session.Session` over
them. The session is quiet on a live bus: NMT only to the target nodes (sent by the client
when it streams), no SYNC unless ``sync_producer``.
"""

from __future__ import annotations

import logging
import os
import socket
import uuid
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from types import TracebackType
from typing import Any, cast

import can
import canopen
import numpy as np

from canimucal.analysis.acceptance import plan_limits
from canimucal.analysis.calibrate import SiteConditions
from canimucal.analysis.session_model import read_factory_k
from canimucal.device.answerers import refuse_second_answerer
from canimucal.device.bus import BusSettings, describe, open_bus
from canimucal.device.bus_log import BusLogWriter, LoggingNetwork
from canimucal.device.client import NOTIFIER_CYCLE_S, Identity, ImuClient
from canimucal.device.factory_k import device_k
from canimucal.errors import InputError, NoDeviceError
from canimucal.io.atomic import per_node_path
from canimucal.io.mounting import choose_mounting, choose_vehicle_size
from canimucal.model.layout import GyroSpec, JointSpec
from canimucal.model.mounting import MountingMap
from canimucal.model.plan import KPrior
from canimucal.model.positions import Plan
from canimucal.model.vehicle_size import VehicleSize
from canimucal.model.vocabulary.plans import PLANS, VEHICLE_PRIOR_K_SIGMA, worded_for_vehicle
from canimucal.procedure.machine import Procedure, ProcedureConfig
from canimucal.runtime.resume import load_resume_state
from canimucal.runtime.session import Session, device_of, recording_header
from canimucal.sim.truth import Truth
from canimucal.simnode.node import SimulatedImuNode

log = logging.getLogger(__name__)

FIRST_NODE_ID = 0x10
FIND_NODE_TIMEOUT_S = 2.0
"""How long to wait for a heartbeat (0x1017 defaults to 1000 ms) before probing by SDO."""
RECEIVE_BUFFER_BYTES = 4 << 20
"""Socket receive buffer asked for on SocketCAN (the default ~200 kB holds well under a
second of 200 Hz TPDOs once a busy or emulated machine stalls the receive thread)."""
SIMULATED_WHERE = "simulated IMU (in-process virtual CAN bus)"


@dataclass(frozen=True)
class SimSettings:
    """The simulated unit(s): one truth per node (a single truth serves every node).

    Node ``i`` (in node-id order) gets noise seed ``seed + i``; ``state`` is the non-volatile
    memory file (``NAME.node<ID>.EXT`` per node when there are several).
    """

    truths: tuple[Truth, ...] = (Truth.from_dict({}),)
    state: Path | None = None
    time_scale: float = 1.0
    seed: int | None = None

    def truth_of(self, index: int) -> Truth:
        """Return the truth of the ``index``-th node."""
        return self.truths[index] if len(self.truths) > 1 else self.truths[0]


@dataclass(frozen=True)
class DeviceSettings:
    """What to open: ``sim`` set → simulated nodes, else the CAN bus of ``bus``."""

    node_ids: tuple[int, ...] = (FIRST_NODE_ID,)
    bus: BusSettings = field(default_factory=BusSettings)
    sim: SimSettings | None = None
    sdo_timeout_s: float | None = None
    sync_producer: bool = False
    find: bool = True
    """Find every node on a real bus while opening (heartbeat, else an SDO probe)."""
    bus_logs: tuple[Path, ...] = ()
    """Log files (python-can's formats, by suffix) that get every frame of the clients' bus."""
    overwrite_logs: bool = False


def demo_settings(
    truths: Sequence[Truth], *, time_scale: float = 10.0, seed: int = 1
) -> DeviceSettings:
    """Describe simulated nodes 0x10, 0x11, … one per truth (the demo's rig)."""
    ids = tuple(FIRST_NODE_ID + i for i in range(len(truths)))
    return DeviceSettings(
        node_ids=ids, sim=SimSettings(tuple(truths), time_scale=time_scale, seed=seed)
    )


def spec_for_plan(plan_name: str, gyro: str = "mems", gyro_g: bool = False) -> JointSpec:
    """Return the model each plan can determine (``gyro``: ``mems`` or ``nav``, checked).

    The plan registry's ``accel_k`` and ``tilt`` (two: diagonal K, no tilt; five: diagonal
    K and base tilt; the others full K and base tilt; the vehicle plan's mounting trim); a
    name it does not hold gets full K and base tilt. ``gyro_g`` adds the gyro's g-sensitivity
    G (what the positions cannot determine of it is held at zero and reported).
    """
    grade = cast(GyroSpec, gyro)  # JointSpec checks the value
    entry = PLANS.get(plan_name)
    if entry is None:
        return JointSpec(accel_k="full", tilt="rigid", gyro=grade, gyro_g=gyro_g)
    return JointSpec(
        accel_k=entry.accel_k, tilt=entry.tilt, gyro=grade, gyro_g=gyro_g, trim=entry.trim
    )


def instruction_mounting(
    plan_name: str, serial: int, mount: MountingMap | str | None, replace_mount: bool
) -> tuple[MountingMap | None, str]:
    """Return the map that words the instructions (None: body axes) and a note saying why.

    The vehicle plan, or any plan with ``mount`` given, is worded for the vehicle through
    :func:`~canimucal.io.mounting.choose_mounting` (the map asked for, else the one saved for
    the first node's ``serial``, else the default); other plans in the unit's axes (a bench).
    """
    if mount is None and not worded_for_vehicle(plan_name):
        return None, ""
    choice = choose_mounting(serial, mount, replace=replace_mount)
    log.info("%s", choice.note)
    return choice.mounting, choice.note


class Devices:
    """Open buses and networks, one client per node and the simulated nodes (context manager).

    ``truths`` holds each simulated node's truth; ``where`` names the bus for messages.
    """

    def __init__(self, settings: DeviceSettings) -> None:
        self.settings = settings
        self.clients: dict[int, ImuClient] = {}
        self.sim_nodes: dict[int, SimulatedImuNode] = {}
        self.truths: dict[int, Truth] = {}
        self._buses: list[can.BusABC] = []
        self._networks: list[canopen.Network] = []
        self.where = SIMULATED_WHERE
        self.bus_log: BusLogWriter | None = None
        self.sim_channel: str | None = None
        """The private virtual channel of the simulated nodes (None on a real bus)."""
        self.bus_log_failures: list[str] = []
        """What went wrong writing the bus logs (known once closed): one line per file."""
        try:
            if settings.bus_logs:
                self.bus_log = BusLogWriter(settings.bus_logs, overwrite=settings.overwrite_logs)
            self._open()
        except BaseException:
            self.close()
            raise

    def _open(self) -> None:
        settings = self.settings
        bitrate: Any = None
        if settings.sim is not None:
            bus = self._start_sim(settings.sim)
            network = self._network(bus, self.sim_channel)
        else:
            config = settings.bus.resolve()
            bus = open_bus(settings.bus)
            self._buses.append(bus)
            enlarge_receive_buffer(bus)
            self.where = describe(config)
            bitrate = settings.bus.bitrate or config.get("bitrate")
            network = self._network(bus, config.get("channel"))
        census = HeartbeatCensus(network)
        for nid in settings.node_ids:
            self.clients[nid] = ImuClient(
                network,
                nid,
                sdo_timeout_s=settings.sdo_timeout_s,
                sync_producer=settings.sync_producer,
                bitrate_bps=int(bitrate) if bitrate else None,
            )
            if settings.find and settings.sim is None:
                how = self._find(nid, census)
                log.info("node %d found by %s", nid, how)

    def _find(self, nid: int, census: HeartbeatCensus) -> str:
        """Find node ``nid``; when it is not there, name the nodes that are heartbeating."""
        try:
            return self.clients[nid].find_node(FIND_NODE_TIMEOUT_S)
        except NoDeviceError as exc:
            others = sorted(census.heard - {nid})
            if others:
                heard = ", ".join(f"{n} (0x{n:02X})" for n in others)
                hint = f"heartbeating on {self.where}: node {heard}; check node_ids"
                raise NoDeviceError(f"{exc}; {hint}", options=("node_ids",)) from exc
            hint = f"no node is heartbeating on {self.where}: check power, wiring, bit rate"
            raise NoDeviceError(f"{exc}; {hint}") from exc

    def _network(self, bus: can.BusABC, channel: Any = None) -> canopen.Network:
        if self.bus_log is not None:
            network: canopen.Network = LoggingNetwork(bus, self.bus_log, channel)
        else:
            network = canopen.Network(bus)
        network.NOTIFIER_CYCLE = NOTIFIER_CYCLE_S
        network.connect()
        self._networks.append(network)
        return network

    def _start_sim(self, sim: SimSettings) -> can.BusABC:
        """Start the simulated nodes on a private virtual bus; return the clients' bus."""
        # private to this process; python-can's log writers number a channel by the name's
        # last digits (BLF holds 16 bits), so the name ends in bus 0 like vcan0
        channel = f"canimucal-sim-{os.getpid()}-{uuid.uuid4().hex[:8]}-can0"
        self.sim_channel = channel
        ids = self.settings.node_ids
        for i, nid in enumerate(ids):
            bus = can.Bus(interface="virtual", channel=channel)
            self._buses.append(bus)
            state = per_node_path(sim.state, nid, len(ids) > 1) if sim.state else None
            truth = sim.truth_of(i)
            node = SimulatedImuNode(
                bus,
                nid,
                truth,
                state_file=state,
                time_scale=sim.time_scale,
                seed=None if sim.seed is None else sim.seed + i,
            )
            self.sim_nodes[nid] = node.start()
            self.truths[nid] = truth
        client_bus = can.Bus(interface="virtual", channel=channel)
        self._buses.append(client_bus)
        return client_bus

    def identities(self) -> dict[int, Identity]:
        """Find every node and read its identity; refuse a node-id two devices answer as."""
        out = {}
        for node_id, client in self.clients.items():
            client.find_node(FIND_NODE_TIMEOUT_S)
            refuse_second_answerer(client, "nothing recorded, the session does not start")
            out[node_id] = client.identity()
        return out

    def refuse_second_answerers(self, consequence: str) -> None:
        """:class:`DuplicateNodeError` (exit 4) when two devices answer as one of the nodes."""
        for client in self.clients.values():
            refuse_second_answerer(client, consequence)

    def simulated_site(self) -> SiteConditions:
        """Return the first simulated node's site, with the LSBs its node reports."""
        accel_lsb, gyro_lsb = next(iter(self.clients.values())).nominal_lsb()
        truth = next(iter(self.truths.values()))
        return SiteConditions(
            g=truth.g,
            latitude=truth.latitude,
            heading=truth.heading,
            accel_lsb=accel_lsb,
            gyro_lsb=gyro_lsb,
        )

    def session(
        self,
        plan: Plan,
        out_dir: Path,
        *,
        plan_name: str,
        gyro: str = "mems",
        gyro_g: bool = False,
        site: SiteConditions | None = None,
        backup_dir: Path | None = None,
        overwrite: bool = False,
        resume: bool = False,
        identities: dict[int, Identity] | None = None,
        operator: str | None = None,
        site_name: str | None = None,
        mount: MountingMap | str | None = None,
        replace_mount: bool = False,
        vehicle_size: VehicleSize | None = None,
        remember_size: bool = True,
        prior_k: str | None = None,
        prior_k_sigma: float | None = None,
        **config: Any,
    ) -> Session:
        """Build the guided session of ``plan`` over every node.

        ``site`` None: the simulated truth's site. The LSBs and the data rate come from the
        first node. Simulated nodes keep their backups in ``out_dir/backups`` by default.
        ``resume``: go on with the interrupted session in ``out_dir``, if its recordings came
        from these very units. ``mount`` (a map, ``"body"`` or None) and ``replace_mount``
        choose how instructions are worded (:func:`instruction_mounting`), ``vehicle_size``
        (else the one saved for the first node's serial) words a vehicle's tilts as heights
        (:func:`~canimucal.io.mounting.choose_vehicle_size`; ``remember_size`` False: used,
        neither saved nor looked up, as the demo does). ``prior_k`` (a file)
        and ``prior_k_sigma`` set the prior on K
        (:meth:`k_priors`); a resumed session without them keeps the prior its recordings
        say the first part held. ``config`` goes to :class:`ProcedureConfig`; without
        ``limits`` there the session judges against the plan's built-in acceptance limits
        (``plan_name``'s registry defaults over the built-in ones; the shells pass the
        user's, docs/design.md §3).
        """
        config.setdefault("limits", plan_limits(plan_name))
        identities = identities or self.identities()
        if backup_dir is None and self.sim_nodes:
            backup_dir = out_dir / "backups"
        first = next(iter(self.clients.values()))
        accel_lsb, gyro_lsb = first.nominal_lsb()
        site = self.simulated_site() if site is None else site
        site = replace(site, accel_lsb=accel_lsb, gyro_lsb=gyro_lsb)
        rate = float(first.output_data_rate())
        if resume:
            serials = {n: i.serial for n, i in identities.items()}
            config["resume_from"] = load_resume_state(out_dir, plan, tuple(self.clients), serials)
        first_serial = identities[next(iter(self.clients))].serial
        config["mounting"], config["mounting_note"] = instruction_mounting(
            plan_name, first_serial, mount, replace_mount
        )
        if config["mounting"] is not None and not remember_size:  # the demo: nothing saved
            config["vehicle_size"] = vehicle_size
        elif config["mounting"] is not None:  # a vehicle: its tilts as heights when known
            sized = choose_vehicle_size(first_serial, vehicle_size, replace=replace_mount)
            config["vehicle_size"] = sized.size
            if sized.note:
                config["mounting_note"] = "; ".join(
                    n for n in (config["mounting_note"], sized.note) if n
                )
        resumed = config.get("resume_from")
        flags = prior_k is not None or prior_k_sigma is not None
        if "k_priors" in config:
            pass
        elif resumed is not None and resumed.k_priors and not flags:
            config["k_priors"] = resumed.k_priors  # the prior the first part held
        else:
            config["k_priors"] = self.k_priors(plan, prior_k, prior_k_sigma)
        cfg = ProcedureConfig(
            plan=plan,
            node_ids=tuple(self.clients),
            sample_rate_hz=rate,
            site=site,
            spec=spec_for_plan(plan_name, gyro, gyro_g),
            devices={n: device_of(n, i) for n, i in identities.items()},
            plan_name=plan_name,
            **config,
        )
        header = {n: recording_header(rate, site, identities[n], n) for n in self.clients}
        for sim in self.sim_nodes.values():
            sim.set_pose(0.0, 0.0, 0.0)
        seed = None if self.settings.sim is None else self.settings.sim.seed
        return Session(
            Procedure(cfg),
            self.clients,
            identities,
            out_dir,
            sims=self.sim_nodes or None,
            header=header,
            backup_dir=backup_dir,
            overwrite=overwrite,
            operator_rng=None if seed is None else np.random.default_rng(seed + 1000),
            operator=operator,
            site_name=site_name,
        )

    def k_priors(
        self, plan: Plan, prior_k: str | None = None, prior_k_sigma: float | None = None
    ) -> dict[int, KPrior]:
        """Return each node's prior on K when ``plan`` (or ``prior_k_sigma``) holds one.

        The mean: the file ``prior_k`` (a calibration JSON or ``read-params --json``), else
        the K each node applies now, read live (:func:`~canimucal.device.factory_k.device_k`).
        The σ: ``prior_k_sigma``, else the plan's default; ``prior_k`` with a plan that holds
        no prior takes the vehicle plan's 1 %, as ``solve --prior-k`` does. Empty (nothing
        read) when no prior is held.
        """
        if prior_k_sigma is not None and not (np.isfinite(prior_k_sigma) and prior_k_sigma > 0):
            raise InputError(
                f"prior_k_sigma must be > 0, got {prior_k_sigma:g}", options=("prior_k_sigma",)
            )
        sigma, whence = prior_k_sigma, "--prior-k-sigma" if prior_k_sigma is not None else None
        if sigma is None and prior_k and plan.prior_k_sigma is None:
            sigma, whence = VEHICLE_PRIOR_K_SIGMA, "the default of --prior-k (no σ given)"
        if not KPrior(rel_sigma=sigma).needed(plan):
            return {}
        if prior_k:
            k = read_factory_k(prior_k)
            source = f"K from {Path(prior_k).name}"
            return {n: KPrior(k, source, sigma, whence) for n in self.clients}
        out = {}
        for node_id, client in self.clients.items():
            held = device_k(client.read_calibration_block(), client.nominal_lsb()[0], node_id)
            log.info("node %d: prior on K: %s", node_id, held.source)
            out[node_id] = KPrior(held.k, held.source, sigma, whence)
        return out

    def close(self) -> None:
        """Close the clients, stop the simulated nodes and notifiers, shut the buses down."""
        for client in self.clients.values():
            try:
                client.close()
            except Exception as exc:  # closing must go on for the other resources
                log.warning("closing node %d: %s", client.node_id, exc)
        for network in self._networks:
            if network.notifier is not None:
                network.notifier.stop(network.NOTIFIER_SHUTDOWN_TIMEOUT)
        if self.bus_log is not None and not self.bus_log_failures:
            self.bus_log_failures = self.bus_log.close()  # idempotent: [] once closed
        for node in self.sim_nodes.values():
            node.stop()
        for bus in self._buses:
            bus.shutdown()
        self.clients, self.sim_nodes, self._networks, self._buses = {}, {}, [], []

    def __enter__(self) -> Devices:
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


def open_devices(settings: DeviceSettings) -> Devices:
    """Open what ``settings`` describe (:class:`NoDeviceError` when the bus cannot open)."""
    return Devices(settings)


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
