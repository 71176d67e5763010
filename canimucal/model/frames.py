"""Rotations, positions and the reference vectors of the level frame L (docs/design.md §2).

Frame L is right-handed: x East, y Down, z North. A position ``(alpha, beta, psi)`` tilts
the unit by ``alpha`` about body z, then by ``beta`` about the new body x (the paper's
eq. 1-3), then turns it by ``psi`` about its own y axis. The constant base tilt
``(alpha0, beta0)`` is applied first. All angles here are radians.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

EARTH_RATE_RAD_S = 7.292115e-5
"""Earth's rotation rate Ω (WGS-84), rad/s."""

TiltModel = Literal["rigid", "additive"]
Matrix = NDArray[np.float64]
Vector = NDArray[np.float64]


def a1(angle: float) -> Matrix:
    """Rotation of the frame about z by ``angle`` (the paper's A1, eq. 1)."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])


def a2(angle: float) -> Matrix:
    """Rotation of the frame about x by ``angle`` (the paper's A2, eq. 2)."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, s], [0.0, -s, c]])


def ay(angle: float) -> Matrix:
    """Rotation of the frame about y by ``angle``: turning the unit on its mounting face."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, 0.0, -s], [0.0, 1.0, 0.0], [s, 0.0, c]])


def position_dcm(
    alpha: float,
    beta: float,
    psi: float = 0.0,
    alpha0: float = 0.0,
    beta0: float = 0.0,
    tilt_model: TiltModel = "rigid",
    trim: ArrayLike | None = None,
) -> Matrix:
    """Direction cosine matrix body <- L of one position (docs/design.md §2).

    rigid:    ``C = Ay(psi) A2(beta) A1(alpha) A2(beta0) A1(alpha0)``
    additive: ``C = Ay(psi) A2(beta + beta0) A1(alpha + alpha0)`` (the paper's eq. 15)

    ``trim`` ``(alpha_m, beta_m, psi_m)``: the unit's mounting trim in the vehicle, applied
    last (on the left), ``C = R_m · C`` with :func:`trim_dcm` (docs/method.md §3, eq. T1).
    """
    if tilt_model == "rigid":
        c = ay(psi) @ a2(beta) @ a1(alpha) @ a2(beta0) @ a1(alpha0)
    elif tilt_model == "additive":
        c = ay(psi) @ a2(beta + beta0) @ a1(alpha + alpha0)
    else:
        raise ValueError(f"tilt_model must be 'rigid' or 'additive', not {tilt_model!r}")
    return c if trim is None else trim_dcm(trim) @ c


def trim_dcm(trim: ArrayLike) -> Matrix:
    """``R_m = Ay(psi_m) A2(beta_m) A1(alpha_m)`` (unit ← vehicle): the mounting trim.

    The unit's small rotation in the vehicle frame, in the angle convention of a position
    (tilt about z, then about the new x, then turn about y; docs/design.md §2).
    """
    alpha_m, beta_m, psi_m = (float(t) for t in np.asarray(trim, dtype=float)[:3])
    return ay(psi_m) @ a2(beta_m) @ a1(alpha_m)


def specific_force_level(g: float) -> Vector:
    """Specific force sensed at rest in L: ``[0, -g, 0]`` (m/s²)."""
    return np.array([0.0, -float(g), 0.0])


def earth_rate_level(latitude: float, heading: float = 0.0) -> Vector:
    """Earth rate in L for a unit whose body z points ``heading`` clockwise from true North.

    At heading 0: ``[0, -Ω sin φ, Ω cos φ]``. A heading is a turn about the vertical, the same
    rotation as ``psi`` at the level pose, so ``w_L(h) = Ay(h) w_L(0)``.
    """
    w0 = np.array([0.0, -EARTH_RATE_RAD_S * np.sin(latitude), EARTH_RATE_RAD_S * np.cos(latitude)])
    return ay(heading) @ w0


def body_vectors(
    angles: ArrayLike,
    reference: ArrayLike,
    alpha0: float = 0.0,
    beta0: float = 0.0,
    tilt_model: TiltModel = "rigid",
) -> Matrix:
    """``C_i · reference`` for each row ``(alpha, beta, psi)`` of ``angles`` (radians).

    Returns an ``(n, 3)`` array, one body-frame vector per position.
    """
    rows = np.atleast_2d(np.asarray(angles, dtype=float))
    ref = np.asarray(reference, dtype=float)
    out = np.empty((rows.shape[0], 3))
    for i, (alpha, beta, psi) in enumerate(rows[:, :3]):
        out[i] = position_dcm(alpha, beta, psi, alpha0, beta0, tilt_model) @ ref
    return out


def gravity_direction_angles(f_body: ArrayLike) -> tuple[float, float]:
    """Invert ``f = A2(beta) A1(alpha) [0, -|f|, 0]`` for (alpha, beta), assuming psi = 0.

    ``f = |f| [-sin a, -cos a cos b, cos a sin b]``. Used to compare a measured gravity
    direction with a target pose.
    """
    f = np.asarray(f_body, dtype=float)
    norm = float(np.linalg.norm(f))
    if norm == 0.0:
        raise ValueError("zero specific force has no direction")
    alpha = float(np.arcsin(np.clip(-f[0] / norm, -1.0, 1.0)))
    beta = float(np.arctan2(f[2], -f[1]))
    return alpha, beta
