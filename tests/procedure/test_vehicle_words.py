"""Instructions worded for the vehicle: read back, they give the pose's rotation again."""

from __future__ import annotations

import re

import numpy as np
import pytest

from canimucal.model.frames import position_dcm
from canimucal.model.mounting import DEFAULT_MOUNTING, MountingMap, VehicleAttitude, attitude_dcm
from canimucal.model.positions import Pose
from canimucal.model.vocabulary.plans import builtin_plan
from canimucal.procedure.posecheck import describe_pose
from tests.support.mounts import all_proper_maps

PLANS = ("two", "five", "recommended", "vehicle")
TUI_COLUMNS = 78
"""The position screen's instruction width at 80 columns (one column of padding a side)."""

_TURN = re.compile(r"turn the vehicle on the spot to ([\d.]+)° (left|right) of the start heading")
_FRONT = re.compile(r"raise the (front|rear) wheels ([\d.]+)°")
_SIDE = re.compile(r"raise the (left|right) side ([\d.]+)°")


def read_back(words: str) -> VehicleAttitude:
    """What an operator following ``words`` does, as angles (the inverse of the wording)."""
    turn = front = left = 0.0
    if "turn the vehicle round" in words:
        turn = 180.0
    elif m := _TURN.search(words):
        turn = float(m[1]) * (1 if m[2] == "left" else -1)
    if m := _FRONT.search(words):
        front = float(m[2]) * (1 if m[1] == "front" else -1)
    if m := _SIDE.search(words):
        left = float(m[2]) * (1 if m[1] == "left" else -1)
    return VehicleAttitude(turn, front, left)


def rotation_angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    cos = (np.trace(a @ b.T) - 1.0) / 2.0
    return float(np.rad2deg(np.arccos(np.clip(cos, -1.0, 1.0))))


@pytest.mark.parametrize("plan", PLANS)
def test_vehicle_words_give_the_pose_back_under_every_mount(plan: str) -> None:
    for mounting in all_proper_maps():
        for pose in builtin_plan(plan).positions:
            words = describe_pose(pose, mounting)
            target = position_dcm(pose.alpha, pose.beta, pose.psi)
            followed = attitude_dcm(read_back(words), mounting)
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
    assert words == [
        "park the vehicle level at the start heading",
        "turn the vehicle on the spot to 90° right of the start heading,\nthen park it level",
        "turn the vehicle round on the spot (180° from the start heading),\nthen park it level",
        "turn the vehicle on the spot to 90° left of the start heading,\nthen park it level",
        "keep the vehicle at the start heading,\nthen raise the rear wheels 10°",
        "keep the vehicle at the start heading,\nthen raise the front wheels 10°",
        "keep the vehicle at the start heading,\nthen raise the left side 10°",
        "keep the vehicle at the start heading,\nthen raise the right side 10°",
    ]


def test_a_unit_turned_in_the_vehicle_changes_the_words_not_the_pose() -> None:
    """+x to the left instead of the front: raising +z (beta) now raises the rear."""
    turned = MountingMap.parse("x=left,y=down,z=back")
    pose = Pose.from_deg(0.0, 10.0)
    assert describe_pose(pose, DEFAULT_MOUNTING).endswith("raise the left side 10°")
    assert describe_pose(pose, turned).endswith("raise the rear wheels 10°")
    assert "about the new x" in describe_pose(pose)  # body wording without a map
