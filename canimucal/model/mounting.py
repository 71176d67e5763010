"""How the unit sits in a vehicle, and a pose read as the vehicle attitude (docs/design.md §2, §9).

A :class:`MountingMap` names the vehicle direction (forward, back, left, right, up, down) of
each of the unit's axes x, y, z: a signed permutation ``M`` (vehicle ← unit, its columns the
unit's axes in the vehicle frame forward/left/up), which must be a proper rotation
(``det M = +1``); a mirror image is refused. Written ``x=forward,y=down,z=left``.

A pose's DCM ``C`` (unit ← L) makes the vehicle's attitude ``V = M C`` (vehicle ← L). It is
read against the *start frame* S: level (up = −y of L, since L's y points down), heading
that of the vehicle at the plan's reference pose (``C = I``). With ``D = V Sᵀ`` (vehicle ←
S; row i is vehicle axis i in S, columns forward/left/up), the vehicle's turn, pitch and roll
in that order (intrinsic yaw about up, then about the new left axis, then about the new
forward axis):

    turn_left = atan2(D[0,1], D[0,0])   (+: to the left, anticlockwise seen from above)
    front_up  = asin(D[0,2])            (+: the front raised)
    left_up   = atan2(D[1,2], D[2,2])   (+: the left side raised)

(with the front straight up or down, the roll is taken as 0 and the turn read from D's row 1).

:func:`attitude_dcm` composes them back, so a wording made from the attitude can be
checked to give the pose's rotation again.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from canimucal.errors import InputError
from canimucal.model.frames import position_dcm
from canimucal.model.positions import Pose

Array = NDArray[np.float64]

_DIRECTIONS = {
    "forward": (0, 1.0),
    "back": (0, -1.0),
    "left": (1, 1.0),
    "right": (1, -1.0),
    "up": (2, 1.0),
    "down": (2, -1.0),
}
_ALIASES = {"fwd": "forward", "front": "forward", "rear": "back", "backward": "back"}
_UP_LEVEL = np.array([0.0, -1.0, 0.0])
"""Up in L (L's y points down)."""


@dataclass(frozen=True)
class MountingMap:
    """The vehicle direction of the unit's x, y and z axes (``forward``, ``down``, ...)."""

    x: str
    y: str
    z: str

    def __post_init__(self) -> None:
        """Refuse unknown words, a vehicle axis used twice and a mirror image."""
        for axis, word in zip("xyz", (self.x, self.y, self.z), strict=True):
            if word not in _DIRECTIONS:
                raise InputError(
                    f"mounting map: unit {axis} = {word!r} is not one of {', '.join(_DIRECTIONS)}"
                )
        used = [_DIRECTIONS[w][0] for w in (self.x, self.y, self.z)]
        if sorted(used) != [0, 1, 2]:
            raise InputError(
                f"mounting map {self.text()}: each of forward/back, left/right, up/down must "
                "be named exactly once"
            )
        if np.linalg.det(self.matrix) < 0:
            raise InputError(
                f"mounting map {self.text()} is a mirror image (det −1), not a rotation: "
                "reverse the sign of one axis"
            )

    @classmethod
    def parse(cls, text: str) -> MountingMap:
        """Parse ``x=forward,y=down,z=left`` (any order; spaces and case ignored).

        Aliases: ``fwd``/``front`` for forward, ``rear``/``backward`` for back.
        """
        words: dict[str, str] = {}
        for item in text.replace(" ", "").lower().split(","):
            axis, sep, word = item.partition("=")
            if not sep or axis not in ("x", "y", "z") or not word:
                raise InputError(
                    f"mounting map {text!r}: write each unit axis as AXIS=DIRECTION, e.g. "
                    "x=forward,y=down,z=left"
                )
            if axis in words:
                raise InputError(f"mounting map {text!r}: unit {axis} is given twice")
            words[axis] = _ALIASES.get(word, word)
        missing = [a for a in "xyz" if a not in words]
        if missing:
            raise InputError(f"mounting map {text!r}: unit {', '.join(missing)} not given")
        return cls(words["x"], words["y"], words["z"])

    def text(self) -> str:
        """Return the map in the form :meth:`parse` reads."""
        return f"x={self.x},y={self.y},z={self.z}"

    @property
    def matrix(self) -> Array:
        """``M`` (vehicle ← unit): column j is unit axis j in forward/left/up."""
        m = np.zeros((3, 3))
        for j, word in enumerate((self.x, self.y, self.z)):
            row, sign = _DIRECTIONS[word]
            m[row, j] = sign
        return m


DEFAULT_MOUNTING = MountingMap("forward", "down", "left")
"""The unit on its mounting face (y down, as at the plans' level pose), +x to the front."""


@dataclass(frozen=True)
class VehicleAttitude:
    """The vehicle's attitude against the start frame, degrees (the module doc's angles)."""

    turn_left_deg: float
    front_up_deg: float
    left_up_deg: float


def start_frame(mounting: MountingMap) -> Array:
    """``S`` (start ← L): rows forward, left, up of the level vehicle at the reference pose."""
    m = mounting.matrix  # vehicle ← unit = vehicle ← L at C = I
    forward, up = m[0], m[2]
    horizontal = forward - (forward @ _UP_LEVEL) * _UP_LEVEL
    if np.linalg.norm(horizontal) < 1e-6:  # front straight up or down: heading of the roof
        horizontal = -np.sign(forward @ _UP_LEVEL) * up
        horizontal = horizontal - (horizontal @ _UP_LEVEL) * _UP_LEVEL
    f = horizontal / np.linalg.norm(horizontal)
    return np.array([f, np.cross(_UP_LEVEL, f), _UP_LEVEL])


def vehicle_attitude(pose: Pose, mounting: MountingMap) -> VehicleAttitude:
    """Read ``pose`` as the vehicle's turn, front and side tilt (module doc)."""
    c = position_dcm(pose.alpha, pose.beta, pose.psi)
    d = mounting.matrix @ c @ start_frame(mounting).T
    pitch = np.arcsin(np.clip(d[0, 2], -1.0, 1.0))
    if np.hypot(d[0, 0], d[0, 1]) < 1e-9:  # front straight up or down: no roll, turn from left
        turn, roll = np.arctan2(-d[1, 0], d[1, 1]), 0.0
    else:
        turn, roll = np.arctan2(d[0, 1], d[0, 0]), np.arctan2(d[1, 2], d[2, 2])
    return VehicleAttitude(*(float(np.rad2deg(a)) + 0.0 for a in (turn, pitch, roll)))


def attitude_dcm(attitude: VehicleAttitude, mounting: MountingMap) -> Array:
    """Return the unit's DCM (unit ← L) of a vehicle attitude (inverts :func:`vehicle_attitude`)."""
    turn, pitch, roll = np.deg2rad(
        [attitude.turn_left_deg, attitude.front_up_deg, attitude.left_up_deg]
    )
    # Frame rotations (vehicle axes in S): about up, then the new left (front up), then the
    # new forward (left side up).
    cz, sz = np.cos(turn), np.sin(turn)
    cy, sy = np.cos(pitch), np.sin(pitch)
    cx, sx = np.cos(roll), np.sin(roll)
    about_up = np.array([[cz, sz, 0.0], [-sz, cz, 0.0], [0.0, 0.0, 1.0]])
    about_left = np.array([[cy, 0.0, sy], [0.0, 1.0, 0.0], [-sy, 0.0, cy]])
    about_forward = np.array([[1.0, 0.0, 0.0], [0.0, cx, sx], [0.0, -sx, cx]])
    d = about_forward @ about_left @ about_up
    return np.asarray(mounting.matrix.T @ d @ start_frame(mounting))
