"""model/chi2_tail.py against scipy.special.chdtrc over both tails and many dof."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.special import chdtrc

from canimucal.model.chi2_tail import chi2_sf


@pytest.mark.parametrize(
    ("dofs", "tolerance"),
    [((0.5, 1, 2, 3, 5, 6, 10, 13, 21, 28), 1e-13), ((100, 333, 1000), 1e-12), ((1e4, 1e5), 1e-9)],
)
def test_the_tail_is_scipys(dofs: tuple[float, ...], tolerance: float) -> None:
    for nu in dofs:
        xs = np.concatenate([np.geomspace(1e-6, 1e5, 300), nu * np.linspace(0.01, 20.0, 300)])
        for x in xs:
            ref = float(chdtrc(nu, x))
            if ref < 1e-300:
                continue
            assert chi2_sf(nu, float(x)) == pytest.approx(ref, rel=tolerance, abs=0.0), (nu, x)


def test_the_edges() -> None:
    assert chi2_sf(3, 0.0) == 1.0
    assert chi2_sf(3, -1.0) == 1.0
    assert chi2_sf(3, math.inf) == 0.0
    assert math.isnan(chi2_sf(0, 1.0))
    assert math.isnan(chi2_sf(3, math.nan))
    assert chi2_sf(2, 4.0) == pytest.approx(math.exp(-2.0), rel=1e-15)  # ν = 2: e^(−x/2)
