"""A vehicle's wheelbase and track: its tilts worded as heights (docs/design.md §2).

A ladder under one axle raises that axle by ``wheelbase · sin(angle)`` for a pitch of
``angle`` (the other axle stays on the floor); one under one side raises it by
``track · sin(angle)`` for a roll. The instructions then say "raise the front wheels
0.61 m (10°)" for a 3.5 m wheelbase, the height an operator can measure with a tape.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from canimucal.errors import InputError

MAX_SIZE_M = 50.0
"""Largest wheelbase or track taken (a typing error in centimetres is refused)."""


@dataclass(frozen=True)
class VehicleSize:
    """Wheelbase (front to rear axle) and track (left to right wheels), metres; None: unknown."""

    wheelbase_m: float | None = None
    track_m: float | None = None

    def __post_init__(self) -> None:
        """Refuse a size that is not a length of a vehicle."""
        for name, value in (("wheelbase_m", self.wheelbase_m), ("track_m", self.track_m)):
            if value is None:
                continue
            if isinstance(value, bool) or not (np.isfinite(value) and 0.0 < value <= MAX_SIZE_M):
                raise InputError(
                    f"{name} must be a length in metres, > 0 and ≤ {MAX_SIZE_M:g}, got {value!r}",
                    options=(name,),
                )

    @property
    def known(self) -> bool:
        """Whether either length is given."""
        return self.wheelbase_m is not None or self.track_m is not None

    def front_rise_m(self, pitch_deg: float) -> float | None:
        """Return an axle's rise for a pitch of ``pitch_deg``: wheelbase · sin (None: unknown)."""
        return _rise(self.wheelbase_m, pitch_deg)

    def side_rise_m(self, roll_deg: float) -> float | None:
        """Return a side's rise for a roll of ``roll_deg``: track · sin (None: unknown)."""
        return _rise(self.track_m, roll_deg)

    def text(self) -> str:
        """``wheelbase 3.5 m, track 1.8 m`` (what is known)."""
        parts = []
        if self.wheelbase_m is not None:
            parts.append(f"wheelbase {self.wheelbase_m:g} m")
        if self.track_m is not None:
            parts.append(f"track {self.track_m:g} m")
        return ", ".join(parts) or "size not given"


def _rise(length_m: float | None, angle_deg: float) -> float | None:
    if length_m is None:
        return None
    return float(length_m * np.sin(np.deg2rad(abs(angle_deg))))
