"""A simulated node's non-volatile memory holding an active calibration with a chosen M."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from canimucal.device import od
from canimucal.device.client import CalibrationReadout
from canimucal.model.sensor import DEFAULT_ACCEL_LSB
from canimucal.model.vocabulary.plans import PLANS
from canimucal.simnode.store import STATE_SCHEMA


def calibration_block(m: np.ndarray) -> od.CalibrationBlock:
    """The factory block with the accel correction M (m/s² per count) replaced."""
    base = od.factory_block(DEFAULT_ACCEL_LSB, 1e-3)
    return od.CalibrationBlock(
        accel_bias=base.accel_bias,
        accel_correction=m,
        gyro_bias=base.gyro_bias,
        gyro_correction=base.gyro_correction,
        gyro_g=base.gyro_g,
        base_tilt_rad=base.base_tilt_rad,
        plan_code=PLANS["recommended"].device_code,
    )


def readout(m: np.ndarray, valid: int = 1) -> CalibrationReadout:
    """The block as a client reads it: valid flag ``valid``, its CRC stored and matching."""
    objects = calibration_block(m).to_objects()
    crc = od.block_crc(objects)
    objects[(od.CAL_INFO, od.CAL_VALID_SUB)] = valid
    objects[(od.CAL_INFO, od.CAL_CRC_SUB)] = crc
    return CalibrationReadout(calibration_block(m), valid, crc, True, objects)


def state_file(path: Path, m: np.ndarray) -> Path:
    """Write the ``--state`` file of a node whose active calibration has the correction M."""
    objects = {od.format_key(*key): raw.hex() for key, raw in readout(m).raw.items()}
    path.write_text(json.dumps({"schema": STATE_SCHEMA, "objects": objects}))
    return path
