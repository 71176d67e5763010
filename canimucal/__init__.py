"""canimucal: field calibration of a CANopen IMU from small rotations."""

from canimucal.version import __version__

__all__ = ["__version__"]
