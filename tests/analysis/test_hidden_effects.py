"""Hidden effects (issue 5, item 8): `analyze` must name exactly the effect injected.

Generator: :func:`canimucal.sim.effects.hide_effect` on a random unit (biases ±50 counts,
scale errors ±3 %, no cross-axis, no tilt, default noise, 200 Hz) under the recommended plan,
30 s per position, angle errors drawn from the 0.1° tolerance, and a non-linear warm-up
(25 → 40 °C, τ = 120 s). The effect sits on a random axis or entry, its size uniform in
5σ–10σ of that entry's own estimate (σ from :func:`effect_sigmas` on the reference session,
seed ``REFERENCE_SEED``, with every other candidate in the model, so aliased entries are
never drawn). Sessions go through the fast per-position path
(:func:`simulate_session`), which the recording path reproduces (``test_recording_path_agrees``).

Seeds (fixed, listed): unit and noise ``SEEDS`` = 0..99; the effect draw ``10_000 + seed``.

A session counts as a hit when the effect is named exactly, or when nothing is named and the
effect is reported ``ambiguous`` against a look-alike (docs/design.md §6's head-to-head rule: under
this 8-position plan with 0.1° poses, the stands alternating, 2-3 of the 100 seeds of
cross_axis, scale_nonlinearity and base_tilt end ambiguous against a look-alike (cross_axis
with scale_nonlinearity, base_tilt with temperature_bias or cross_axis); the canonical
correlation reported in ``ambiguous`` is at least the worst entry pair's magnitude).
Naming a different cause counts as confidently wrong (at most ``MAX_WRONG``).

Thresholds as binomial statements. The outcomes are deterministic for these seeds; the
margins say how unlikely a failure would be for a fresh list of seeds:
- detection: ``hits >= 95`` of 100. Measured on these seeds: 100 % for every effect (named
  exactly 97-100, the rest ambiguous), none confidently wrong. For a fresh list of seeds
  P(Bin(100, p) <= 94) is 0.081 at p = 0.97, 0.015 at 0.98, 5e-4 at 0.99.
- confidently wrong: ``<= MAX_WRONG``. A second cause named beside the hidden one is a false
  alarm of the tests made after it was chosen; on clean data with cross_axis held in the
  model, temperature_bias's per-entry p is below 0.01 on 13 of 1200 seeds (positions
  visited stand by stand; below the Holm step that names it on 2), the rate its
  Bonferroni correction allows (0.8 % at p < 0.01 on the analysis's own noise model).
- false alarms on clean data: ``<= 2`` of 100. The family-wise level is 1 %, so
  P(Bin(100, 0.01) >= 3) = 0.079 for a fresh list; these seeds give 0.
"""

from __future__ import annotations

from functools import cache
from typing import Any

import numpy as np
import pytest

from canimucal.analysis.discrepancy import analyse_discrepancy, effect_sigmas
from canimucal.analysis.session import session_from_recording
from canimucal.analysis.simulated import simulate_plan_recording
from canimucal.model.vocabulary.effects import EFFECTS
from canimucal.model.vocabulary.plans import RECOMMENDED
from canimucal.sim.effects import hide_effect, warm_up_profile
from canimucal.sim.truth import Truth
from tests.support.sessions import simulate_session

SEEDS = tuple(range(100))
REFERENCE_SEED = 999
MIN_HITS = 95
MAX_FALSE_ALARMS = 2
MAX_WRONG = 1
"""Sessions on which a cause other than the hidden one is named (issue 14: at most 1 %)."""


def clean_truth(seed: int) -> dict[str, Any]:
    """A random unit without any effect of the vocabulary, warming up."""
    rng = np.random.default_rng(seed)
    doc = Truth.random(rng, cross_axis_max=0.0, tilt_max_deg=0.0).to_dict()
    doc["temperature"] = {"profile": warm_up_profile()}
    return doc


@cache
def reference_sigmas() -> dict[str, np.ndarray]:
    """σ of every candidate entry under the recommended plan and default noise."""
    truth = Truth.from_dict(clean_truth(REFERENCE_SEED))
    return effect_sigmas(simulate_session(truth, RECOMMENDED, seed=REFERENCE_SEED))


def named(doc: dict[str, Any], seed: int) -> set[str]:
    """Effects `analyze` names on one simulated session."""
    return named_or_ambiguous(doc, seed)[0]


def named_or_ambiguous(doc: dict[str, Any], seed: int) -> tuple[set[str], set[str]]:
    """Effects named, and effects reported ambiguous, on one simulated session."""
    session = simulate_session(Truth.from_dict(doc), RECOMMENDED, seed=seed)
    result = analyse_discrepancy(session)
    return {f.effect for f in result.findings}, {c for a in result.ambiguous for c in a.candidates}


@pytest.mark.slow
def test_clean_data_name_nothing() -> None:
    alarms = [s for s in SEEDS if named(clean_truth(s), s)]
    assert len(alarms) <= MAX_FALSE_ALARMS, f"false alarms on seeds {alarms}"


@pytest.mark.slow
@pytest.mark.parametrize("effect", list(EFFECTS))
def test_hidden_effect_is_named_exactly(effect: str) -> None:
    sigmas = reference_sigmas()
    misses, wrong = [], []
    for seed in SEEDS:
        doc, hidden = hide_effect(
            clean_truth(seed), effect, np.random.default_rng(10_000 + seed), sigmas
        )
        found, unsure = named_or_ambiguous(doc, seed)
        if found != {effect} and not (not found and effect in unsure):
            misses.append((seed, hidden.entry, round(hidden.sigmas, 1), sorted(found)))
        if found - {effect}:
            wrong.append((seed, sorted(found)))
    assert len(SEEDS) - len(misses) >= MIN_HITS, f"missed: {misses}"
    assert len(wrong) <= MAX_WRONG, f"confidently wrong: {wrong}"


@pytest.mark.parametrize("effect", ["cross_axis", "temperature_bias"])
def test_recording_path_agrees(effect: str) -> None:
    """The same hidden effect through a whole simulated recording (positions labelled)."""
    doc, _ = hide_effect(clean_truth(7), effect, np.random.default_rng(10_007), reference_sigmas())
    truth = Truth.from_dict(doc)
    rec = simulate_plan_recording(truth, RECOMMENDED, seed=7)
    session = session_from_recording(rec, g=truth.g, latitude=truth.latitude)
    assert {f.effect for f in analyse_discrepancy(session).findings} == {effect}
