"""Fixtures of the procedure tests (the helpers live in ``procedure_bench.py``)."""

from __future__ import annotations

import numpy as np
import pytest

from canimucal.sim.truth import Truth


@pytest.fixture
def diag_truth() -> Truth:
    """A random unit without cross-axis terms (the five plan's model), base tilt ±1°."""
    return Truth.random(np.random.default_rng(20261121), cross_axis_max=0.0)
