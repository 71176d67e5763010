"""The verification after a write: poses other than the fit's level one (docs/design.md §3).

Re-reading the level pose the fit started from shows little: the fit matched it already.
After the write the procedure asks for :func:`verification_poses` instead: the plan's most
tilted pose (the scale and cross-axis terms must hold there) and a level pose turned on the
spot (bias against base tilt: the floor's slope turns with the unit, a bias does not), each
worded as the plan's poses are (for a vehicle, through its mounting map). Each is averaged
from the raw counts the device streams and judged by :func:`pose_verified`:

- ``|f| − g``: the norm of ``a = M (U − b)`` (the parameters written, applied as the firmware
  applies them, docs/design.md §4) against the site's g;
- the tilt error: the angle between ``a`` and the direction the pose predicts,
  ``C(alpha, beta, psi) T0(alpha0, beta0) f_L`` with the fitted base tilt ``T0`` (level when
  the plan does not fit one).

Both against ``max_verify_norm_error_mg`` and ``max_verify_tilt_error_deg``
(:class:`~canimucal.analysis.acceptance.AcceptanceLimits`).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from canimucal.analysis.calibrate import SiteConditions
from canimucal.io.calibration import Calibration
from canimucal.model.frames import position_dcm, specific_force_level
from canimucal.model.positions import Plan, PlannedPosition, PositionAverage
from canimucal.procedure.events import PoseVerified

Array = NDArray[np.float64]

VERIFICATION_POSES = 2
"""How many poses the verification asks for (:func:`verification_poses`)."""
TURN_RAD = float(np.deg2rad(90.0))
"""The turn of the level verification pose when the plan turns nothing (a bench plan)."""


def verification_poses(plan: Plan) -> tuple[PlannedPosition, PlannedPosition]:
    """Return the plan's most tilted pose, then a level pose turned on the spot (module doc).

    The tilted one is the first pose of the largest tilt; the turned one the plan's first
    level pose with a turn, else its first pose turned by 90° (its tolerances kept).
    """
    tilts = [float(np.hypot(p.alpha, p.beta)) for p in plan.positions]
    tilted = plan.positions[int(np.argmax(tilts))]
    level = [p for p in plan.positions if p.alpha == 0.0 and p.beta == 0.0]
    turned = next((p for p in level if p.psi % (2 * np.pi) != 0.0), None)
    if turned is None:
        first = level[0] if level else plan.positions[0]
        turned = PlannedPosition(
            0.0,
            0.0,
            TURN_RAD,
            first.tolerance,
            first.seconds,
            psi_tolerance=first.psi_tolerance,
        )
    return tilted, turned


def predicted_direction(position: PlannedPosition, record: Calibration) -> Array:
    """Return the unit vector of ``R_m C(alpha, beta, psi) T0 f_L`` in the unit's axes.

    With the record's base tilt (floor slope) and mounting trim (docs/method.md §3): the
    calibrated reading ``M (U − b)`` is in the unit's axes, which the trim turns from the
    vehicle's.
    """
    tilt, trim = record.base_tilt_deg, record.mounting_trim_deg
    alpha0 = 0.0 if tilt is None or tilt.alpha0 is None else float(np.deg2rad(tilt.alpha0))
    beta0 = 0.0 if tilt is None or tilt.beta0 is None else float(np.deg2rad(tilt.beta0))
    c = position_dcm(
        position.alpha,
        position.beta,
        position.psi,
        alpha0,
        beta0,
        trim=None if trim is None else trim.radians(),
    )
    f = c @ specific_force_level(1.0)
    return f / np.linalg.norm(f)


def _angle_deg(a: Array, b: Array) -> float:
    cross = float(np.linalg.norm(np.cross(a, b)))
    return float(np.rad2deg(np.arctan2(cross, float(np.dot(a, b)))))


def pose_verified(
    node_id: int,
    index: int,
    total: int,
    position: PlannedPosition,
    words: str,
    average: PositionAverage,
    record: Calibration,
    site: SiteConditions,
) -> PoseVerified:
    """|f| − g and the tilt error of a verification pose, nominal and calibrated."""
    want = predicted_direction(position, record)
    nominal = site.accel_lsb * np.asarray(average.mean_accel, dtype=float)
    calibrated = record.accel.correct(average.mean_accel, site.accel_lsb)
    return PoseVerified(
        node_id,
        index,
        total,
        position,
        words,
        float(np.linalg.norm(nominal) - site.g),
        float(np.linalg.norm(calibrated) - site.g),
        _angle_deg(nominal, want),
        _angle_deg(calibrated, want),
    )
