"""A plan whose moves turn about every body axis (gyro-from-moves tests)."""

from __future__ import annotations

import numpy as np

from canimucal.model.positions import Plan, PlannedPosition

TURN_POSES_DEG = [
    (0, 0, 0),
    (90, 0, 0),
    (0, 0, 0),
    (0, 90, 0),
    (0, 0, 0),
    (0, 0, 90),
    (0, 0, 0),
    (-90, 0, 0),
    (0, -90, 0),
]
"""Level, then a 90° turn about each body axis and back: every column of S is seen."""


def turns_plan(seconds: float = 5.0) -> Plan:
    """The poses of :data:`TURN_POSES_DEG`, each held ``seconds``, tolerance 0.1°."""
    positions = tuple(
        PlannedPosition(*np.deg2rad(p), np.deg2rad(0.1), seconds) for p in TURN_POSES_DEG
    )
    return Plan("custom", positions)
