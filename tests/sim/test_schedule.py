"""Schedules of the simulated unit: where an operator sets each pose, and the first move."""

from __future__ import annotations

import numpy as np

from canimucal.model.positions import Plan, PlannedPosition
from canimucal.sim.schedule import ALREADY_THERE_SIGMAS, PoseTrajectory, set_by_operator

TOL = np.deg2rad(0.2)
PSI_TOL = np.deg2rad(5.0)


def _plan(n: int) -> Plan:
    pose = PlannedPosition(0.3, -0.2, 1.0, TOL, 10.0, psi_tolerance=PSI_TOL)
    return Plan("custom", (pose,) * n, prior_k_sigma=0.01)


def test_operator_errors_have_each_angles_own_sigma() -> None:
    plan = _plan(4000)
    placed = set_by_operator(plan, np.random.default_rng(7))
    errors = np.array([p.angles for p in placed.positions]) - plan.positions[0].angles
    # 4000 draws: the sample σ is within 5 % of the true one at ~3.2σ of its own spread
    assert np.allclose(errors.std(axis=0), [TOL, TOL, PSI_TOL], rtol=0.05)
    assert np.allclose(errors.mean(axis=0), 0.0, atol=4 * np.array([TOL, TOL, PSI_TOL]) / 63)
    first = placed.positions[0]
    assert (first.tolerance, first.psi_tolerance, first.seconds) == (TOL, PSI_TOL, 10.0)
    assert placed.prior_k_sigma == 0.01 and placed.name == "custom"
    assert plan.positions[0].alpha == 0.3  # the nominal plan is left as it was


def test_same_seed_same_poses() -> None:
    a = set_by_operator(_plan(3), np.random.default_rng(1))
    b = set_by_operator(_plan(3), np.random.default_rng(1))
    assert a == b


def _first_hold_start(start: tuple[float, float, float], plan: Plan) -> float:
    trajectory = PoseTrajectory()
    trajectory.move_to(0.0, start, 0.0)
    trajectory.follow(0.0, plan, 1.0)
    t = np.arange(0.0, 3.0, 0.01)
    return float(t[np.argmax(trajectory.sample(t).index == 0)])


def test_no_move_first_when_already_there_within_the_setting_accuracy() -> None:
    """A recorder that knows the nominal plan starts the first hold at once when the unit
    starts at the nominal first pose; the unit set there by an operator (off by its draw)
    must too, or every label is a transient early."""
    plan = _plan(2)
    near = (0.3 + 3.0 * TOL, -0.2 - 3.0 * TOL, 1.0 + 4.0 * PSI_TOL)
    assert _first_hold_start(near, plan) == 0.0
    far = (0.3 + (ALREADY_THERE_SIGMAS + 1.0) * TOL, -0.2, 1.0)
    assert _first_hold_start(far, plan) >= 1.0
