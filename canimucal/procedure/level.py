"""The level check: |f| − g and the tilt at the level pose, nominal and with new parameters.

The new accelerometer parameters are applied in software as the firmware would
(docs/design.md §4): ``a = M (U − b)`` with ``M = K⁻¹`` and nominal values where the record holds
``null`` (:meth:`canimucal.io.calibration.AccelBlock.correct`). The tilt is read from
the direction of ``a`` with :func:`canimucal.model.frames.gravity_direction_angles`.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from canimucal.analysis.calibrate import SiteConditions
from canimucal.io.calibration import Calibration
from canimucal.model.frames import gravity_direction_angles
from canimucal.model.positions import PositionAverage
from canimucal.procedure.events import LevelChecked

Array = NDArray[np.float64]


def _norm_and_tilt(f: Array, g: float) -> tuple[float, tuple[float, float]]:
    alpha, beta = gravity_direction_angles(f)
    return float(np.linalg.norm(f) - g), (float(np.rad2deg(alpha)), float(np.rad2deg(beta)))


def corrected_accel(record: Calibration, mean_counts: Array, site: SiteConditions) -> Array:
    """Return ``a = M (U − b)`` (m/s²) with the record's parameters."""
    return record.accel.correct(mean_counts, site.accel_lsb)


def level_check(
    node_id: int,
    stage: str,
    average: PositionAverage,
    record: Calibration,
    site: SiteConditions,
) -> LevelChecked:
    """Nominal and calibrated |f| − g and tilt of a level position's mean."""
    nominal = _norm_and_tilt(site.accel_lsb * average.mean_accel, site.g)
    calibrated = _norm_and_tilt(corrected_accel(record, average.mean_accel, site), site.g)
    return LevelChecked(node_id, stage, nominal[0], nominal[1], calibrated[0], calibrated[1])
