"""Look-alike causes told apart or reported ambiguous, never confidently wrong (issue 14).

With small tilts (≤ 15°) ``f_y`` stays near −g, ``f_y ≈ −g + (f_x² + f_z²)/2g``, so a y→z
cross-axis term K[2][1] looks like a z quadratic. The plan: six tilts of at most 15°, each at
psi 0° and 180°, poses set exactly (a fixture), no tolerance given: the scatter is estimated.
Each seed hides one of the pair at 5σ of its own estimate (every other candidate fitted
beside it; σ from seed 999), signs alternating; seeds 0..39 for each of the pair.

Counted: named exactly, reported ambiguous (nothing named; the rival may be the other of
the pair or ``temperature_bias``, which the warm-up makes alike too), and confidently wrong
(any other cause named). Measured with every candidate fitted exactly (issue 21): K[2][1] 35
named, 5 ambiguous; z quadratic 35 named, 5 ambiguous; none wrong, none missed. (Seeds 0..99,
with the candidates linearised at the base fit, gave 83/17 and 86/14; the 100 seeds cost 10
min of the suite's 30, so 40 run here.) The same sets with 0.1° poses (SMALL_TILTS'
tolerance set to 0.1°, scatter still estimated; not run here) gave, at 100 seeds, 81 named,
6 ambiguous, 13 missed and 90, 9, 1 missed, with 1 wrong (z quadratic, seed 56: both causes
named).
"""

from __future__ import annotations

from functools import cache

import numpy as np
import pytest

from canimucal.analysis.discrepancy import analyse_discrepancy, effect_sigmas
from canimucal.model.positions import Plan, PlannedPosition
from canimucal.sim.truth import Truth
from tests.analysis.test_hidden_effects import clean_truth
from tests.support.sessions import simulate_session

SEEDS = tuple(range(40))

SMALL_TILTS = Plan(
    "small",
    tuple(
        PlannedPosition(*(float(x) for x in np.deg2rad([a, b, p])), tolerance=0.0)
        for a, b in [(0, 0), (15, 0), (-15, 0), (0, 15), (0, -15), (15, 15)]
        for p in (0, 180)
    ),
)
"""Tilts of at most 15°: f_y within 3.4 % of −g, where the pair looks alike."""

PAIR = ("cross_axis", "scale_nonlinearity")
ENTRY = {"cross_axis": 5, "scale_nonlinearity": 2}
"""K[2][1] (the sixth off-diagonal entry) and quadratic[2]."""


@cache
def sigmas() -> dict[str, np.ndarray]:
    """σ of every candidate entry under the small-tilt plan (seed 999, clean unit)."""
    return effect_sigmas(simulate_session(Truth.from_dict(clean_truth(999)), SMALL_TILTS, seed=999))


def hidden(effect: str, seed: int) -> dict[str, object]:
    """A clean unit with ``effect``'s look-alike entry at ±5σ (sign alternating by seed)."""
    doc = clean_truth(seed)
    size = (1.0 if seed % 2 else -1.0) * 5.0 * sigmas()[f"accel.{effect}"][ENTRY[effect]]
    if effect == "cross_axis":
        doc["accel"]["K"][2][1] += size
    else:
        doc["accel"]["quadratic"] = [0.0, 0.0, size]
    return doc


@pytest.mark.slow
@pytest.mark.parametrize("effect", PAIR)
def test_look_alike_is_named_right_or_reported_ambiguous(effect: str) -> None:
    """Wrong on at most 1 of 40 (measured 0; at a 1 % rate P(Bin(40, 0.01) >= 2) = 0.061);
    named or ambiguous on >= 37 (the oracle's power at 5σ is 1.0; measured 40; 37 or more of
    40 rejects a rate of 0.8: P(Bin(40, 0.8) >= 37) = 0.029)."""
    wrong, stated = [], 0
    for seed in SEEDS:
        session = simulate_session(
            Truth.from_dict(hidden(effect, seed)), SMALL_TILTS, seed=seed, estimate_scatter=True
        )
        result = analyse_discrepancy(session)
        found = {f.effect for f in result.findings}
        unsure = {c for a in result.ambiguous for c in a.candidates}
        if found - {effect}:
            wrong.append((seed, sorted(found)))
        stated += found == {effect} or (not found and effect in unsure)
    assert len(wrong) <= 1, wrong
    assert stated >= 37, stated
