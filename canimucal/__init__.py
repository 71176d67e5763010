"""canimucal: field calibration of a CANopen IMU from small rotations."""

__version__ = "0.1.0"
