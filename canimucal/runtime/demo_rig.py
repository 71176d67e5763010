"""The demo's test rig: simulated IMU node(s) and their clients on a private virtual bus.

``canimucal demo`` (headless or TUI) and the tests build a :class:`DemoRig`, then a
:class:`~canimucal.runtime.session.Session` from it with :meth:`DemoRig.session`. Each
node gets its own truth (its own serial and errors); all sit on one rigid body, so the
session moves them together. Closing the rig stops nodes and clients and shuts the buses.
"""

from __future__ import annotations

import logging
import uuid
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import Any

import can
import canopen
import numpy as np

from canimucal.analysis.calibrate import SiteConditions
from canimucal.device.client import Identity, ImuClient
from canimucal.model.layout import JointSpec
from canimucal.model.positions import Plan
from canimucal.procedure.machine import Procedure, ProcedureConfig
from canimucal.runtime.resume import load_resume_state
from canimucal.runtime.session import Session, device_of, recording_header
from canimucal.sim.truth import Truth
from canimucal.simnode.node import SimulatedImuNode

logger = logging.getLogger(__name__)

FIRST_NODE_ID = 0x10
NOTIFIER_CYCLE_S = 0.1


def spec_for_plan(plan_name: str, gyro: str = "mems") -> JointSpec:
    """Return the model each plan can determine (``gyro``: ``mems`` or ``nav``).

    two → bias + diagonal K; five → bias + diagonal K + base tilt; recommended and custom →
    bias, full K and base tilt.
    """
    if plan_name == "two":
        return JointSpec(accel_k="diag", tilt="none", gyro=gyro)  # type: ignore[arg-type]
    if plan_name == "five":
        return JointSpec(accel_k="diag", tilt="rigid", gyro=gyro)  # type: ignore[arg-type]
    return JointSpec(accel_k="full", tilt="rigid", gyro=gyro)  # type: ignore[arg-type]


class DemoRig:
    """Simulated nodes 0x10, 0x11, … with ``truths`` and one client each, on a virtual bus."""

    def __init__(self, truths: Sequence[Truth], *, time_scale: float = 10.0, seed: int = 1) -> None:
        channel = f"canimucal-demo-{uuid.uuid4().hex[:12]}"
        self.seed = seed
        self._buses: list[can.BusABC] = []
        self.sims: dict[int, SimulatedImuNode] = {}
        self.clients: dict[int, ImuClient] = {}
        self.truths: dict[int, Truth] = {}
        try:
            for i, truth in enumerate(truths):
                node_id = FIRST_NODE_ID + i
                sim = SimulatedImuNode(
                    self._bus(channel), node_id, truth, time_scale=time_scale, seed=seed + i
                )
                self.sims[node_id] = sim.start()
                self.truths[node_id] = truth
            self.network = canopen.Network(self._bus(channel))
            self.network.NOTIFIER_CYCLE = NOTIFIER_CYCLE_S
            self.network.connect()
            for node_id in self.sims:
                self.clients[node_id] = ImuClient(self.network, node_id)
        except BaseException:
            self.close()
            raise

    def _bus(self, channel: str) -> can.BusABC:
        bus = can.Bus(interface="virtual", channel=channel)
        self._buses.append(bus)
        return bus

    def identities(self) -> dict[int, Identity]:
        """Find every node and read its identity."""
        out = {}
        for node_id, client in self.clients.items():
            client.find_node(2.0)
            out[node_id] = client.identity()
        return out

    def session(
        self,
        plan: Plan,
        out_dir: Path,
        *,
        plan_name: str,
        gyro: str = "mems",
        resume: bool = False,
        operator: str | None = None,
        site_name: str | None = None,
        **config: Any,
    ) -> Session:
        """Build a session over every node, with the site taken from the first truth.

        ``resume``: go on with the interrupted session in ``out_dir``, if its recordings came
        from these very units (:func:`~canimucal.runtime.resume.load_resume_state`).
        """
        identities = self.identities()
        if resume:
            serials = {n: i.serial for n, i in identities.items()}
            config["resume_from"] = load_resume_state(out_dir, plan, tuple(self.clients), serials)
        first = next(iter(self.clients.values()))
        rate = float(first.output_data_rate())
        site = self.site()
        devices = {n: device_of(n, i) for n, i in identities.items()}
        cfg = ProcedureConfig(
            plan=plan,
            node_ids=tuple(self.clients),
            sample_rate_hz=rate,
            site=site,
            spec=spec_for_plan(plan_name, gyro),
            devices=devices,
            plan_name=plan_name,
            **config,
        )
        header = {n: recording_header(rate, site, identities[n], n) for n in self.clients}
        for sim in self.sims.values():
            sim.set_pose(0.0, 0.0, 0.0)
        return Session(
            Procedure(cfg),
            self.clients,
            identities,
            out_dir,
            sims=self.sims,
            header=header,
            backup_dir=out_dir / "backups",
            overwrite=True,
            operator_rng=np.random.default_rng(self.seed + 1000),
            operator=operator,
            site_name=site_name,
        )

    def site(self) -> SiteConditions:
        """Return the site of the first truth, with the LSBs the first node reports."""
        accel_lsb, gyro_lsb = next(iter(self.clients.values())).nominal_lsb()
        truth = next(iter(self.truths.values()))
        return SiteConditions(
            g=truth.g,
            latitude=truth.latitude,
            heading=truth.heading,
            accel_lsb=accel_lsb,
            gyro_lsb=gyro_lsb,
        )

    def close(self) -> None:
        """Stop clients and nodes and shut the buses down (idempotent)."""
        for client in self.clients.values():
            client.close()
        self.clients = {}
        if getattr(self, "network", None) is not None and self.network.notifier is not None:
            self.network.notifier.stop(self.network.NOTIFIER_SHUTDOWN_TIMEOUT)
        for sim in self.sims.values():
            sim.stop()
        self.sims = {}
        for bus in self._buses:
            bus.shutdown()
        self._buses = []

    def __enter__(self) -> DemoRig:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()


@dataclass(frozen=True)
class Deviation:
    """One parameter read back from the device against the simulator's truth."""

    name: str
    truth: float
    readback: float
    sigma: float

    @property
    def dev_sigma(self) -> float:
        """(readback − truth) / σ."""
        return (self.readback - self.truth) / self.sigma


def readback_deviations(record: Mapping[str, Any], truth: Truth) -> list[Deviation]:
    """Compare a calibration JSON's ``readback`` with the truth, for every estimated value.

    Accel bias and K (K = M⁻¹ of the read-back correction), gyro bias and the base tilt
    (degrees), each with the σ of the record; values the record holds ``null`` (held at
    nominal) are skipped.
    """
    back = record.get("readback")
    if not back:
        return []
    accel, gyro = record["accel"], record.get("gyro") or {}
    out = []
    k_back = np.linalg.inv(np.asarray(back["accel_correction"], dtype=float))
    for i in range(3):
        out += _dev(
            f"accel.bias[{i}]",
            truth.accel.bias[i],
            back["accel_bias"][i],
            _at(accel.get("bias_sigma"), i),
        )
        out += _dev(
            f"gyro.bias[{i}]",
            truth.gyro.bias[i],
            back["gyro_bias"][i],
            _at(gyro.get("bias_sigma"), i),
        )
        for j in range(3):
            sigma = _at(_at(accel.get("K_sigma"), i), j)
            out += _dev(f"accel.K[{i}][{j}]", truth.accel.K[i, j], k_back[i, j], sigma)
    tilt = record.get("base_tilt_deg") or {}
    sig = tilt.get("sigma") or [None, None]
    for k, (name, true) in enumerate((("alpha0", truth.alpha0), ("beta0", truth.beta0))):
        value = float(np.rad2deg(back["base_tilt_rad"][k]))
        out += _dev(f"base_tilt.{name} (deg)", float(np.rad2deg(true)), value, sig[k])
    return out


def _at(seq: Any, i: int) -> Any:
    return None if seq is None else seq[i]


def _dev(name: str, truth: float, readback: float, sigma: Any) -> list[Deviation]:
    if sigma is None or not sigma > 0:
        return []
    return [Deviation(name, float(truth), float(readback), float(sigma))]


def comparison_table(deviations: Sequence[Deviation]) -> str:
    """Format each read-back value beside the truth with σ and the deviation in σ."""
    lines = [f"{'parameter':<24}{'truth':>12}{'read back':>12}{'σ':>10}{'dev/σ':>8}"]
    for d in deviations:
        lines.append(
            f"{d.name:<24}{d.truth:>12.5g}{d.readback:>12.5g}{d.sigma:>10.2g}{d.dev_sigma:>8.2f}"
        )
    if deviations:
        rms = float(np.sqrt(np.mean([d.dev_sigma**2 for d in deviations])))
        lines.append(f"rms deviation {rms:.2f} σ over {len(deviations)} values (expected ≈ 1)")
    return "\n".join(lines)
