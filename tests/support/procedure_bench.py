"""Helpers of the procedure tests: blocks injected straight from the simulator (no CAN).

:class:`Bench` owns one :class:`ImuSimulator` per node (one rigid body: every node is moved
together) and a :class:`Procedure`; :meth:`Bench.run` feeds blocks of ``block_n`` samples to
the machine, node by node, and collects the events. Blocks may be altered on the way
(``alter``), e.g. to drop PDO halves or to add a bump.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from canimucal.analysis.calibrate import SiteConditions
from canimucal.model.layout import JointSpec
from canimucal.model.positions import Plan, Pose
from canimucal.model.samples import SampleBlock
from canimucal.procedure import events as ev
from canimucal.procedure.averaging import AveragingPolicy
from canimucal.procedure.machine import Phase, Procedure, ProcedureConfig
from canimucal.sim.imu import ImuSimulator
from canimucal.sim.truth import Truth

Alter = Callable[[int, SampleBlock], SampleBlock]


def to_sample_block(sim: ImuSimulator, n: int, first_counter: int) -> SampleBlock:
    """``n`` simulator samples as the client would hand them over (no loss)."""
    b = sim.next_block(n)
    return SampleBlock(
        t=np.asarray(b.t_s, float),
        counter=(np.arange(n) + first_counter) % 65536,
        accel=np.asarray(b.accel, float),
        gyro=np.asarray(b.gyro, float),
        temp_c=float(b.temp_c[-1]),
        status=0,
        lost_accel=0,
        lost_gyro=0,
        lost_samples=0,
        duplicates=0,
        late=0,
    )


class Bench:
    """Simulated node(s) feeding a procedure directly; see the module doc."""

    def __init__(
        self,
        truths: Sequence[Truth],
        plan: Plan,
        *,
        seed: int = 11,
        spec: JointSpec | None = None,
        **config: Any,
    ) -> None:
        first = truths[0]
        self.node_ids = tuple(0x10 + i for i in range(len(truths)))
        self.sims = {
            n: ImuSimulator(t, seed=seed + i)
            for i, (n, t) in enumerate(zip(self.node_ids, truths, strict=True))
        }
        self.counters = dict.fromkeys(self.node_ids, 0)
        config.setdefault("averaging", AveragingPolicy(fixed_s=3.0))
        config.setdefault("warmup", False)
        site = SiteConditions(
            g=first.g,
            latitude=first.latitude,
            heading=first.heading,
            accel_lsb=first.accel.nominal_lsb,
            gyro_lsb=first.gyro.nominal_lsb,
        )
        self.fs = float(first.sample_rate_hz)
        cfg = ProcedureConfig(
            plan=plan,
            node_ids=self.node_ids,
            sample_rate_hz=self.fs,
            site=site,
            spec=spec or JointSpec(accel_k="diag", tilt="rigid", gyro="mems"),
            plan_name=plan.name,
            **config,
        )
        self.proc = Procedure(cfg)
        self.events: list[ev.Event] = list(self.proc.start())

    def move(self, pose: Pose, transient_s: float = 1.0) -> None:
        """Move every node (one rigid body) to ``pose``."""
        for sim in self.sims.values():
            sim.set_pose(pose.alpha, pose.beta, pose.psi, transient_s=transient_s)

    def run(
        self, seconds: float, *, block_n: int = 20, alter: Alter | None = None
    ) -> list[ev.Event]:
        """Feed ``seconds`` of samples from every node; return (and keep) the events."""
        out: list[ev.Event] = []
        for _ in range(max(1, round(seconds * self.fs / block_n))):
            for node_id, sim in self.sims.items():
                block = to_sample_block(sim, block_n, self.counters[node_id])
                self.counters[node_id] += block_n
                if alter is not None:
                    block = alter(node_id, block)
                out += self.proc.feed(node_id, block)
        self.events += out
        return out

    def run_until(
        self,
        kind: type | tuple[type, ...],
        max_s: float,
        *,
        block_n: int = 20,
        alter: Alter | None = None,
    ) -> list[ev.Event]:
        """Feed until an event of ``kind`` appears (fail after ``max_s`` of samples)."""
        out: list[ev.Event] = []
        for _ in range(max(1, round(max_s * 10))):
            out += self.run(0.1, block_n=block_n, alter=alter)
            if any(isinstance(e, kind) for e in out):
                return out
        raise AssertionError(f"no {kind} within {max_s} s; phase {self.proc.phase}")

    def do(self, command: str) -> list[ev.Event]:
        """Run a machine command and keep its events."""
        out = list(getattr(self.proc, command)())
        self.events += out
        return out

    def position(
        self, *, settle_s: float = 1.5, alter: Alter | None = None, max_s: float = 200.0
    ) -> list[ev.Event]:
        """Move to the current target, confirm, and run until it is averaged (or verified)."""
        self.move(self.proc.target)
        self.run(settle_s)
        out = self.do("confirm_pose")
        done = (ev.PositionAveraged, ev.PoseVerified)
        return out + self.run_until(done, max_s, alter=alter, block_n=50)

    def whole_plan(self) -> None:
        """Every position averaged and accepted; ready to solve."""
        while self.proc.phase is not Phase.READY_TO_SOLVE:
            self.position()
            self.do("accept")


def of(events: Sequence[ev.Event], kind: type) -> list[Any]:
    """The events of one kind."""
    return [e for e in events if isinstance(e, kind)]
