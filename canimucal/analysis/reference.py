"""Published calibrations of known public data sets, to compare `analyze` against.

Keyed by the SHA-256 of the input file. The facts are those published with the data set
(the factory calibration of the Xsens MTi recorded in imu_tk's test data, published beside a
MATLAB port of imu_tk, and the local gravity used with it); docs/real-data.md uses them.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from canimucal.io.calibration import sha256_of


@dataclass(frozen=True)
class Reference:
    """A published calibration: offsets (counts) and diagonal scales (counts per SI unit)."""

    name: str
    g: float
    accel_offsets: tuple[float, float, float]
    accel_scales: tuple[float, float, float]
    gyro_offsets: tuple[float, float, float]
    gyro_scales: tuple[float, float, float]


XSENS_IMUTK = Reference(
    name="imu_tk Xsens MTi test data, factory calibration (data README)",
    g=9.81744,
    accel_offsets=(33123.0, 33276.0, 32360.0),
    accel_scales=(415.0, 413.0, 415.0),
    gyro_offsets=(32768.0, 32466.0, 32485.0),
    gyro_scales=(4778.0, 4758.0, 4766.0),
)

_BY_SHA256 = {
    "335a234736ff4dd8741118283d5d4cd389ac54b04d00e6cd8d48ca3e532b7510": XSENS_IMUTK,
}


def reference_for(path: str | Path) -> Reference | None:
    """Return the published calibration of the data set in ``path``, if it is a known one."""
    try:
        return _BY_SHA256.get(sha256_of(path))
    except OSError:
        return None
