"""The separation rule of docs/design.md §6 (issue 21 items 2, 3).

In the model holding a chosen term and its rival: the term significant beside the rival
(family-wise 1 %) is named whatever the rival does; both significant, both are named; only
when neither is significant beside the other is the pair ambiguous. When nothing is named the
report says whether the base model fits; text, JSON and ``--truth-out`` name the same terms.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from canimucal.analysis.discrepancy import _head_to_head, analyse_discrepancy
from canimucal.analysis.report import base_fit_summary
from canimucal.analysis.significance import LinearProblem, entry_test
from canimucal.sim.truth import Truth
from tests.analysis.test_hidden_effects import clean_truth
from tests.support.plans import twelve
from tests.support.sessions import simulate_session

TERM, RIVAL = "accel.cross_axis", "accel.scale_nonlinearity"
WEIGHTS = ({TERM: 1.0, RIVAL: 1.0}, 10.0)
"""Each candidate one entry in a family of weight 10: significant is p < 0.001."""


def _pair(seed: int, term: float, rival: float, n: int = 60) -> tuple[LinearProblem, dict]:
    """Two columns correlated 0.95; the residual holds ``term`` of the first and ``rival`` of
    the second's own direction (each in σ of the whitened noise per unit of column)."""
    rng = np.random.default_rng(seed)
    a = rng.normal(size=n)
    e = rng.normal(size=n)
    e -= a * (a @ e) / (a @ a)
    e *= np.linalg.norm(a) / np.linalg.norm(e)
    b = 0.95 * a + np.sqrt(1 - 0.95**2) * e
    problem = LinearProblem(
        residual_w=term * a + rival * e + rng.normal(size=n),
        base_w=np.ones((n, 1)),
        block=np.arange(n) // 2,
        unwhiten=np.eye(n),
        si_scale=np.ones(n),
        sensor=np.array(["accel"] * n),
    )
    return problem, {TERM: a[:, None], RIVAL: b[:, None]}


@pytest.mark.parametrize("seed", range(4))
def test_a_term_standing_beside_its_rival_is_named_though_the_rival_has_p_of_a_few_percent(
    seed: int,
) -> None:
    problem, columns = _pair(seed, term=5.0, rival=0.32)
    p_rival = entry_test(problem, columns, [TERM], RIVAL).p_value
    assert p_rival < 0.05  # the old rule (rival p > 0.05) called this pair ambiguous
    ambiguous, also, dropped = _head_to_head(problem, columns, [TERM], 0.01, WEIGHTS, False)
    assert (ambiguous, also, dropped) == ([], [], [])


@pytest.mark.parametrize("seed", range(4))
def test_both_significant_beside_each_other_are_both_named(seed: int) -> None:
    problem, columns = _pair(seed, term=15.0, rival=1.5)
    ambiguous, also, dropped = _head_to_head(problem, columns, [TERM], 0.01, WEIGHTS, False)
    assert (ambiguous, also, dropped) == ([], [RIVAL], [])


@pytest.mark.parametrize("seed", range(4))
def test_neither_significant_beside_the_other_is_ambiguous(seed: int) -> None:
    problem, columns = _pair(seed, term=1.0, rival=0.0)
    ambiguous, also, dropped = _head_to_head(problem, columns, [TERM], 0.01, WEIGHTS, False)
    assert [a.candidates for a in ambiguous] == [("cross_axis", "scale_nonlinearity")]
    assert ambiguous[0].correlation == pytest.approx(0.95, abs=0.01)
    assert (also, dropped) == ([], [])


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_cross_axis_of_one_percent_of_scale_is_named_alone(seed: int) -> None:
    doc = clean_truth(seed)
    k = doc["accel"]["K"]
    k[2][1] += (1.0 if seed % 2 else -1.0) * 0.01 * k[2][2]
    session = simulate_session(Truth.from_dict(doc), twelve(0.0), seed=seed, estimate_scatter=True)
    result = analyse_discrepancy(session)
    assert [f.effect for f in result.findings] == ["cross_axis"]
    assert not result.ambiguous
    assert result.scores["accel"].extended_terms == ("bias", "scale", "cross_axis")
    assert base_fit_summary(result)["summary"] is None


def test_nothing_named_says_whether_the_base_model_fits() -> None:
    """Seed 2: every position's mean pushed ±3 counts per axis (nothing of the vocabulary)."""
    doc = clean_truth(2)
    doc.pop("temperature")
    clean = simulate_session(Truth.from_dict(doc), twelve(0.0), seed=2, estimate_scatter=True)
    result = analyse_discrepancy(clean)
    assert not result.findings
    assert base_fit_summary(result)["summary"].startswith("no cause named; the base model fits")
    rng = np.random.default_rng(2)
    pushed = dataclasses.replace(
        clean,
        averages=tuple(
            dataclasses.replace(a, mean_accel=a.mean_accel + rng.choice([-3.0, 3.0], 3))
            for a in clean.averages
        ),
    )
    result = analyse_discrepancy(pushed)
    summary = base_fit_summary(result)
    assert not result.findings and not result.ambiguous and summary["rejected"]
    assert summary["summary"].startswith("no cause named; the base model is rejected, χ²/dof ")
    assert summary["summary"].endswith(": the misfit is not one of the candidates")
    # what is not named is not in the extended model either (JSON, --truth-out)
    assert result.scores["accel"].extended_terms == ("bias", "scale")
    assert np.all(result.params.K == np.diag(np.diag(result.params.K)))
    assert np.all(result.params.quadratic == 0.0)
