"""The gyro confirms each move: a turn about the vertical not made, made the wrong way or too
far is refused before averaging, with the integrated angle in the message."""

from __future__ import annotations

import numpy as np
import pytest

from canimucal.model.positions import Plan, PlannedPosition, Pose
from canimucal.model.vocabulary.plans import builtin_plan
from canimucal.procedure import events as ev
from canimucal.procedure.machine import Phase
from canimucal.sim.truth import Truth
from tests.support.procedure_bench import Bench, of

LEVEL_TURNS = Plan(
    "custom",
    tuple(PlannedPosition(0.0, 0.0, np.deg2rad(p), seconds=30.0) for p in (0, 90, 180, 270)),
)
"""Level, then turned 90° about y at a time: turns the accelerometer cannot see."""
RECOMMENDED = builtin_plan("recommended")


def _after_level(truth: Truth) -> Bench:
    bench = Bench([truth], LEVEL_TURNS)
    bench.position()
    bench.do("accept")
    target = bench.proc.target
    assert np.rad2deg(target.psi) == pytest.approx(90.0) and target.alpha == target.beta == 0.0
    return bench


def _refused_after(bench: Bench, pose: Pose) -> ev.MoveRefused:
    bench.move(pose, transient_s=2.0)
    bench.run(3.0)
    bench.do("confirm_pose")
    events = bench.run_until(ev.PoseRefused, 10.0)
    assert not of(events, ev.AveragingStarted) and bench.proc.phase is Phase.INSTRUCT
    refused = of(events, ev.MoveRefused)
    assert refused, [type(e).__name__ for e in events]
    return refused[0]


@pytest.fixture
def truth() -> Truth:
    return Truth.random(np.random.default_rng(5), cross_axis_max=0.01)


def test_a_turn_about_the_vertical_not_made_is_refused(truth: Truth) -> None:
    bench = _after_level(truth)
    refused = _refused_after(bench, Pose(0.0, 0.0, 0.0))  # left level, unturned
    assert refused.error_deg == pytest.approx(90.0, abs=5.0)
    assert np.linalg.norm(refused.turn_measured_deg) < 5.0
    assert "not made" in refused.message and "90°" in refused.message
    bench.position()  # turned as asked: averaged
    assert of(bench.events, ev.PositionAveraged)[-1].index == 1


def test_a_turn_the_wrong_way_is_refused(truth: Truth) -> None:
    bench = _after_level(truth)
    refused = _refused_after(bench, Pose(0.0, 0.0, np.deg2rad(-90.0)))
    assert refused.error_deg == pytest.approx(180.0, abs=5.0)
    assert "wrong way" in refused.message


def test_a_turn_of_180_instead_of_90_is_refused(truth: Truth) -> None:
    bench = _after_level(truth)
    refused = _refused_after(bench, Pose(0.0, 0.0, np.deg2rad(180.0)))
    assert refused.error_deg == pytest.approx(90.0, abs=8.0)  # 180° at up to 3 % scale error
    assert "wrong angle" in refused.message
    assert refused.turn_target_deg[1] == pytest.approx(90.0, abs=0.01)


def test_moves_as_planned_pass_with_an_uncalibrated_gyro(truth: Truth) -> None:
    """Scale errors up to 3 % and cross-axis 1 %: every move of the plan passes."""
    bench = Bench([truth], RECOMMENDED)
    for _ in RECOMMENDED.positions:
        bench.position()
        bench.do("accept")
    assert not of(bench.events, ev.PoseRefused)
    assert bench.proc.phase is Phase.READY_TO_SOLVE


def test_move_check_can_be_switched_off(truth: Truth) -> None:
    bench = Bench([truth], LEVEL_TURNS, move_tolerance_deg=None)
    bench.position()
    bench.do("accept")
    bench.run(1.0)
    bench.do("confirm_pose")  # still level: only the accelerometer checks, and it agrees
    assert of(bench.run_until(ev.AveragingStarted, 10.0), ev.AveragingStarted)
