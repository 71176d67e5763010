"""Helpers of the TUI tests: a source with no CAN, a solved result, events, the screen as text."""

from __future__ import annotations

import io
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from rich.console import Console
from textual.app import App

from canimucal.analysis.acceptance import AcceptanceLimits, check_acceptance
from canimucal.analysis.calibrate import SiteConditions, solve_positions
from canimucal.device.client import CalibrationReadout, Identity
from canimucal.device.od import factory_block
from canimucal.errors import InputError, NoDeviceError
from canimucal.model.mounting import MountingMap
from canimucal.model.positions import Plan
from canimucal.model.sensor import DEFAULT_ACCEL_LSB, DEFAULT_GYRO_LSB
from canimucal.model.vocabulary.plans import builtin_plan
from canimucal.procedure import events as ev
from canimucal.runtime.session import Session, device_of
from canimucal.runtime.wiring import spec_for_plan
from canimucal.sim.averages import simulate_averages
from canimucal.sim.truth import Truth
from canimucal.tui.source import Heartbeat, NodeStatus

SERIAL = 4242
G = 9.80665


def node_status(node_id: int = 0x10, serial: int = SERIAL) -> NodeStatus:
    """A factory-calibrated node as the connection screen would read it."""
    identity = Identity(0x0000ABCD, 0x1, 0x10000, serial, "canimucal IMU")
    block = factory_block(DEFAULT_ACCEL_LSB, DEFAULT_GYRO_LSB)
    readout = CalibrationReadout(block, 0, 0, False, {})
    return NodeStatus(node_id, identity, readout, DEFAULT_ACCEL_LSB, DEFAULT_GYRO_LSB, 200.0, "sdo")


@dataclass
class FakeSource:
    """A source with fixed node statuses and no session (events are injected instead)."""

    out_dir: Path
    statuses: list[NodeStatus] = field(default_factory=lambda: [node_status()])
    fail: bool = False
    description: str = "test bus (no CAN)"
    closed: int = 0
    mount: MountingMap | str | None = None
    replace_mount: bool = False

    def connect(self) -> list[NodeStatus]:
        if self.fail:
            raise NoDeviceError("no CAN interface 'socketcan' on channel 'can9'")
        return self.statuses

    def heartbeat(self, node_id: int) -> Heartbeat:
        return Heartbeat("OPERATIONAL", 0.25)

    def open(self, plan: Plan, plan_name: str, gyro: str) -> Session:
        raise InputError("the fake source has no session")

    def close(self) -> None:
        self.closed += 1


def solved_event(
    plan_name: str = "five", seed: int = 5, seconds: float = 30.0, gyro: str = "mems"
) -> ev.Solved:
    """A real solve of simulated averages (no CAN): what the procedure emits after 'solve'."""
    rng = np.random.default_rng(seed)
    truth = Truth.random(rng, cross_axis_max=0.0)
    base = builtin_plan(plan_name)
    plan = base.with_total_seconds(seconds * len(base.positions))
    averages = simulate_averages(
        plan.positions,
        truth.accel.params(),
        rng,
        g=G,
        gyro=truth.gyro.params(),
        alpha0=truth.alpha0,
        beta0=truth.beta0,
        accel_noise_density=3.0,
        gyro_noise_density=3.0,
    )
    site = SiteConditions(g=G, latitude=truth.latitude, heading=truth.heading)
    spec = spec_for_plan(plan_name, gyro)
    solution = solve_positions(
        averages, spec, site, device_of(0x10, node_status().identity), plan_name=plan_name
    )
    report = check_acceptance(solution, AcceptanceLimits(), DEFAULT_ACCEL_LSB, G)
    return ev.Solved({0x10: solution}, {0x10: report})


def live(node_id: int = 0x10, t: float = 12.0, spark: tuple[float, ...] = (0.01, -0.02, 0.03)):
    """A live readout event (level pose, 0.2° off in alpha)."""
    return ev.SamplesReceived(
        node_id,
        t,
        np.array([0.01, -9.80, 0.02]),
        np.array([1e-5, -5e-5, 4e-5]),
        25.0,
        (0.2, -0.1),
        3.5,
        spark,
        7,
    )


def screen_text(app: App[object]) -> str:
    """The current screen as plain text (what a terminal of the app's size shows)."""
    width, height = app.size
    console = Console(
        width=width,
        height=height,
        file=io.StringIO(),
        force_terminal=True,
        color_system=None,
        record=True,
        legacy_windows=False,
    )
    update = app.screen._compositor.render_update(full=True, screen_stack=app._background_screens)
    console.print(update)
    return console.export_text(styles=False)
