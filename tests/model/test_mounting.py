"""The mounting map (unit axes → vehicle directions) and a pose read as the vehicle's attitude."""

from __future__ import annotations

import numpy as np
import pytest

from canimucal.errors import InputError
from canimucal.model.frames import position_dcm
from canimucal.model.mounting import (
    DEFAULT_MOUNTING,
    MountingMap,
    VehicleAttitude,
    attitude_dcm,
    start_frame,
    vehicle_attitude,
)
from canimucal.model.positions import Pose
from canimucal.model.vocabulary.plans import builtin_names, builtin_plan
from tests.support.mounts import all_proper_maps


def test_exactly_the_24_rotations_are_accepted() -> None:
    maps = all_proper_maps()
    assert len(maps) == 24
    for m in maps:
        assert np.allclose(m.matrix @ m.matrix.T, np.eye(3))
        assert np.linalg.det(m.matrix) == pytest.approx(1.0)


def test_parse_round_trips_and_accepts_aliases() -> None:
    m = MountingMap.parse(" X=Fwd, z=left ,y=down")
    assert m == DEFAULT_MOUNTING
    assert MountingMap.parse(m.text()) == m
    assert MountingMap.parse("x=rear,y=down,z=right").x == "back"


@pytest.mark.parametrize(
    ("text", "fragment"),
    [
        ("x=forward,y=left,z=down", "mirror image"),
        ("x=forward,y=back,z=up", "exactly once"),
        ("x=forward,y=down", "unit z not given"),
        ("x=forward,x=down,z=left", "given twice"),
        ("x=sideways,y=down,z=left", "not one of"),
        ("forward,down,left", "AXIS=DIRECTION"),
        ("", "AXIS=DIRECTION"),
    ],
)
def test_bad_maps_are_one_line_input_errors(text: str, fragment: str) -> None:
    with pytest.raises(InputError, match=fragment) as info:
        MountingMap.parse(text)
    assert "\n" not in str(info.value)


def test_default_map_reads_the_vehicle_plan_as_turns_and_ladder_tilts() -> None:
    got = [vehicle_attitude(p, DEFAULT_MOUNTING) for p in builtin_plan("vehicle").positions]
    expected = [
        (0, 0, 0),
        (-90, 0, 0),  # psi +90: +z (left) toward +x (forward), clockwise from above: right
        (180, 0, 0),
        (90, 0, 0),
        (0, -10, 0),  # alpha +10 lowers the +x end: the front
        (0, 10, 0),
        (0, 0, 10),  # beta +10 raises the +z end: the left side
        (0, 0, -10),
    ]
    for attitude, (turn, front, left) in zip(got, expected, strict=True):
        assert abs((attitude.turn_left_deg - turn + 180) % 360 - 180) < 1e-9
        assert attitude.front_up_deg == pytest.approx(front, abs=1e-9)
        assert attitude.left_up_deg == pytest.approx(left, abs=1e-9)


@pytest.mark.parametrize("plan", builtin_names())
def test_attitude_composes_back_to_the_pose_under_every_map(plan: str) -> None:
    for mounting in all_proper_maps():
        for pose in builtin_plan(plan).positions:
            attitude = vehicle_attitude(pose, mounting)
            c = position_dcm(pose.alpha, pose.beta, pose.psi)
            np.testing.assert_allclose(attitude_dcm(attitude, mounting), c, atol=1e-12)


def test_a_rotated_mount_sees_the_same_physical_pose_as_another_vehicle_attitude() -> None:
    """The unit turned 90° on its face in the vehicle: the same vehicle motion, other poses."""
    turned = MountingMap("left", "down", "back")  # DEFAULT turned: +x now points left
    attitude = VehicleAttitude(30.0, 7.0, -4.0)
    c_default = attitude_dcm(attitude, DEFAULT_MOUNTING)
    c_turned = attitude_dcm(attitude, turned)
    # The same vehicle motion: the unit DCMs differ by the mount rotation on the left and by
    # the start headings (each mount's reference pose faces the vehicle another way) on the right.
    rel = turned.matrix.T @ DEFAULT_MOUNTING.matrix
    heading = start_frame(DEFAULT_MOUNTING).T @ start_frame(turned)
    np.testing.assert_allclose(rel @ c_default @ heading, c_turned, atol=1e-12)
    pose = Pose.from_deg(0.0, 10.0)  # raises +z: the left side by default, the rear here
    assert vehicle_attitude(pose, DEFAULT_MOUNTING).left_up_deg == pytest.approx(10.0)
    assert vehicle_attitude(pose, turned).front_up_deg == pytest.approx(-10.0)
