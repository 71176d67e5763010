"""Effects of realistic size are named alone, or nothing is named (issue 21).

A base tilted 1–3° (about alpha0, beta0 or both), a cross-axis entry of 1–2 % of its row's
scale, a quadratic term at 10–20σ of its own estimate: `analyze`'s loop on seeds 0–7 dealt
round the five and recommended plans at exact and 0.1° poses (the scatter estimated). The
suite's time allows eight seeds a departure (about 20 s each on an idle machine); seeds 0–19
passed the same checks when this was written (``MAX_WRONG`` 2 there), and
``benchmarks/departures.py`` runs every case on 40.

- A cause other than the departure's own is a wrong cause. Designed rate: the family-wise
  1 %; more than :data:`MAX_WRONG` of 8 has binomial probability 0.003 at that rate.
- On the recommended plan, which separates every pair of these effects, the departure is
  named alone on every seed but :data:`MAX_WRONG`; the five plan cannot tell bias z from
  beta0 (correlation −0.9996) nor most K entries apart, so there its pairs may stay
  ambiguous (nothing named).

Before the angle errors' covariance followed the exact fit (:mod:`canimucal.analysis.
exact_fit` eq. 3), a base tilt on the recommended plan at 0.1° poses brought a phantom
cross_axis on 7 of 20 seeds (exact poses: 0 of 20). ``benchmarks/departures.py`` runs every
case on 40 seeds.
"""

from __future__ import annotations

import pytest

from tests.support import departures as dep

SEEDS = tuple(range(8))
MAX_WRONG = 1
"""P(Bin(8, 0.01) ≥ 2) = 0.0027."""


@pytest.mark.parametrize(
    "departure", [dep.TILTED_BASE, dep.CROSS_AXIS, dep.QUADRATIC], ids=lambda d: d.name
)
def test_a_large_effect_is_named_alone_or_nothing_is(departure: dep.Departure) -> None:
    wrong, missed = {}, {}
    for case, seed in dep.rotation_all(departure, SEEDS):
        causes, ambiguous = dep.named(case, seed)
        if causes - departure.causes:
            wrong[(case.label, seed)] = sorted(causes)
        elif case.plan == "recommended" and causes != departure.causes:
            missed[(case.label, seed)] = (sorted(causes), ambiguous)
    assert len(wrong) <= MAX_WRONG, wrong
    assert len(missed) <= MAX_WRONG, missed
