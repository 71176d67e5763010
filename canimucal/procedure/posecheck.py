"""The pose check before averaging, and a target pose in words (docs/design.md §2 directions).

The measured specific force ``f = lsb · U`` (nominal K) is compared with the target's
``R_m C(alpha, beta, psi) T0 f_L + b``: ``T0`` the floor slope (a tilt fixed in the level
frame, docs/design.md §2, so it turns with the pose), ``R_m`` the unit's mounting trim (a
small rotation fixed in the vehicle frame, docs/method.md §3 eq. T1) and ``b`` a bias in the
unit's frame, all fitted by :class:`FloorFit` to the positions accepted so far and the one
checked. The angle between the two directions must be within the tolerance, so a tilt of
the wrong sign (twice the tilt off) or the wrong size is refused. What the accepted
positions cannot tell apart (slope, trim and bias after the first position) is settled by
the one checked, within bounds no floor or mounting exceeds.
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


SLOPE_BOUND_DEG = 5.0
"""Largest floor slope about each axis the pose check will assume (a yard, a garage)."""
TRIM_BOUND_DEG = 3.0
"""Largest mounting trim about each axis it will assume (a unit bolted in by eye)."""
BIAS_BOUND_G = 0.1
"""Largest accelerometer bias on each axis it will assume, in g (a MEMS zero-g offset)."""
SEEN_WEIGHT = 10.0
"""How much more each accepted position weighs in the check's fit than the one checked."""
_ITERATIONS = 3
"""Gauss–Newton steps of the check's fit (exact rotations, linear steps)."""


@dataclass
class FloorFit:
    """What the accepted positions showed beyond their prediction: slope, trim and bias.

    The model of a nominal specific force at pose ``C``: ``R_m C T0(alpha0, beta0) f_L + b``;
    ``T0`` is the rigid base tilt of docs/design.md §2 (the floor's slope, fixed in the level
    frame: it turns with the vehicle or the unit), ``R_m = exp(−[m]×)`` the mounting trim (a
    rotation fixed in the vehicle frame; docs/method.md §3 eq. T1), ``b`` a bias in the unit
    frame (m/s²); measured vectors are scaled to ``|f| = g`` first (a scale error of the
    nominal K does not tilt anything). :meth:`check` fits the eight unknowns to the accepted
    positions and the one checked together, the accepted ones weighing
    :data:`SEEN_WEIGHT` times more, each unknown within what a floor, a mounting and a bias
    can be (:data:`SLOPE_BOUND_DEG`, :data:`TRIM_BOUND_DEG`, :data:`BIAS_BOUND_G`): what the
    accepted positions leave open (after a level first position: whether its offset is
    slope, trim or bias; at any level pose a trim's roll and pitch look like a bias) is
    settled by the position checked, within those bounds, and what the fit cannot explain is
    the pose error. A tilt of the wrong sign or size needs a slope or trim far beyond the
    bounds, so it is still refused.
    """

    g: float
    seen: list[tuple[Pose, Array]] = field(default_factory=list)
    _alone: FloorReading | None = field(default=None, repr=False)

    def add(self, pose: Pose, f_nominal: Array) -> None:
        """Take an accepted position's nominal specific force (m/s²) at its target ``pose``."""
        self.seen.append((pose, np.asarray(f_nominal, dtype=float)))
        self._alone = None

    @property
    def empty(self) -> bool:
        """Whether no position has been accepted yet."""
        return not self.seen

    def fit(self, extra: tuple[Pose, Array] | None = None) -> FloorReading:
        """Fit slope, trim and bias to the accepted positions (and ``extra``, weighing 1)."""
        points = [(pose, f, SEEN_WEIGHT) for pose, f in self.seen]
        if extra is not None:
            points.append((extra[0], np.asarray(extra[1], dtype=float), 1.0))
        from scipy.optimize import lsq_linear  # lazy (issue 23)

        q, bound = np.zeros(8), _bounds()
        for _ in range(_ITERATIONS):
            rows, residuals = [], []
            for pose, f, weight in points:
                jac, res = self._linearised(pose, f, q)
                rows.append(np.sqrt(weight) * jac)
                residuals.append(np.sqrt(weight) * res)
            step = lsq_linear(
                np.vstack(rows), np.concatenate(residuals), bounds=(-bound - q, bound - q)
            )
            q = np.clip(q + step.x, -bound, bound)
        return FloorReading(float(q[0]), float(q[1]), q[2:5].copy(), self.g * q[5:])

    def _linearised(self, pose: Pose, f: Array, q: Array) -> tuple[Array, Array]:
        """d(prediction)/dq at ``q`` and the residual (scaled measurement − prediction), in g."""
        norm = float(np.linalg.norm(f))
        scaled = f / norm if norm > 0 else f
        c = position_dcm(pose.alpha, pose.beta, pose.psi)
        rotation = _frame_rotation(q[2:5])
        slope = position_dcm(0.0, 0.0, 0.0, q[0], q[1])
        unit_g = specific_force_level(1.0)
        predicted = rotation @ c @ slope @ unit_g
        d_slope = np.column_stack(
            [
                (position_dcm(0.0, 0.0, 0.0, q[0] + h[0], q[1] + h[1]) - slope) @ unit_g / 1e-7
                for h in (np.array([1e-7, 0.0]), np.array([0.0, 1e-7]))
            ]
        )
        jac = np.hstack([rotation @ c @ d_slope, _cross(predicted), np.eye(3)])
        return jac, scaled - (predicted + q[5:])

    def check(self, pose: Pose, f_nominal: Array, tolerance_deg: float) -> PoseCheck:
        """Check ``f_nominal`` (m/s²) against ``pose`` with the fit that explains it best.

        It passes when the fit of the accepted positions with this one leaves it within
        ``tolerance_deg``. Otherwise (and for a live readout, ``tolerance_deg`` 0) the
        measurement is shown as the accepted positions alone predict it, so the message
        gives the whole error, not what the bounds left of it. Before any position was
        accepted: the plain :func:`check_pose`.
        """
        f = np.asarray(f_nominal, dtype=float)
        if not self.seen:
            return check_pose(pose, f, self.g, tolerance_deg)
        if self._alone is None:
            self._alone = self.fit()
        alone = check_pose(pose, self._alone.on_level_floor(pose, f), self.g, tolerance_deg)
        if tolerance_deg <= 0.0:  # a live readout: what the accepted positions predict
            return alone
        joint = check_pose(pose, self.fit((pose, f)).on_level_floor(pose, f), self.g, tolerance_deg)
        return joint if joint.passed else alone


@dataclass(frozen=True)
class FloorReading:
    """One fit of :class:`FloorFit`: slope (rad), trim (rotation vector, rad) and bias (m/s²)."""

    alpha0: float
    beta0: float
    trim: Array
    bias: Array

    def on_level_floor(self, pose: Pose, f: Array) -> Array:
        """Refer the measurement to a level floor and an exact mounting.

        ``m = C T0ᵀ Cᵀ R_mᵀ (f − b)``: what the unit would have shown at ``pose`` (m/s²).
        """
        c = position_dcm(pose.alpha, pose.beta, pose.psi)
        slope = position_dcm(0.0, 0.0, 0.0, self.alpha0, self.beta0)
        untrimmed = _frame_rotation(self.trim).T @ (np.asarray(f, dtype=float) - self.bias)
        return np.asarray(c @ slope.T @ c.T @ untrimmed)


def _bounds() -> Array:
    slope, trim = np.deg2rad(SLOPE_BOUND_DEG), np.deg2rad(TRIM_BOUND_DEG)
    return np.array([slope, slope, trim, trim, trim, BIAS_BOUND_G, BIAS_BOUND_G, BIAS_BOUND_G])


def _cross(v: Array) -> Array:
    """``[v]×``: the matrix of ``v × ·``; ``R_m v ≈ v + [v]× m`` for a small frame rotation."""
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def _frame_rotation(m: Array) -> Array:
    """``R_m = exp(−[m]×)``: the frame rotation by the rotation vector ``m`` (Rodrigues)."""
    angle = float(np.linalg.norm(m))
    if angle < 1e-15:
        return np.eye(3)
    k = _cross(np.asarray(m, dtype=float) / angle)
    return np.asarray(np.eye(3) - np.sin(angle) * k + (1.0 - np.cos(angle)) * (k @ k))


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
