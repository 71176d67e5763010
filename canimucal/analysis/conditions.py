"""A recording's conditions: gravity, latitude and heading from its header (docs/design.md §2)."""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from canimucal.io.recording import Recording
from canimucal.model.gravity import normal_gravity
from canimucal.model.sensor import DEFAULT_ACCEL_LSB, DEFAULT_GYRO_LSB, STANDARD_GRAVITY

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class RecordingConditions:
    """g (m/s²) and where it came from, latitude/heading (degrees or None), nominal LSBs."""

    g: float
    g_source: str
    latitude_deg: float | None
    height_m: float | None
    heading_deg: float | None
    accel_lsb: float
    gyro_lsb: float

    @property
    def latitude_rad(self) -> float | None:
        """Latitude in radians, or None."""
        return None if self.latitude_deg is None else float(np.deg2rad(self.latitude_deg))

    @property
    def heading_rad(self) -> float:
        """Heading in radians (0 when unknown)."""
        return float(np.deg2rad(self.heading_deg or 0.0))


def _number(rec: Recording, key: str) -> float | None:
    value = rec.header.get(key)
    return float(value) if isinstance(value, int | float) and not isinstance(value, bool) else None


def recording_conditions(rec: Recording, g_override: float | None = None) -> RecordingConditions:
    """Read the conditions of a recording.

    g: the flag, else the header's ``g``, else WGS-84 normal gravity from latitude and
    height, else 9.80665 with a warning (docs/design.md §2).
    """
    latitude = _number(rec, "latitude_deg")
    height = _number(rec, "height_m")
    if g_override is not None:
        g, source = g_override, "given"
    elif (header_g := _number(rec, "g")) is not None:
        g, source = header_g, "recording header"
    elif latitude is not None:
        g = normal_gravity(float(np.deg2rad(latitude)), height or 0.0)
        source = "WGS-84 normal gravity from latitude and height"
    else:
        g, source = STANDARD_GRAVITY, "standard gravity (no g or latitude given)"
        log.warning("no g or latitude in the recording: using standard gravity 9.80665 m/s²")
    return RecordingConditions(
        g=g,
        g_source=source,
        latitude_deg=latitude,
        height_m=height,
        heading_deg=_number(rec, "heading_deg"),
        accel_lsb=_number(rec, "accel_lsb") or DEFAULT_ACCEL_LSB,
        gyro_lsb=_number(rec, "gyro_lsb") or DEFAULT_GYRO_LSB,
    )
