"""A twelve-position plan: the recommended eight poses plus four single 30° tilts."""

from __future__ import annotations

import numpy as np

from canimucal.model.positions import Plan, PlannedPosition

TWELVE_DEG = (
    [(0, 0, 0), (0, 0, 90), (0, 0, 180), (0, 0, 270)]
    + [(45, 45, 0), (45, 45, 90), (45, 45, 180), (45, 45, 270)]
    + [(30, 0, 0), (30, 0, 180), (0, 30, 90), (0, 30, 270)]
)


def twelve(tolerance_deg: float) -> Plan:
    """The twelve-position plan with every angle set to ``tolerance_deg`` (1σ)."""
    tol = float(np.deg2rad(tolerance_deg))
    return Plan(
        "twelve",
        tuple(
            PlannedPosition(*(float(x) for x in np.deg2rad(d)), tolerance=tol, seconds=30.0)
            for d in TWELVE_DEG
        ),
    )
