"""A calibration near nominal for the write tests' unit (node 0x10, serial 4242)."""

from __future__ import annotations

from typing import Any

import numpy as np

NODE_ID = 0x10
SERIAL = 4242
ACCEL_LSB = 9.80665 / 2048.0
GYRO_LSB = float(np.pi / (180.0 * 16.4))


def calibration(scale: float, bias: float) -> dict[str, Any]:
    """A calibration JSON dict near nominal (cross-axis terms, g-sensitivity, tilt)."""
    k = np.diag([scale, -scale, 0.99]) / ACCEL_LSB
    k[0, 1] = 0.01 / ACCEL_LSB
    s = np.eye(3) * 1.02 / GYRO_LSB
    return {
        "schema": "canimucal.calibration/1",
        "plan": "five",
        "device": {"node_id": NODE_ID, "serial": SERIAL},
        "accel": {"bias": [bias, -3.25, 1.5], "K": k.tolist()},
        "gyro": {"bias": [1.0, 2.0, 3.0], "S": s.tolist(), "G": np.eye(3).tolist()},
        "base_tilt_deg": {"alpha0": 0.3, "beta0": -0.2},
    }
