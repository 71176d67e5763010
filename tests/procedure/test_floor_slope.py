"""A sloped floor does not stop the session (issue 22 item 1, docs/design.md §2).

The floor's slope is fixed in the level frame: when the vehicle (or the unit on the
recommended plan) turns, its share of the measured direction turns with the pose. The pose
check predicts each position with the slope the accepted positions showed
(:class:`~canimucal.procedure.posecheck.FloorFit`), so no position of a correctly followed
plan is refused, and the fit recovers the slope.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from canimucal.model.layout import JointSpec
from canimucal.model.positions import Plan, Pose
from canimucal.model.vocabulary.plans import PLANS
from canimucal.procedure import events as ev
from canimucal.procedure.averaging import AveragingPolicy
from canimucal.procedure.machine import Phase
from canimucal.procedure.posecheck import FloorFit, predicted_force
from canimucal.sim.truth import Truth
from tests.support.procedure_bench import Bench, of


def _plan(name: str) -> Plan:
    plan = PLANS[name].plan
    assert plan is not None
    return plan


def _truth(seed: int, slope_deg: tuple[float, float], plan: str) -> Truth:
    """A random unit the plan can determine, on a floor sloped by ``slope_deg``."""
    limits: dict[str, Any] = {"tilt_max_deg": 0.0}
    if plan == "vehicle":  # K held at its 1 % prior: scale errors within it, no cross-axis
        limits.update(cross_axis_max=0.0, scale_error_max=0.017)
    doc = Truth.random(np.random.default_rng(seed), **limits).to_dict()
    del doc["base_tilt_deg"]
    doc["floor_slope_deg"] = list(slope_deg)
    return Truth.from_dict(doc)


def _session(truth: Truth, plan: str, seed: int) -> ev.Solved:
    """Follow ``plan`` exactly on the simulated unit; fail on the first refused pose."""
    spec = JointSpec(accel_k=PLANS[plan].accel_k, tilt="rigid", gyro="mems")
    bench = Bench([truth], _plan(plan), seed=seed, spec=spec, averaging=AveragingPolicy(2.0))
    while bench.proc.phase is not Phase.READY_TO_SOLVE:
        bench.move(bench.proc.target)
        bench.run(1.5)
        bench.do("confirm_pose")
        kinds = (ev.PositionAveraged, ev.PoseRefused, ev.MoveRefused)
        out = bench.run_until(kinds, 60.0, block_n=50)
        refused = of(out, ev.PoseRefused) + of(out, ev.MoveRefused)
        assert not refused, f"position {bench.proc.index + 1}: {refused[0].message}"
        bench.do("accept")
    return of(bench.do("solve"), ev.Solved)[0]


def _slope_recovered(solved: ev.Solved, truth: Truth) -> None:
    joint = solved.solutions[0x10].joint
    assert joint is not None
    names = list(joint.names)
    sigma = np.sqrt(np.diag(joint.covariance))
    for name, true in (("alpha0", truth.alpha0), ("beta0", truth.beta0)):
        k = next(i for i, n in enumerate(names) if n.endswith(name))
        assert abs(joint.values[k] - true) < 4 * sigma[k], (name, joint.values[k], true)


@pytest.mark.parametrize(
    ("plan", "slope_deg"), [("vehicle", (1.5, 1.5)), ("recommended", (1.4, 1.0))]
)
def test_the_issue_slopes_complete_and_the_slope_is_recovered(
    plan: str, slope_deg: tuple[float, float]
) -> None:
    truth = _truth(22, slope_deg, plan)
    _slope_recovered(_session(truth, plan, seed=5), truth)


@pytest.mark.parametrize("plan", ["vehicle", "recommended"])
def test_slopes_up_to_3_degrees_every_session_completes(plan: str) -> None:
    rng = np.random.default_rng(2203)
    for seed in range(4):
        slope = rng.uniform(-3.0, 3.0, 2)
        truth = _truth(100 + seed, (float(slope[0]), float(slope[1])), plan)
        _slope_recovered(_session(truth, plan, seed=seed), truth)


def test_a_unit_frame_offset_would_refuse_the_turn_the_floor_fit_accepts() -> None:
    """The old prediction (first position's excess as a fixed offset in the unit frame) is
    off by twice the slope after a half turn; the level-frame slope is not."""
    g = 9.81
    slope = Truth.from_dict({"floor_slope_deg": [1.5, 1.5]})
    level, round_ = Pose.from_deg(0, 0, 0), Pose.from_deg(0, 0, 180)

    def seen(pose: Pose) -> np.ndarray:
        from canimucal.model.frames import position_dcm, specific_force_level

        c = position_dcm(pose.alpha, pose.beta, pose.psi, slope.alpha0, slope.beta0)
        return c @ specific_force_level(g) + np.array([0.02, -0.03, 0.01])

    offset = seen(level) - predicted_force(level, g)
    old = FloorFit(g).check(round_, seen(round_) - offset, 3.0)
    assert not old.passed and old.error_deg > 4.0
    floor = FloorFit(g)
    floor.add(level, seen(level))
    assert floor.check(round_, seen(round_), 3.0).error_deg < 0.3
    floor.add(Pose.from_deg(0, 0, 90), seen(Pose.from_deg(0, 0, 90)))
    assert floor.check(round_, seen(round_), 3.0).error_deg < 0.01
    wrong_sign = Pose.from_deg(-10, 0, 0)
    assert not floor.check(Pose.from_deg(10, 0, 0), seen(wrong_sign), 3.0).passed
