"""`solve`'s σ mean what they say, with the pose scatter estimated (issue 21 item 6).

No tolerance in the header: the scatter comes from the data (docs/design.md §10). The rms of
(estimate − truth)/σ of every accelerometer parameter and the tilt must lie within
0.8–1.25, and each parameter's Σz²/n within its χ² band (docs/design.md §8). Position means
come from the sensor model (:func:`tests.support.departures.offline_averages`).

- the issue's case, a clean unit on the five-position plan at 0.1° poses, seeds 0–19: rms
  0.93 (before: 1.62 with τ̂ plugged in, |z| up to 6.1; the issue's 2.07 counted the gyro's
  dof too);
- a clean unit, a base tilted 1–3° and a cross-axis entry of 1–2 % of scale (where
  `solve`'s model holds it: not the five plan's diagonal K), seeds 0–19 dealt round the
  five and recommended plans at exact and 0.1° poses (:func:`~tests.support.departures.
  rotation`). ``benchmarks/departures.py`` runs every case on 40 seeds: 0.88–1.11.
"""

from __future__ import annotations

import pytest

from tests.support import departures as dep

SEEDS = tuple(range(20))
CLEAN = dep.Departure("clean")
COMPARISONS = 4


def test_the_five_plan_at_a_tenth_of_a_degree() -> None:
    spread = dep.spread(dep.Case(CLEAN, "five", 0.1, SEEDS))
    assert not spread.within(COMPARISONS), (spread.rms, spread.within(COMPARISONS))


@pytest.mark.parametrize(
    "departure", [CLEAN, dep.TILTED_BASE, dep.CROSS_AXIS], ids=lambda d: d.name
)
def test_plans_and_poses_in_turn(departure: dep.Departure) -> None:
    spread = dep.pooled_spread(dep.rotation(departure, SEEDS))
    assert not spread.within(COMPARISONS), (spread.rms, spread.within(COMPARISONS))
