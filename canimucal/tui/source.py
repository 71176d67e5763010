"""Where the TUI's nodes come from: the devices the wiring path opens (bus or simulated).

A source connects (blocking: SDO reads, run on a worker thread), reports each node's
identity, current calibration and heartbeat for the connection screen, and opens the
:class:`~canimucal.runtime.session.Session` of the chosen plan through
:meth:`~canimucal.runtime.wiring.Devices.session`, the path the CLI and the demo use too.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Protocol

import numpy as np

from canimucal.analysis.acceptance import AcceptanceConfig
from canimucal.analysis.calibrate import SiteConditions
from canimucal.device.answerers import refuse_second_answerer
from canimucal.device.busload import BusLoad
from canimucal.device.client import CalibrationReadout, Identity, ImuClient
from canimucal.errors import CanimucalError
from canimucal.io.site_memory import LastSite, read_last_site, save_last_site
from canimucal.model.gravity import normal_gravity
from canimucal.model.mounting import MountingMap
from canimucal.model.positions import Plan
from canimucal.model.vehicle_size import VehicleSize
from canimucal.procedure.averaging import AveragingPolicy
from canimucal.runtime.resume import recorded_site
from canimucal.runtime.session import Session
from canimucal.runtime.wiring import (
    FIND_NODE_TIMEOUT_S,
    Devices,
    DeviceSettings,
    demo_settings,
    open_devices,
)
from canimucal.sim.truth import Truth

logger = logging.getLogger(__name__)


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


class SessionSource(Protocol):
    """A source of nodes and sessions; see the module doc."""

    description: str
    out_dir: Path
    mount: MountingMap | str | None
    """How the unit sits in the vehicle (a map, ``"body"``, None: saved or default)."""
    replace_mount: bool
    """Save ``mount`` for the unit's serial even when another map is saved."""

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
class DeviceSource:
    """The nodes :class:`~canimucal.runtime.wiring.DeviceSettings` describe, opened on connect.

    ``site`` None takes the simulated truth's site (the demo). ``seconds`` fixes the
    averaging time of every position (None: the procedure's rule). ``operator`` and
    ``site_name`` go into the records and the certificate.
    """

    settings: DeviceSettings
    out_dir: Path
    description: str
    site: SiteConditions | None = None
    backup_dir: Path | None = None
    overwrite: bool = False
    warmup: bool = True
    seconds: float | None = None
    verify_seconds: float = 10.0
    operator: str | None = None
    site_name: str | None = None
    resume: bool = False
    """Go on with the interrupted session in ``out_dir`` (:mod:`canimucal.runtime.resume`)."""
    mount: MountingMap | str | None = None
    """How the unit sits in the vehicle (``"body"``: body-axis wording; None: saved/default)."""
    replace_mount: bool = False
    """Replace the map saved for the unit's serial with ``mount``."""
    vehicle_size: VehicleSize | None = None
    """The vehicle's wheelbase and track (``--wheelbase``/``--track``; None: the saved ones)."""
    remember_size: bool = True
    """Save ``vehicle_size`` for the unit's serial and look a saved one up (not the demo)."""
    prior_k: str | None = None
    prior_k_sigma: float | None = None
    """The prior on K of a plan that holds one: ``prior_k`` a file (else the K each node
    applies, read live) and its relative σ (else the plan's default)."""
    gyro_g: bool = False
    """Estimate the gyro's g-sensitivity G (where the plan's positions determine it)."""
    acceptance: AcceptanceConfig = field(default_factory=AcceptanceConfig)
    """The acceptance limits sessions are judged against, per plan (the shell reads the
    user's ``acceptance.toml`` into it; empty: the built-in limits)."""
    ask_site: bool = False
    """Ask the operator and the site (latitude and height, or g) before the first position:
    no ``--site``, ``--latitude-deg`` or ``--g`` was given, and g is never assumed."""
    last_site_file: Path | None = None
    """Where the last answer is kept and offered from (the user's state directory)."""
    heading: float = 0.0
    """Azimuth of body z (radians) of a site the question gives."""
    devices: Devices | None = field(default=None, init=False)
    statuses: dict[int, NodeStatus] = field(default_factory=dict, init=False)

    def connect(self) -> list[NodeStatus]:
        """Open the devices, find every node and read it."""
        if self.devices is None:
            self.devices = open_devices(self.settings)
        out = []
        for node_id, client in self.devices.clients.items():
            how = client.find_node(FIND_NODE_TIMEOUT_S)
            refuse_second_answerer(client, "nothing read, the session does not start")
            out.append(read_status(client, how))
            self.statuses[node_id] = out[-1]
        return out

    def heartbeat(self, node_id: int) -> Heartbeat:
        """Heartbeat of one node."""
        return heartbeat_of(None if self.devices is None else self.devices.clients.get(node_id))

    @property
    def averaging(self) -> AveragingPolicy:
        """The averaging-time policy the sessions of this source use (``--seconds``)."""
        return AveragingPolicy(fixed_s=self.seconds)

    def open(self, plan: Plan, plan_name: str, gyro: str) -> Session:
        """Build the session over every node (confirming a pose moves simulated nodes)."""
        if self.devices is None:
            self.connect()
        assert self.devices is not None
        return self.devices.session(
            plan,
            self.out_dir,
            plan_name=plan_name,
            gyro=gyro,
            gyro_g=self.gyro_g,
            site=self.site,
            backup_dir=self.backup_dir,
            overwrite=self.overwrite,
            resume=self.resume,
            identities={n: s.identity for n, s in self.statuses.items()},
            averaging=self.averaging,
            operator=self.operator,
            site_name=self.site_name,
            warmup=self.warmup,
            verify_seconds=self.verify_seconds,
            mount=self.mount,
            replace_mount=self.replace_mount,
            vehicle_size=self.vehicle_size,
            remember_size=self.remember_size,
            prior_k=self.prior_k,
            prior_k_sigma=self.prior_k_sigma,
            limits=self.acceptance.limits(plan_name),
        )

    def last_site(self) -> LastSite:
        """Return the answer to offer: the last one saved, the flags' operator on top.

        A resumed session offers the site its recording's header holds (it goes on where it
        started), an unreadable recording being the session's own error later.
        """
        last = read_last_site(self.last_site_file)
        last = replace(last, operator=self.operator or last.operator)
        if self.resume:
            try:
                site = recorded_site(self.out_dir)
            except CanimucalError:
                return last
            last = replace(
                last,
                latitude_deg=site.get("latitude_deg"),
                height_m=site.get("height_m"),
                g=site.get("g"),
            )
        return last

    def take_site(self, answer: LastSite) -> None:
        """Use the site question's answer for the session and keep it for the next one."""
        latitude = None if answer.latitude_deg is None else float(np.deg2rad(answer.latitude_deg))
        height = 0.0 if answer.height_m is None else answer.height_m
        if answer.g is not None:
            g = answer.g
        else:
            assert latitude is not None  # site_answer needs latitude or g
            g = normal_gravity(latitude, height)
        self.site = SiteConditions(g=g, latitude=latitude, heading=self.heading, height_m=height)
        self.operator, self.site_name = answer.operator, answer.site_name or None
        self.ask_site = False
        save_last_site(self.last_site_file, answer)

    def close(self) -> None:
        """Release the devices (idempotent)."""
        if self.devices is not None:
            self.devices.close()
            self.devices = None


def demo_source(
    truths: Sequence[Truth],
    out_dir: Path,
    *,
    time_scale: float = 20.0,
    seed: int = 1,
    seconds: float | None = None,
) -> DeviceSource:
    """Build the demo's source: simulated node(s) 0x10, … one per truth, backups in out_dir."""
    return DeviceSource(
        demo_settings(truths, time_scale=time_scale, seed=seed),
        out_dir,
        "simulated IMU (demo, in-process virtual CAN bus)",
        backup_dir=out_dir / "backups",
        overwrite=True,
        seconds=seconds,
    )
