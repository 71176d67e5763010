"""The accelerometer K a device holds now: the mean of a plan's prior on K, read live.

Which object holds it (docs/design.md §4): the firmware corrects with ``a = M (U − b)`` where
M = K⁻¹ is 0x2101:01–09 (REAL32, m/s² per count, row-major), but only while 0x2121:05
(valid) is 1 and 0x2121:06 matches the CRC of the block. Then the device's K is M⁻¹ (the
factory's or the last calibration's). Otherwise the firmware applies the nominal LSB of
0x2010:01, and the device's K is ``I / LSB``. The object dictionary holds no σ of K: the
σ of the prior comes from the plan's documented default or a flag, never from the device.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from canimucal.device import od
from canimucal.device.client import CalibrationReadout
from canimucal.errors import DeviceError

SINGULAR_CONDITION = 1e12
"""A correction M with a larger condition number cannot be inverted to a K."""


@dataclass(frozen=True)
class DeviceK:
    """The K (counts per m/s²) a node applies now, and where it was read."""

    k: NDArray[np.float64]
    source: str
    calibrated: bool
    """True: M⁻¹ of an active calibration block; False: the nominal LSB."""


def device_k(readout: CalibrationReadout, accel_lsb: float, node_id: int) -> DeviceK:
    """Return the K node ``node_id`` applies, from its calibration block and nominal LSB.

    DeviceError (one line) when the active M is non-finite or singular, or the nominal LSB
    is not a finite non-zero number: such a device cannot give a prior on K.
    """
    where = f"node {node_id} (0x{node_id:02X})"
    if readout.valid == 1 and readout.crc_ok:
        m = np.asarray(readout.block.accel_correction, dtype=float).reshape(3, 3)
        name = f"{where}: its accel correction {od.format_key(od.ACCEL_CORRECTION, 1)}..09"
        if not np.all(np.isfinite(m)):
            raise DeviceError(
                f"{name} holds non-finite values; it cannot give the prior on K "
                "(give prior_k, a file, or rewrite the unit's calibration)",
                options=("prior_k",),
            )
        if not np.linalg.cond(m) < SINGULAR_CONDITION:
            raise DeviceError(
                f"{name} is singular (det {np.linalg.det(m):.3g}); it cannot give the prior "
                "on K (give prior_k, a file, or rewrite the unit's calibration)",
                options=("prior_k",),
            )
        k = np.asarray(np.linalg.inv(m), dtype=float)
        return DeviceK(k, f"K = M⁻¹ read from node {node_id}'s 0x2101, active, CRC ok", True)
    lsb = float(accel_lsb)
    if not (np.isfinite(lsb) and lsb != 0.0):
        raise DeviceError(
            f"{where}: its nominal accel LSB 0x2010:01 = {lsb!r} cannot give the prior on K"
        )
    state = "valid = 0" if readout.valid != 1 else "CRC mismatch"
    return DeviceK(
        np.eye(3) / lsb,
        f"K = I/LSB read from node {node_id}'s 0x2010:01, no active calibration: {state}",
        False,
    )
