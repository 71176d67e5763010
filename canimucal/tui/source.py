"""Where the TUI's nodes come from: the demo rig (simulated nodes) or a real bus.

A source connects (blocking: SDO reads, run on a worker thread), reports each node's
identity, current calibration and heartbeat for the connection screen, and opens the
:class:`~canimucal.runtime.session.Session` of the chosen plan. The TUI never imports the
CLI: a real bus is opened by a callable the CLI passes in (``canimucal tui`` gives
``DeviceSession(args)``, which has ``clients``, ``where`` and ``close()``).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol

from canimucal.analysis.calibrate import SiteConditions
from canimucal.device.busload import BusLoad
from canimucal.device.client import CalibrationReadout, Identity, ImuClient
from canimucal.model.positions import Plan
from canimucal.procedure.averaging import AveragingPolicy
from canimucal.procedure.machine import Procedure, ProcedureConfig
from canimucal.runtime.demo_rig import DemoRig, spec_for_plan
from canimucal.runtime.resume import load_resume_state
from canimucal.runtime.session import Session, device_of, recording_header
from canimucal.sim.truth import Truth

logger = logging.getLogger(__name__)

FIND_NODE_TIMEOUT_S = 2.0


@dataclass(frozen=True)
class NodeStatus:
    """What the connection screen shows of one node."""

    node_id: int
    identity: Identity
    calibration: CalibrationReadout | None
    accel_lsb: float
    gyro_lsb: float
    rate_hz: float
    found_by: str = ""


@dataclass(frozen=True)
class Heartbeat:
    """NMT state last reported and the age of the last heartbeat (None before any).

    ``bus_load``: the load of the node's bus over the last second, as its client sees it.
    """

    state: str | None
    age_s: float | None
    bus_load: BusLoad | None = None


class ClientSet(Protocol):
    """What a real bus opener returns (``canimucal.cli.bus_options.DeviceSession``)."""

    clients: dict[int, ImuClient]
    where: str

    def close(self) -> None:
        """Close clients and buses."""


class SessionSource(Protocol):
    """A source of nodes and sessions; see the module doc."""

    description: str
    out_dir: Path

    def connect(self) -> list[NodeStatus]:
        """Find every node and read identity and calibration (blocking)."""

    def heartbeat(self, node_id: int) -> Heartbeat:
        """Heartbeat state of one node (non-blocking)."""

    def open(self, plan: Plan, plan_name: str, gyro: str) -> Session:
        """Build the session of ``plan`` (blocking)."""

    def close(self) -> None:
        """Release buses and nodes (idempotent)."""


def read_status(client: ImuClient, found_by: str = "") -> NodeStatus:
    """Read a node's identity, LSBs, data rate and current calibration block."""
    identity = client.identity()
    accel_lsb, gyro_lsb = client.nominal_lsb()
    rate = float(client.output_data_rate())
    readout = client.read_calibration_block()
    return NodeStatus(client.node_id, identity, readout, accel_lsb, gyro_lsb, rate, found_by)


def heartbeat_of(client: ImuClient | None) -> Heartbeat:
    """Heartbeat of a client; the age is wall time since the last frame's timestamp."""
    if client is None:
        return Heartbeat(None, None)
    last = client.last_heartbeat_s
    age = None if last is None else max(0.0, time.time() - last)
    return Heartbeat(client.node_state, age, client.bus_load())


@dataclass
class DemoSource:
    """Simulated node(s) on a private virtual bus (:class:`DemoRig`)."""

    truths: list[Truth]
    out_dir: Path
    time_scale: float = 20.0
    seed: int = 1
    seconds: float | None = None
    warmup: bool = True
    verify_seconds: float = 10.0
    description: str = "simulated IMU (demo, in-process virtual CAN bus)"
    resume: bool = False
    """Go on with the interrupted demo in ``out_dir`` (same units: same truths and seed)."""
    rig: DemoRig | None = field(default=None, init=False)

    def connect(self) -> list[NodeStatus]:
        """Start the simulated nodes and read them."""
        if self.rig is None:
            self.rig = DemoRig(self.truths, time_scale=self.time_scale, seed=self.seed)
        return [read_status(c, "demo") for c in self.rig.clients.values()]

    def heartbeat(self, node_id: int) -> Heartbeat:
        """Heartbeat of a simulated node."""
        return heartbeat_of(None if self.rig is None else self.rig.clients.get(node_id))

    def open(self, plan: Plan, plan_name: str, gyro: str) -> Session:
        """Build the demo session (confirming a pose moves the simulated nodes)."""
        if self.rig is None:
            self.connect()
        assert self.rig is not None
        return self.rig.session(
            plan,
            self.out_dir,
            plan_name=plan_name,
            gyro=gyro,
            averaging=AveragingPolicy(fixed_s=self.seconds),
            warmup=self.warmup,
            verify_seconds=self.verify_seconds,
            resume=self.resume,
        )

    def close(self) -> None:
        """Stop the rig."""
        if self.rig is not None:
            self.rig.close()
            self.rig = None


@dataclass
class BusSource:
    """Real node(s) on a bus opened by ``opener`` (the CLI's bus flags)."""

    opener: Callable[[], ClientSet]
    out_dir: Path
    site: SiteConditions
    backup_dir: Path | None = None
    warmup: bool = True
    description: str = "CAN bus"
    resume: bool = False
    """Go on with the interrupted session in ``out_dir`` (:mod:`canimucal.runtime.resume`)."""
    opened: ClientSet | None = field(default=None, init=False)
    statuses: dict[int, NodeStatus] = field(default_factory=dict, init=False)

    def connect(self) -> list[NodeStatus]:
        """Open the bus, find every node and read it."""
        if self.opened is None:
            self.opened = self.opener()
            self.description = self.opened.where or self.description
        out = []
        for node_id, client in self.opened.clients.items():
            how = client.find_node(FIND_NODE_TIMEOUT_S)
            out.append(read_status(client, how))
            self.statuses[node_id] = out[-1]
        return out

    def heartbeat(self, node_id: int) -> Heartbeat:
        """Heartbeat of a node on the bus."""
        return heartbeat_of(None if self.opened is None else self.opened.clients.get(node_id))

    def open(self, plan: Plan, plan_name: str, gyro: str) -> Session:
        """Build the session over every node (LSBs and rate from the first node)."""
        if self.opened is None:
            self.connect()
        assert self.opened is not None
        clients = self.opened.clients
        first = self.statuses[next(iter(clients))]
        site = _with_lsb(self.site, first.accel_lsb, first.gyro_lsb)
        identities = {n: s.identity for n, s in self.statuses.items()}
        cfg = ProcedureConfig(
            plan=plan,
            node_ids=tuple(clients),
            sample_rate_hz=first.rate_hz,
            site=site,
            spec=spec_for_plan(plan_name, gyro),
            devices={n: device_of(n, i) for n, i in identities.items()},
            plan_name=plan_name,
            warmup=self.warmup,
            resume_from=load_resume_state(
                self.out_dir, plan, tuple(clients), {n: i.serial for n, i in identities.items()}
            )
            if self.resume
            else None,
        )
        headers = {n: recording_header(first.rate_hz, site, identities[n], n) for n in clients}
        sims = getattr(self.opened, "sim_nodes", None) or None  # --sim: poses move the unit
        if sims:
            for sim in sims.values():
                sim.set_pose(0.0, 0.0, 0.0)
        return Session(
            Procedure(cfg),
            clients,
            identities,
            self.out_dir,
            sims=sims,
            header=headers,
            backup_dir=self.backup_dir,
        )

    def close(self) -> None:
        """Close the bus."""
        if self.opened is not None:
            self.opened.close()
            self.opened = None


def _with_lsb(site: SiteConditions, accel_lsb: float, gyro_lsb: float) -> SiteConditions:
    from dataclasses import replace

    return replace(site, accel_lsb=accel_lsb, gyro_lsb=gyro_lsb)
