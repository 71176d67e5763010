"""The pose check before averaging, and a target pose in words (docs/design.md §2 directions).

The measured specific force ``f = lsb · U − offset`` (nominal K; ``offset`` is what the
first accepted position showed beyond its prediction: bias and base tilt) is compared with
the target's ``C(alpha, beta, psi) f_L``. The angle between the two vectors must be within
the tolerance, so a tilt of the wrong sign (twice the tilt off) or the wrong size is refused.
For display the measurement is turned back by the target's psi and read as (alpha, beta)
with :func:`~canimucal.model.frames.gravity_direction_angles`.

A target is worded in the unit's body axes (bench use) or, given a mounting map, as the
vehicle's turn on the spot and front and side tilts read from the pose's rotation
(:func:`~canimucal.model.mounting.vehicle_attitude`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from canimucal.model.frames import ay, gravity_direction_angles, position_dcm, specific_force_level
from canimucal.model.mounting import MountingMap, vehicle_attitude
from canimucal.model.positions import Pose

Array = NDArray[np.float64]


@dataclass(frozen=True)
class PoseCheck:
    """Measured against target: (alpha, beta) in degrees and the angle between the f vectors."""

    measured_deg: tuple[float, float]
    target_deg: tuple[float, float]
    error_deg: float
    tolerance_deg: float

    @property
    def passed(self) -> bool:
        """Whether the measured direction is within the tolerance of the target's."""
        return self.error_deg <= self.tolerance_deg

    @property
    def tilt_error_deg(self) -> tuple[float, float]:
        """(measured − target) of alpha and beta, degrees."""
        return (
            self.measured_deg[0] - self.target_deg[0],
            self.measured_deg[1] - self.target_deg[1],
        )

    def message(self) -> str:
        """One line for the operator."""
        da, db = self.tilt_error_deg
        return (
            f"measured alpha {self.measured_deg[0]:+.1f}°, beta {self.measured_deg[1]:+.1f}° "
            f"against target {self.target_deg[0]:+.1f}°, {self.target_deg[1]:+.1f}° "
            f"(off by {da:+.1f}°, {db:+.1f}°; {self.error_deg:.1f}° > {self.tolerance_deg:g}°): "
            "check the sign and size of the tilt"
        )


def predicted_force(pose: Pose, g: float) -> Array:
    """``C(alpha, beta, psi) f_L`` (m/s²), no base tilt."""
    return position_dcm(pose.alpha, pose.beta, pose.psi) @ specific_force_level(g)


def measured_force(mean_counts: Array, accel_lsb: float, offset_ms2: Array | None) -> Array:
    """Nominal specific force of a mean: ``lsb · U − offset`` (m/s²)."""
    f = accel_lsb * np.asarray(mean_counts, dtype=float)
    return f if offset_ms2 is None else f - offset_ms2


def check_pose(pose: Pose, f_measured: Array, g: float, tolerance_deg: float) -> PoseCheck:
    """Compare a measured specific force with the target pose's."""
    f_target = predicted_force(pose, g)
    cross = float(np.linalg.norm(np.cross(f_measured, f_target)))
    error = float(np.rad2deg(np.arctan2(cross, float(np.dot(f_measured, f_target)))))
    unturned = ay(pose.psi).T @ f_measured
    alpha, beta = gravity_direction_angles(unturned)
    return PoseCheck(
        (float(np.rad2deg(alpha)), float(np.rad2deg(beta))),
        (float(np.rad2deg(pose.alpha)), float(np.rad2deg(pose.beta))),
        error,
        tolerance_deg,
    )


def describe_pose(pose: Pose, mounting: MountingMap | None = None) -> str:
    """Describe the pose in words: for the vehicle given a ``mounting`` map, else in body axes."""
    if mounting is not None:
        return describe_vehicle_pose(pose, mounting)
    return describe_body_pose(pose)


_WORDING_STEP_DEG = 0.1
"""Vehicle angles are worded to 0.1° (a ladder tilt is set to a few tenths at best)."""


def describe_vehicle_pose(pose: Pose, mounting: MountingMap) -> str:
    """Word ``pose`` as the vehicle's turn on the spot, then its front and side tilt.

    The turn is relative to the vehicle's heading at the plan's reference pose (the start
    heading); "raise the front wheels" then "raise the left side" are the pitch and roll of
    :func:`~canimucal.model.mounting.vehicle_attitude`, in that order. One step a line.
    """
    attitude = vehicle_attitude(pose, mounting)
    turn, front, left = (
        round(a / _WORDING_STEP_DEG) * _WORDING_STEP_DEG + 0.0
        for a in (attitude.turn_left_deg, attitude.front_up_deg, attitude.left_up_deg)
    )
    tilts = []
    if front != 0.0:
        tilts.append(f"raise the {'front' if front > 0 else 'rear'} wheels {abs(front):g}°")
    if left != 0.0:
        tilts.append(f"raise the {'left' if left > 0 else 'right'} side {abs(left):g}°")
    if turn == 0.0:
        if not tilts:
            return "park the vehicle level at the start heading"
        steps = ["keep the vehicle at the start heading"]
    elif abs(turn) == 180.0:
        steps = ["turn the vehicle round on the spot (180° from the start heading)"]
    else:
        side = "left" if turn > 0 else "right"
        steps = [f"turn the vehicle on the spot to {abs(turn):g}° {side} of the start heading"]
    return _steps(steps + (tilts or ["park it level"]))


def _steps(steps: list[str]) -> str:
    """Join instruction steps one a line (each fits the TUI's 78 columns)."""
    return ",\nthen ".join(steps)


def describe_body_pose(pose: Pose) -> str:
    """Describe the pose in the unit's body axes (docs/design.md §2 directions; bench use)."""
    alpha, beta, psi = (float(np.rad2deg(x)) for x in pose.angles)
    parts = []
    if abs(alpha) > 1e-9:
        end = "lower" if alpha > 0 else "raise"
        parts.append(f"tilt {abs(alpha):g}° about z ({end} the +x end)")
    if abs(beta) > 1e-9:
        end = "raise" if beta > 0 else "lower"
        parts.append(f"tilt {abs(beta):g}° about the new x ({end} the +z end)")
    if not parts:
        parts.append("set the unit level on the base")
    turn = psi % 360.0
    if turn > 1e-9:
        parts.append(f"turn the unit {turn:g}° on its face (+z toward +x, clockwise from above)")
    return _steps(parts)
