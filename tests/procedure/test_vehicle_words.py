"""Instructions worded for the vehicle: read back, they give the pose's rotation again."""

from __future__ import annotations

import re

import numpy as np
import pytest

from canimucal.errors import InputError
from canimucal.model.frames import position_dcm
from canimucal.model.mounting import DEFAULT_MOUNTING, MountingMap, VehicleAttitude, attitude_dcm
from canimucal.model.positions import Pose
from canimucal.model.vehicle_size import VehicleSize
from canimucal.model.vocabulary.plans import builtin_plan
from canimucal.procedure.posecheck import describe_pose
from tests.support.mounts import all_proper_maps

PLANS = ("two", "five", "recommended", "vehicle")
TUI_COLUMNS = 78
"""The position screen's instruction width at 80 columns (one column of padding a side)."""

_TURN = re.compile(r"turn the vehicle on the spot to ([\d.]+)° (left|right) of the start heading")
_FRONT = re.compile(r"raise the (front|rear) wheels (?:([\d.]+) m \()?([\d.]+)°")
_SIDE = re.compile(r"raise the (left|right) side (?:([\d.]+) m \()?([\d.]+)°")
SIZE = VehicleSize(wheelbase_m=3.5, track_m=1.8)


def read_back(words: str, size: VehicleSize | None = None) -> VehicleAttitude:
    """What an operator following ``words`` does, as angles (the inverse of the wording).

    With ``size`` a tilt is worded as a height too, which must be the angle's on that
    wheelbase or track (to the 1 cm it is worded to).
    """
    turn = front = left = 0.0
    if "turn the vehicle round" in words:
        turn = 180.0
    elif m := _TURN.search(words):
        turn = float(m[1]) * (1 if m[2] == "left" else -1)
    for pattern, length, ahead in ((_FRONT, "wheelbase_m", "front"), (_SIDE, "track_m", "left")):
        if m := pattern.search(words):
            angle = float(m[3]) * (1 if m[1] == ahead else -1)
            assert (m[2] is None) is (size is None), words
            if size is not None:
                rise = getattr(size, length) * np.sin(np.deg2rad(abs(angle)))
                assert abs(float(m[2]) - rise) <= 0.005 + 1e-9, words
            if ahead == "front":
                front = angle
            else:
                left = angle
    if turn != 0.0:
        assert "then come back to the same tyre marks" in words  # every turn says so
    return VehicleAttitude(turn, front, left)


def rotation_angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    cos = (np.trace(a @ b.T) - 1.0) / 2.0
    return float(np.rad2deg(np.arccos(np.clip(cos, -1.0, 1.0))))


@pytest.mark.parametrize("size", [None, SIZE])
@pytest.mark.parametrize("plan", PLANS)
def test_vehicle_words_give_the_pose_back_under_every_mount(
    plan: str, size: VehicleSize | None
) -> None:
    for mounting in all_proper_maps():
        for pose in builtin_plan(plan).positions:
            words = describe_pose(pose, mounting, size)
            target = position_dcm(pose.alpha, pose.beta, pose.psi)
            followed = attitude_dcm(read_back(words, size), mounting)
            # Each angle is worded to 0.1°: three roundings of ≤ 0.05° each.
            assert rotation_angle_deg(followed, target) < 0.16, (mounting.text(), words)
            for line in words.splitlines():
                assert len(line) <= TUI_COLUMNS, line


@pytest.mark.parametrize("plan", PLANS)
def test_body_words_fit_the_tui_width(plan: str) -> None:
    for pose in builtin_plan(plan).positions:
        for line in describe_pose(pose).splitlines():
            assert len(line) <= TUI_COLUMNS, line


def test_vehicle_plan_reads_as_turns_and_ladder_tilts_with_the_default_mount() -> None:
    words = [describe_pose(p, DEFAULT_MOUNTING) for p in builtin_plan("vehicle").positions]
    back = "then come back to the same tyre marks,\nthen park it level"
    start = "put the vehicle at the start heading on the same tyre marks,\nthen raise the"
    assert words == [
        "park the vehicle level at the start heading,\nthen mark where its tyres stand",
        f"turn the vehicle on the spot to 90° right of the start heading,\n{back}",
        f"turn the vehicle round on the spot (180° from the start heading),\n{back}",
        f"turn the vehicle on the spot to 90° left of the start heading,\n{back}",
        f"{start} rear wheels 10°",
        f"{start} front wheels 10°",
        f"{start} left side 10°",
        f"{start} right side 10°",
    ]


def test_with_its_wheelbase_and_track_a_tilt_is_worded_as_a_height() -> None:
    """Issue 22 item 6: "raise the front wheels 0.61 m (10°)" on a 3.5 m wheelbase."""
    size = VehicleSize(wheelbase_m=3.5, track_m=1.8)
    plan = builtin_plan("vehicle").positions
    words = [describe_pose(p, DEFAULT_MOUNTING, size).splitlines()[-1] for p in plan[4:]]
    rise = 3.5 * np.sin(np.deg2rad(10.0))  # wheelbase · sin(pitch): the other axle stays down
    side = 1.8 * np.sin(np.deg2rad(10.0))  # track · sin(roll)
    assert f"{rise:.2f}" == "0.61"
    assert words == [
        f"then raise the rear wheels {rise:.2f} m (10°)",
        f"then raise the front wheels {rise:.2f} m (10°)",
        f"then raise the left side {side:.2f} m (10°)",
        f"then raise the right side {side:.2f} m (10°)",
    ]
    only_wheelbase = describe_pose(plan[6], DEFAULT_MOUNTING, VehicleSize(wheelbase_m=3.5))
    assert only_wheelbase.endswith("raise the left side 10°")  # no track: the angle alone
    with pytest.raises(InputError, match="wheelbase_m must be a length in metres"):
        VehicleSize(wheelbase_m=350.0)  # centimetres typed for metres


def test_a_unit_turned_in_the_vehicle_changes_the_words_not_the_pose() -> None:
    """+x to the left instead of the front: raising +z (beta) now raises the rear."""
    turned = MountingMap.parse("x=left,y=down,z=back")
    pose = Pose.from_deg(0.0, 10.0)
    assert describe_pose(pose, DEFAULT_MOUNTING).endswith("raise the left side 10°")
    assert describe_pose(pose, turned).endswith("raise the rear wheels 10°")
    assert "about the new x" in describe_pose(pose)  # body wording without a map
