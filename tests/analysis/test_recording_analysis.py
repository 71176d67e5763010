"""The discrepancy loop on whole simulated sessions: untestable reasons, scalar path, outputs."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from canimucal.analysis.discrepancy import analyse_discrepancy, effect_sigmas
from canimucal.analysis.report import analyse_recording, extended_truth, observed_poses
from canimucal.analysis.simulated import simulate_plan_recording
from canimucal.io.recording import recording_from_columns
from canimucal.model.positions import Plan, PlannedPosition
from canimucal.model.vocabulary.plans import RECOMMENDED
from canimucal.sim.effects import hide_effect, slope_random_walk, warm_up_profile
from canimucal.sim.truth import Truth
from tests.support.sessions import simulate_session


def _doc(seed: int, temperature: dict[str, Any] | None = None) -> dict[str, Any]:
    doc = Truth.random(np.random.default_rng(seed), cross_axis_max=0.0, tilt_max_deg=0.0)
    out = doc.to_dict()
    out["temperature"] = temperature or {"profile": warm_up_profile()}
    return out


def test_temperature_constant_or_linear_is_untestable() -> None:
    constant = simulate_session(Truth.from_dict(_doc(1, {"start_c": 25.0})), RECOMMENDED, seed=1)
    reason = analyse_discrepancy(constant).untestable["temperature_bias"]
    assert reason.startswith("temperature constant")
    ramp = {"start_c": 20.0, "rate_c_per_s": 0.05}
    linear = simulate_session(Truth.from_dict(_doc(2, ramp)), RECOMMENDED, seed=2)
    assert "linear in time" in analyse_discrepancy(linear).untestable["temperature_bias"]


def test_sigmas_mark_aliased_entries() -> None:
    session = simulate_session(Truth.from_dict(_doc(3)), RECOMMENDED, seed=3)
    sig = effect_sigmas(session)
    # f_y takes only two values under the recommended plan: quadratic[1] is aliased with
    # the y bias and scale, so its σ is infinite and the generator never draws it
    assert np.isinf(sig["accel.scale_nonlinearity"][1])
    assert np.all(np.isfinite(sig["accel.base_tilt"]))
    assert np.all(sig["gyro.gyro_g_sensitivity"] > 0)


def test_inverted_axis_is_named_axis_sign() -> None:
    doc, hidden = hide_effect(_doc(4), "axis_sign", np.random.default_rng(4), {})
    session = simulate_session(Truth.from_dict(doc), RECOMMENDED, seed=4)
    result = analyse_discrepancy(session)
    assert [f.effect for f in result.findings] == ["axis_sign"]
    assert result.findings[0].size < 0 and hidden.entry in result.findings[0].evidence


def test_drift_size_formula() -> None:
    # k = 5 white σ of a 30 s slope at 200 Hz with 4.4 counts per sample
    q = slope_random_walk(5.0, 4.4, 200.0, 30.0)
    slope_sigma = 4.4 * np.sqrt(12.0 / (6000 * 30.0**2))
    assert np.sqrt(6.0 * q**2 / (5.0 * 30.0)) == pytest.approx(5.0 * slope_sigma)


SPREAD = Plan(
    "custom",
    tuple(
        PlannedPosition(*np.deg2rad([a, b, 0.0]), seconds=10.0)
        for a, b in [(0, 0), (90, 0), (-90, 0), (180, 0), (0, 90), (0, -90), (45, 30),
                     (-45, 60), (135, -30), (30, -60), (-120, 20), (60, 75), (-30, -45),
                     (150, 50)]
    ),
)  # fmt: skip
"""Fourteen orientations spread over the sphere: the scalar fit needs more than 7."""


def _unlabelled(doc: dict[str, Any], seed: int) -> Any:
    rec = simulate_plan_recording(Truth.from_dict(doc), SPREAD, seed=seed)
    return recording_from_columns(
        {"sample_rate_hz": rec.sample_rate_hz}, t=rec.t, accel=rec.accel, gyro=rec.gyro
    )


def test_scalar_path_names_cross_axis_and_reports_untestable() -> None:
    doc = _doc(5)
    doc["accel"]["K"][2][1] = 4.0  # counts per m/s²: a 1 % non-orthogonality
    truth = Truth.from_dict(doc)
    analysis = analyse_recording(_unlabelled(doc, 5), g=truth.g)
    result = analysis.result
    assert result.method == "scalar"
    assert "cross_axis" in {f.effect for f in result.findings}
    assert {"base_tilt", "axis_sign", "temperature_bias"} <= set(result.untestable)
    assert observed_poses(analysis) is None


def test_extended_truth_is_a_valid_truth_document() -> None:
    doc = _doc(6)
    doc["accel"]["K"][0][2] = 2.0
    truth = Truth.from_dict(doc)
    rec = simulate_plan_recording(truth, RECOMMENDED, seed=6)
    analysis = analyse_recording(rec, g=truth.g, latitude=truth.latitude)
    rebuilt = Truth.from_dict(extended_truth(analysis))
    assert rebuilt.accel.K[0, 2] == pytest.approx(2.0, abs=0.8)
    sigma = np.array([analysis.result.base_sigmas[f"accel.bias[{i}]"] for i in range(3)])
    assert np.all(np.abs(rebuilt.accel.bias - truth.accel.bias) < 4.0 * sigma)
    assert rebuilt.temperature.profile is not None
    plan = observed_poses(analysis)
    assert plan is not None and len(plan.positions) == 8
