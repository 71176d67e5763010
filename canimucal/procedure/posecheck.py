"""The pose check before averaging, and a target pose in words (docs/design.md §2 directions).

The measured specific force ``f = lsb · U`` (nominal K) is compared with the target's
``C(alpha, beta, psi) T0 f_L + b``: ``T0`` the floor slope (a tilt fixed in the level frame,
docs/design.md §2, so it turns with the pose) and ``b`` a bias in the unit's frame, both
estimated by :class:`FloorFit` from the positions accepted so far. The angle between the two
directions must be within the tolerance, so a tilt of the wrong sign (twice the tilt off) or
the wrong size is refused. Where the accepted positions cannot tell slope from bias (after
the first position only), every split between them is tried and the closest one counts.
For display the measurement is referred to a level floor, turned back by the target's psi and
read as (alpha, beta) with :func:`~canimucal.model.frames.gravity_direction_angles`.

A target is worded in the unit's body axes (bench use) or, given a mounting map, as the
vehicle's turn on the spot and front and side tilts read from the pose's rotation
(:func:`~canimucal.model.mounting.vehicle_attitude`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from canimucal.model.frames import ay, gravity_direction_angles, position_dcm, specific_force_level
from canimucal.model.mounting import MountingMap, vehicle_attitude
from canimucal.model.positions import Pose
from canimucal.model.vehicle_size import VehicleSize

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


def measured_force(mean_counts: Array, accel_lsb: float) -> Array:
    """Nominal specific force of a mean: ``lsb · U`` (m/s²)."""
    return accel_lsb * np.asarray(mean_counts, dtype=float)


_SLOPE_JACOBIAN = np.array([[-1.0, 0.0], [0.0, 0.0], [0.0, 1.0]])
"""``d(T0 f_L)/d(alpha0, beta0)`` at a level floor, per unit of g (docs/design.md §2)."""
_SEPARABLE = 0.05
"""Singular values below this share of the largest are directions the positions leave open."""
_SPLITS = np.linspace(0.0, 1.0, 21)
"""Splits tried between all-slope and all-bias along the directions left open."""


@dataclass
class FloorFit:
    """What the accepted positions showed beyond their prediction: floor slope and bias.

    The model of a nominal specific force at pose ``C``: ``C T0(alpha0, beta0) f_L + b``;
    ``T0`` is the rigid base tilt of docs/design.md §2 (the floor's slope, fixed in the level
    frame: it turns with the vehicle or the unit), ``b`` a bias in the unit frame (m/s²).
    Linear least squares in the small slope; measured vectors are scaled to ``|f| = g`` first
    (a scale error of the nominal K does not tilt anything). Directions of the parameters the
    accepted positions do not determine are kept open: the readings run from the
    all-slope to the all-bias one (after a level first position: the horizontal residual as
    slope, or as bias). The readings of the first position, of the first two, … are all
    kept (:meth:`candidates`): a scale or cross-axis error of the nominal K, not modelled
    here, can pull a later fit off by a degree at a 45° pose, and the first position's
    all-bias reading is the unit-frame offset the check used before the floor was modelled.
    :meth:`check` takes the reading closest to the measurement: none of them is more than a
    few degrees, so a tilt of the wrong sign or size is still refused.
    """

    g: float
    seen: list[tuple[Pose, Array]] = field(default_factory=list)
    _candidates: list[tuple[float, float, Array]] = field(default_factory=list, repr=False)
    _slopes: Array = field(default_factory=lambda: np.zeros((0, 3, 3)), repr=False)
    _biases: Array = field(default_factory=lambda: np.zeros((0, 3)), repr=False)

    def add(self, pose: Pose, f_nominal: Array) -> None:
        """Take an accepted position's nominal specific force (m/s²) at its target ``pose``."""
        self.seen.append((pose, np.asarray(f_nominal, dtype=float)))
        self._candidates += self._fit(self.seen)
        self._slopes = np.stack([position_dcm(0.0, 0.0, 0.0, a, b) for a, b, _ in self._candidates])
        self._biases = np.stack([bias for _, _, bias in self._candidates])

    @property
    def empty(self) -> bool:
        """Whether no position has been accepted yet."""
        return not self.seen

    def candidates(self) -> list[tuple[float, float, Array]]:
        """``(alpha0, beta0, b)`` readings of what was seen (radians, m/s²); none when empty."""
        return list(self._candidates)

    def _fit(self, seen: list[tuple[Pose, Array]]) -> list[tuple[float, float, Array]]:
        rows, residuals = [], []
        for pose, f in seen:
            norm = float(np.linalg.norm(f))
            scaled = f * (self.g / norm) if norm > 0 else f
            c = position_dcm(pose.alpha, pose.beta, pose.psi)
            rows.append(np.hstack([c @ _SLOPE_JACOBIAN, np.eye(3)]))
            residuals.append((scaled - c @ specific_force_level(self.g)) / self.g)
        a, r = np.vstack(rows), np.concatenate(residuals)
        u, s, vt = np.linalg.svd(a, full_matrices=True)
        rank = int(np.sum(s > _SEPARABLE * s[0]))
        q0 = vt[:rank].T @ ((u[:, :rank].T @ r) / s[:rank])
        open_dirs = vt[rank:].T
        if open_dirs.shape[1] == 0:
            ends = [q0]
        else:
            ends = [
                q0 - open_dirs @ (np.linalg.pinv(part @ open_dirs) @ (part @ q0))
                for part in (np.eye(5)[2:], np.eye(5)[:2])  # no bias; no slope
            ]
        out = []
        for lam in _SPLITS if len(ends) == 2 else (0.0,):
            q = (1.0 - lam) * ends[0] + lam * ends[-1]
            out.append((float(q[0]), float(q[1]), self.g * q[2:]))
        return out

    def check(self, pose: Pose, f_nominal: Array, tolerance_deg: float) -> PoseCheck:
        """Check ``f_nominal`` (m/s²) against ``pose`` with the reading that fits it best.

        Before any position was accepted: the plain :func:`check_pose`.
        """
        f = np.asarray(f_nominal, dtype=float)
        if not self._candidates:
            return check_pose(pose, f, self.g, tolerance_deg)
        c = position_dcm(pose.alpha, pose.beta, pose.psi)
        # every reading at once: the measurement referred to a level floor, m = C T0ᵀ Cᵀ (f − b)
        turned = np.einsum("ij,njk,lk->nil", c, self._slopes.transpose(0, 2, 1), c)
        on_level_floor = np.einsum("nij,nj->ni", turned, f[None, :] - self._biases)
        target = predicted_force(pose, self.g)
        cos = (on_level_floor @ target) / np.maximum(
            np.linalg.norm(on_level_floor, axis=1) * np.linalg.norm(target), 1e-300
        )
        best = int(np.argmax(cos))
        return check_pose(pose, on_level_floor[best], self.g, tolerance_deg)


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


def describe_pose(
    pose: Pose, mounting: MountingMap | None = None, size: VehicleSize | None = None
) -> str:
    """Describe the pose in words: for the vehicle given a ``mounting`` map, else in body axes.

    ``size`` (the vehicle's wheelbase and track) words the vehicle's tilts as heights.
    """
    if mounting is not None:
        return describe_vehicle_pose(pose, mounting, size)
    return describe_body_pose(pose)


_WORDING_STEP_DEG = 0.1
"""Vehicle angles are worded to 0.1° (a ladder tilt is set to a few tenths at best)."""


BACK_TO_THE_MARKS = "come back to the same tyre marks"
"""Said after every turn on the spot: the floor's slope is the slope under those marks."""
MARK_THE_TYRES = "mark where its tyres stand"
"""Said at the start pose: the marks every later pose comes back to."""


def describe_vehicle_pose(
    pose: Pose, mounting: MountingMap, size: VehicleSize | None = None
) -> str:
    """Word ``pose`` as the vehicle's turn on the spot, then its front and side tilt.

    The turn is relative to the vehicle's heading at the plan's reference pose (the start
    heading), the start pose says to mark the tyres and every other pose to come back to
    those marks (the floor slope the fit learns is the one under them); "raise the front
    wheels" then "raise the left side" are the pitch and roll of
    :func:`~canimucal.model.mounting.vehicle_attitude`, in that order, as heights with
    ``size`` ("raise the front wheels 0.61 m (10°)": wheelbase · sin(pitch), track ·
    sin(roll)). One step a line.
    """
    attitude = vehicle_attitude(pose, mounting)
    turn, front, left = (
        round(a / _WORDING_STEP_DEG) * _WORDING_STEP_DEG + 0.0
        for a in (attitude.turn_left_deg, attitude.front_up_deg, attitude.left_up_deg)
    )
    size = size or VehicleSize()
    tilts = []
    if front != 0.0:
        amount = _rise_words(size.front_rise_m(front), front)
        tilts.append(f"raise the {'front' if front > 0 else 'rear'} wheels {amount}")
    if left != 0.0:
        amount = _rise_words(size.side_rise_m(left), left)
        tilts.append(f"raise the {'left' if left > 0 else 'right'} side {amount}")
    if turn == 0.0:
        if not tilts:
            return _steps(["park the vehicle level at the start heading", MARK_THE_TYRES])
        steps = ["put the vehicle at the start heading on the same tyre marks"]
    elif abs(turn) == 180.0:
        steps = ["turn the vehicle round on the spot (180° from the start heading)"]
        steps.append(BACK_TO_THE_MARKS)
    else:
        side = "left" if turn > 0 else "right"
        steps = [f"turn the vehicle on the spot to {abs(turn):g}° {side} of the start heading"]
        steps.append(BACK_TO_THE_MARKS)
    return _steps(steps + (tilts or ["park it level"]))


def _rise_words(rise_m: float | None, angle_deg: float) -> str:
    """``0.61 m (10°)`` with a known length, else ``10°``."""
    if rise_m is None:
        return f"{abs(angle_deg):g}°"
    return f"{rise_m:.2f} m ({abs(angle_deg):g}°)"


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
