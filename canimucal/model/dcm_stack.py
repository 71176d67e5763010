"""Direction cosine matrices of many positions at once, with their analytic derivatives.

Pure rotation geometry (the product of :func:`canimucal.model.frames.position_dcm`, batched),
kept apart from :mod:`canimucal.model.layout`, whose forward model and Jacobians use it; it
knows nothing of the parameters.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from canimucal.model.frames import TiltModel

Array = NDArray[np.float64]


_ENTRIES = {
    # axis: where the rotation holds cos (row, col), ±sin (row, col, sign) and 1; the
    # derivative follows by d cos = −sin, d sin = cos; frames.a1/a2/ay (eq. 1-2)
    "z": (((0, 0), (1, 1)), ((0, 1, 1), (1, 0, -1)), (2, 2)),
    "x": (((1, 1), (2, 2)), ((1, 2, 1), (2, 1, -1)), (0, 0)),
    "y": (((0, 0), (2, 2)), ((2, 0, 1), (0, 2, -1)), (1, 1)),
}


def _rotations(axis: str, angle: Array) -> tuple[Array, Array]:
    """A1 (``z``), A2 (``x``) or Ay (``y``) of each angle and its derivative, ``(n, 3, 3)``.

    Same matrices as ``frames.a1``/``a2``/``ay`` (eq. 1-2), for a vector of angles; filled
    entry by entry into preallocated stacks (the fits call this thousands of times).
    """
    angle = np.asarray(angle, dtype=float)
    c, s = np.cos(angle), np.sin(angle)
    rot = np.zeros(angle.shape + (3, 3))
    der = np.zeros(angle.shape + (3, 3))
    cos_at, sin_at, one_at = _ENTRIES[axis]
    for i, j in cos_at:
        rot[..., i, j] = c
        der[..., i, j] = -s
    for i, j, sign in sin_at:
        rot[..., i, j] = s if sign > 0 else -s
        der[..., i, j] = c if sign > 0 else -c
    rot[..., one_at[0], one_at[1]] = 1.0
    return rot, der


def _partials(factors: Sequence[Array], derivs: Sequence[Array]) -> tuple[Array, list[Array]]:
    """Multiply stacks of ``factors``; also each product with factor k replaced by its derivative.

    Prefix and suffix products keep the cost linear in the number of factors.
    """
    n = len(factors)
    eye = np.broadcast_to(np.eye(3), factors[0].shape)
    prefix = [eye]
    for f in factors:
        prefix.append(prefix[-1] @ f)
    suffix = [eye] * (n + 1)
    for k in range(n - 1, -1, -1):
        suffix[k] = factors[k] @ suffix[k + 1]
    return prefix[n], [prefix[k] @ derivs[k] @ suffix[k + 1] for k in range(n)]


def dcm_stack(
    angles: Array, alpha0: float, beta0: float, tilt_model: TiltModel
) -> tuple[Array, Array, Array]:
    """DCMs of positions ``(n, 3)`` and their derivatives (the product of ``position_dcm``).

    Returns ``C`` ``(n, 3, 3)``, ``dC/d(alpha, beta, psi)`` ``(n, 3, 3, 3)`` (angle on axis
    1) and ``dC/d(alpha0, beta0)`` ``(n, 2, 3, 3)``.
    rigid: ``C = Ay(psi) A2(beta) A1(alpha) A2(beta0) A1(alpha0)``;
    additive: ``C = Ay(psi) A2(beta + beta0) A1(alpha + alpha0)`` (eq. 15).
    """
    rows = np.atleast_2d(np.asarray(angles, dtype=float))
    alpha, beta, psi = rows[:, 0], rows[:, 1], rows[:, 2]
    tilt = np.ones_like(alpha)
    if tilt_model == "rigid":
        parts = [
            _rotations("y", psi), _rotations("x", beta), _rotations("z", alpha),
            _rotations("x", beta0 * tilt), _rotations("z", alpha0 * tilt),
        ]  # fmt: skip
        which_angles, which_tilt = (2, 1, 0), (4, 3)
    else:
        parts = [
            _rotations("y", psi),
            _rotations("x", beta + beta0),
            _rotations("z", alpha + alpha0),
        ]
        which_angles, which_tilt = (2, 1, 0), (2, 1)
    c, replaced = _partials([r for r, _ in parts], [d for _, d in parts])
    d_angles = np.stack([replaced[k] for k in which_angles], axis=1)
    d_tilt = np.stack([replaced[k] for k in which_tilt], axis=1)
    return c, d_angles, d_tilt


def trim_rotation(trim: Array) -> tuple[Array, Array]:
    """Return the mounting trim ``R_m`` (unit ← vehicle) and ``dR_m/d(alpha_m, beta_m, psi_m)``.

    ``R_m = Ay(psi_m) A2(beta_m) A1(alpha_m)``: the unit's pose in the vehicle in the angle
    convention of a position (docs/design.md §2, docs/method.md §3 "Floor slope and mounting
    trim"); returns ``(3, 3)`` and ``(3, 3, 3)`` (angle on axis 0).
    """
    alpha, beta, psi = (np.atleast_1d(float(t)) for t in np.asarray(trim, dtype=float)[:3])
    parts = [_rotations("y", psi), _rotations("x", beta), _rotations("z", alpha)]
    r, replaced = _partials([m for m, _ in parts], [d for _, d in parts])
    return r[0], np.stack([replaced[2][0], replaced[1][0], replaced[0][0]])


def trimmed_stack(
    angles: Array, alpha0: float, beta0: float, tilt_model: TiltModel, trim: Array
) -> tuple[Array, Array, Array, Array]:
    """:func:`dcm_stack` with the mounting trim on the left: ``C = R_m · C_pose · T0``.

    docs/method.md §3 eq. (T1). Returns ``C`` ``(n, 3, 3)``, ``dC/d(alpha, beta, psi)``
    ``(n, 3, 3, 3)``, ``dC/d(alpha0, beta0)`` ``(n, 2, 3, 3)`` and
    ``dC/d(alpha_m, beta_m, psi_m)`` ``(n, 3, 3, 3)``.
    """
    c, d_angles, d_tilt = dcm_stack(angles, alpha0, beta0, tilt_model)
    r, d_r = trim_rotation(trim)
    d_trim = np.einsum("kij,njl->nkil", d_r, c)
    return r @ c, r @ d_angles, r @ d_tilt, d_trim


def dcm_derivatives(
    angles: Array, alpha0: float, beta0: float, tilt_model: TiltModel
) -> tuple[Array, Array, Array]:
    """One position's DCM, ``dC/d(alpha, beta, psi)`` ``(3, 3, 3)``, ``dC/d(alpha0, beta0)``."""
    c, d_angles, d_tilt = dcm_stack(np.asarray(angles)[None, :3], alpha0, beta0, tilt_model)
    return c[0], d_angles[0], d_tilt[0]
