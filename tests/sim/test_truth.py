"""Truth JSON of the simulator (docs/design.md §5): defaults, strict checks, round trip, random."""

from __future__ import annotations

import json
import math
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from canimucal.errors import InputError, SchemaError
from canimucal.model.gravity import normal_gravity
from canimucal.model.sensor import DEFAULT_ACCEL_LSB, DEFAULT_GYRO_LSB
from canimucal.sim.truth import (
    DEFAULT_ACCEL_NOISE_DENSITY,
    DEFAULT_GYRO_NOISE_DENSITY,
    SCHEMA,
    TemperatureProfile,
    Truth,
)


def _close(a: Any, b: Any, rel: float = 1e-13) -> bool:
    """Nested equality of JSON-like values, floats to ``rel`` (degrees go through radians)."""
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_close(a[k], b[k], rel) for k in a)
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(_close(x, y, rel) for x, y in zip(a, b, strict=True))
    if isinstance(a, float | int) and isinstance(b, float | int) and not isinstance(a, bool):
        return math.isclose(a, b, rel_tol=rel, abs_tol=1e-300)
    return bool(a == b)


def _full_dict() -> dict[str, Any]:
    """A truth document using every key with non-default values."""
    return {
        "schema": SCHEMA,
        "sample_rate_hz": 500,
        "g": 9.81,
        "latitude_deg": -33.9,
        "height_m": 120.0,
        "heading_deg": 37.5,
        "serial": 123456,
        "tilt_model": "additive",
        "base_tilt_deg": {"alpha0": -0.7, "beta0": 0.3},
        "accel": {
            "nominal_lsb": -0.00478840,
            "quantization": 0.5,
            "bias": [3.0, -4.0, 5.5],
            "K": [[-208.0, 1.0, -0.5], [0.2, 210.0, 0.1], [0.0, -0.3, 205.0]],
            "noise_density": [1e-3, 2e-3, 3e-3],
            "quadratic": [0.01, -0.02, 0.0],
            "temp_coeff": [0.5, -0.25, 0.0],
            "random_walk": [0.1, 0.2, 0.3],
            "bias_instability": [1.0, 2.0, 0.0],
            "correlation_time_s": [10.0, 20.0, 30.0],
        },
        "gyro": {
            "nominal_lsb": 0.00106422,
            "quantization": 0.0,
            "bias": [-7.0, 8.0, 9.0],
            "S": [[940.0, 2.0, 0.0], [0.0, -939.0, 1.0], [3.0, 0.0, 941.0]],
            "G": [[0.1, 0.0, 0.0], [0.0, 0.2, 0.0], [0.0, 0.0, -0.3]],
            "noise_density": [1e-4, 1.1e-4, 1.2e-4],
            "temp_coeff": [0.1, 0.2, 0.3],
            "random_walk": [0.0, 0.01, 0.0],
            "bias_instability": [0.0, 0.0, 0.5],
            "correlation_time_s": [1.0, 2.0, 3.0],
        },
        "temperature": {"start_c": 20.0, "rate_c_per_s": 0.01, "profile": [[0, 20], [60, 30.5]]},
        "faults": {"drop_tpdo2": {"every": 10}},
        "nmt_start": "operational",
        "heartbeat_ms": 0,
        "store_delay_s": 2.5,
        "store_pdo_mode": "queue",
        "storage_subs": [1, 2, 3],
        "sync_pdos": True,
        "timer_skew_ppm": -5000.0,
    }


def test_defaults_follow_design() -> None:
    t = Truth.from_dict({})
    assert t.sample_rate_hz == 200.0
    assert t.latitude == pytest.approx(np.deg2rad(50.45), rel=1e-15)
    assert t.g == pytest.approx(normal_gravity(np.deg2rad(50.45), 0.0), rel=1e-15)
    assert 9.80 < t.g < 9.82
    assert t.heading == 0.0 and t.alpha0 == 0.0 and t.beta0 == 0.0
    assert t.tilt_model == "rigid" and t.serial == 0 and dict(t.faults) == {}
    assert t.accel.nominal_lsb == pytest.approx(9.80665 / 2048, rel=1e-15)
    assert t.gyro.nominal_lsb == pytest.approx(np.pi / (180 * 16.4), rel=1e-15)
    np.testing.assert_allclose(t.accel.K, np.eye(3) / DEFAULT_ACCEL_LSB, rtol=1e-15)
    np.testing.assert_allclose(t.gyro.S, np.eye(3) / DEFAULT_GYRO_LSB, rtol=1e-15)
    np.testing.assert_array_equal(t.gyro.G, np.zeros((3, 3)))
    np.testing.assert_array_equal(t.accel.bias, np.zeros(3))
    np.testing.assert_array_equal(t.accel.noise_density, [DEFAULT_ACCEL_NOISE_DENSITY] * 3)
    np.testing.assert_array_equal(t.gyro.noise_density, [DEFAULT_GYRO_NOISE_DENSITY] * 3)
    assert t.accel.quantization == 1.0 and t.gyro.quantization == 1.0
    assert t.temperature == TemperatureProfile(25.0, 0.0, None)
    assert t.store_pdo_mode == "drop" and not t.sync_pdos and t.timer_skew_ppm == 0.0


def test_dataclass_default_equals_parsed_default() -> None:
    assert _close(Truth().to_dict(), Truth.from_dict({}).to_dict())


def test_nominal_lsb_sets_default_scale_with_its_sign() -> None:
    t = Truth.from_dict({"accel": {"nominal_lsb": -0.01}, "gyro": {"nominal_lsb": 0.002}})
    np.testing.assert_allclose(t.accel.K, -100.0 * np.eye(3))
    np.testing.assert_allclose(t.gyro.S, 500.0 * np.eye(3))


def test_gravity_from_latitude_and_height_or_given() -> None:
    t = Truth.from_dict({"latitude_deg": 10.0, "height_m": 2000.0})
    assert t.g == pytest.approx(normal_gravity(np.deg2rad(10.0), 2000.0), rel=1e-15)
    assert t.g < normal_gravity(np.deg2rad(10.0), 0.0) - 5e-3  # free-air gradient ~3e-6/m
    assert Truth.from_dict({"g": 9.7, "latitude_deg": 10.0}).g == 9.7


def test_angles_are_radians_inside_degrees_outside() -> None:
    t = Truth.from_dict(_full_dict())
    assert t.alpha0 == pytest.approx(np.deg2rad(-0.7), rel=1e-15)
    assert t.beta0 == pytest.approx(np.deg2rad(0.3), rel=1e-15)
    assert t.heading == pytest.approx(np.deg2rad(37.5), rel=1e-15)
    assert t.latitude == pytest.approx(np.deg2rad(-33.9), rel=1e-15)
    assert t.g == 9.81 and t.height_m == 120.0 and t.serial == 123456
    assert t.tilt_model == "additive"
    assert t.temperature.profile == ((0.0, 20.0), (60.0, 30.5))


def test_round_trip_through_json() -> None:
    d = _full_dict()
    t = Truth.from_dict(d)
    out = json.loads(json.dumps(t.to_dict()))
    assert _close(out, d)
    assert _close(Truth.from_dict(out).to_dict(), out)


def test_mounting_trim_is_radians_inside_and_round_trips() -> None:
    t = Truth.from_dict({"floor_slope_deg": [1.0, -2.0], "mounting_trim_deg": [1.5, -0.5, 2.0]})
    assert t.trim == pytest.approx(tuple(np.deg2rad([1.5, -0.5, 2.0])), rel=1e-15)
    assert t.trim_object and Truth.from_dict({}).trim == (0.0, 0.0, 0.0)
    out = t.to_dict()
    assert out["mounting_trim_deg"] == pytest.approx([1.5, -0.5, 2.0], rel=1e-14)
    assert Truth.from_dict(out).trim == pytest.approx(t.trim, rel=1e-15)
    assert "mounting_trim_deg" not in Truth.from_dict({}).to_dict()  # no trim, no key
    old = Truth.from_dict({"trim_object": False})
    assert not old.trim_object and Truth.from_dict(old.to_dict()).trim_object is False
    # drawn last: a seed's other draws are those it gave before the trim existed
    a, b = (
        Truth.random(np.random.default_rng(5)),
        Truth.random(np.random.default_rng(5), trim_max_deg=2.0),
    )
    assert a.to_dict() | {"mounting_trim_deg": b.to_dict()["mounting_trim_deg"]} == b.to_dict()
    assert np.all(np.abs(np.rad2deg(b.trim)) <= 2.0) and any(b.trim)


def test_faults_are_kept_opaque_and_copied() -> None:
    d = _full_dict()
    t = Truth.from_dict(d)
    d["faults"]["drop_tpdo2"]["every"] = 99
    assert t.faults == {"drop_tpdo2": {"every": 10}}
    assert t.to_dict()["faults"] == {"drop_tpdo2": {"every": 10}}


def test_arrays_are_read_only() -> None:
    t = Truth.from_dict({})
    with pytest.raises(ValueError):
        t.accel.K[0, 0] = 1.0


NAN, INF = float("nan"), float("inf")
BAD_CASES: list[tuple[Any, str]] = [
    ([], "truth: top level: must be a JSON object"),
    ({"schema": "canimucal.truth/2"}, "truth: schema: must be"),
    ({"schema": 1}, "truth: schema: must be"),
    ({"colour": "red"}, "truth: colour: unknown key"),
    ({"accel": []}, "truth: accel: must be a JSON object"),
    ({"accel": {"Q": 1}}, "truth: accel.Q: unknown key"),
    ({"gyro": {"quadratic": [0, 0, 0]}}, "truth: gyro.quadratic: unknown key"),
    ({"accel": {"K": [[1, 2, 3], [4, 5, 6]]}}, "truth: accel.K: must be a 3x3 array of finite"),
    ({"accel": {"K": [[1, 2, 3], [4, 5, 6], [7, 8, NAN]]}}, "truth: accel.K: must be a 3x3"),
    ({"accel": {"K": [[1, 2, 3], [4, 5], [7, 8, 9]]}}, "truth: accel.K: must be a 3x3"),
    ({"gyro": {"S": [1, 0, 0]}}, "truth: gyro.S: must be a 3x3"),
    ({"gyro": {"G": "zero"}}, "truth: gyro.G: must be a 3x3"),
    ({"accel": {"bias": [1, 2]}}, "truth: accel.bias: must be an array of 3 finite numbers"),
    ({"accel": {"bias": [1, True, 2]}}, "truth: accel.bias: must be an array of 3"),
    ({"gyro": {"bias": [1, "2", 3]}}, "truth: gyro.bias: must be an array of 3"),
    ({"gyro": {"bias": [1, INF, 3]}}, "truth: gyro.bias: must be an array of 3"),
    ({"accel": {"quadratic": 0.1}}, "truth: accel.quadratic: must be an array of 3"),
    ({"accel": {"noise_density": [-1e-3, 0, 0]}}, "truth: accel.noise_density: must be non-neg"),
    ({"gyro": {"random_walk": [0, -1e-3, 0]}}, "truth: gyro.random_walk: must be non-negative"),
    ({"accel": {"noise_density": [1e308, 0, 0]}}, "truth: accel.noise_density: gives a white"),
    ({"gyro": {"noise_density": [0, 0, 20.0]}}, "truth: gyro.noise_density: gives a white-noise"),
    ({"gyro": {"random_walk": [0, 1e6, 0]}}, "truth: gyro.random_walk: must be at most 65536"),
    ({"accel": {"bias_instability": [1e300] * 3}}, "truth: accel.bias_instability: must be at"),
    ({"gyro": {"bias_instability": [0, 0, INF]}}, "truth: gyro.bias_instability: must be an"),
    ({"gyro": {"bias_instability": [0, 0, -1]}}, "truth: gyro.bias_instability: must be non-"),
    ({"accel": {"correlation_time_s": [0, 1, 1]}}, "truth: accel.correlation_time_s: must be pos"),
    ({"accel": {"temp_coeff": [1, 2, 3, 4]}}, "truth: accel.temp_coeff: must be an array of 3"),
    ({"accel": {"quantization": -1}}, "truth: accel.quantization: must be ≥ 0"),
    ({"gyro": {"quantization": "1"}}, "truth: gyro.quantization: must be a finite number"),
    ({"accel": {"nominal_lsb": 0}}, "truth: accel.nominal_lsb: must be non-zero"),
    ({"gyro": {"nominal_lsb": NAN}}, "truth: gyro.nominal_lsb: must be a finite number"),
    ({"sample_rate_hz": 300}, "truth: sample_rate_hz: must be one of 50, 100, 200, 250, 500, 1000"),
    ({"sample_rate_hz": "200"}, "truth: sample_rate_hz: must be a finite number"),
    ({"sample_rate_hz": True}, "truth: sample_rate_hz: must be a finite number"),
    ({"g": NAN}, "truth: g: must be a finite number"),
    ({"g": -9.8}, "truth: g: must be positive"),
    ({"latitude_deg": 91.0}, "truth: latitude_deg: must be within"),
    ({"height_m": None}, "truth: height_m: must be a finite number"),
    ({"heading_deg": [0]}, "truth: heading_deg: must be a finite number"),
    ({"serial": -1}, "truth: serial: must be within"),
    ({"serial": 2**32}, "truth: serial: must be within"),
    ({"serial": 1.0}, "truth: serial: must be an integer"),
    ({"tilt_model": "paper"}, "truth: tilt_model: must be one of 'rigid', 'additive'"),
    ({"base_tilt_deg": [0, 0]}, "truth: base_tilt_deg: must be a JSON object"),
    ({"base_tilt_deg": {"gamma0": 1}}, "truth: base_tilt_deg.gamma0: unknown key"),
    ({"base_tilt_deg": {"alpha0": "1"}}, "truth: base_tilt_deg.alpha0: must be a finite number"),
    ({"base_tilt_deg": {"beta0": 95.0}}, "truth: base_tilt_deg.beta0: must be within"),
    ({"temperature": {"profile": [[0, 25], [0, 30]]}}, "truth: temperature.profile: times must"),
    ({"temperature": {"profile": [[0, 25, 1]]}}, "truth: temperature.profile: must be a non-empty"),
    ({"temperature": {"profile": []}}, "truth: temperature.profile: must be a non-empty"),
    ({"temperature": {"profile": [[0, NAN]]}}, "truth: temperature.profile: must be a non-empty"),
    ({"temperature": {"rate_c_per_s": INF}}, "truth: temperature.rate_c_per_s: must be a finite"),
    ({"temperature": {"start": 25}}, "truth: temperature.start: unknown key"),
    ({"faults": []}, "truth: faults: must be a JSON object"),
    ({"store_pdo_mode": "hold"}, "truth: store_pdo_mode: must be one of drop, queue, continue"),
    ({"store_pdo_mode": 1}, "truth: store_pdo_mode: must be one of drop, queue, continue"),
    ({"sync_pdos": 1}, "truth: sync_pdos: must be true or false"),
    ({"sync_pdos": "yes"}, "truth: sync_pdos: must be true or false"),
    ({"timer_skew_ppm": "5000"}, "truth: timer_skew_ppm: must be a finite number"),
    ({"timer_skew_ppm": NAN}, "truth: timer_skew_ppm: must be a finite number"),
    ({"timer_skew_ppm": 2e5}, "truth: timer_skew_ppm: must be within ±100000 ppm"),
    ({"mounting_trim_deg": [1, 2]}, "truth: mounting_trim_deg: must be [alpha, beta, psi]"),
    ({"mounting_trim_deg": {"alpha": 1}}, "truth: mounting_trim_deg: must be [alpha, beta, psi]"),
    ({"mounting_trim_deg": [0, "1", 0]}, "truth: mounting_trim_deg[1]: must be a finite number"),
    ({"mounting_trim_deg": [0, 0, 95]}, "truth: mounting_trim_deg[2]: must be within (-90, 90)"),
    ({"trim_object": 0}, "truth: trim_object: must be true or false"),
]


@pytest.mark.parametrize(("doc", "message"), BAD_CASES, ids=[m for _, m in BAD_CASES])
def test_bad_truth_raises_input_error_naming_the_key(doc: Any, message: str) -> None:
    with pytest.raises(InputError) as info:
        Truth.from_dict(doc)
    text = str(info.value)
    assert text.startswith(message)
    assert "\n" not in text
    assert info.value.exit_code == 2


def test_temperature_profile_interpolates_and_overrides_rate() -> None:
    p = TemperatureProfile(25.0, 1.0, ((10.0, 20.0), (20.0, 30.0), (40.0, 10.0)))
    np.testing.assert_allclose(p.at([0.0, 10.0, 15.0, 30.0, 40.0, 100.0]), [20, 20, 25, 20, 10, 10])
    ramp = TemperatureProfile(25.0, 0.5)
    np.testing.assert_allclose(ramp.at([0.0, 4.0]), [25.0, 27.0])


def _within_device_ranges(k: np.ndarray, lsb: float) -> bool:
    """docs/design.md §4 ranges of the correction M = K⁻¹ the node would accept."""
    m = np.linalg.inv(k)
    diag = np.abs(np.diag(m))
    off = np.abs(m - np.diag(np.diag(m)))
    return bool(np.all(np.abs(diag / abs(lsb) - 1) <= 0.5) and np.all(off <= 0.2 * diag[:, None]))


def test_random_truth_is_plausible() -> None:
    rng = np.random.default_rng(20261121)
    serials = set()
    for _ in range(50):
        t = Truth.random(rng)
        serials.add(t.serial)
        for k, lsb in ((t.accel.K, DEFAULT_ACCEL_LSB), (t.gyro.S, DEFAULT_GYRO_LSB)):
            e = k * lsb - np.eye(3)
            assert np.all(np.abs(np.diag(e)) <= 0.03)
            assert np.all(np.abs(e - np.diag(np.diag(e))) <= 0.01)
            assert _within_device_ranges(k, lsb)
        assert np.all(np.abs(t.accel.bias) <= 50) and np.all(np.abs(t.gyro.bias) <= 50)
        assert max(abs(t.alpha0), abs(t.beta0)) <= np.deg2rad(1.0)
        np.testing.assert_array_equal(t.gyro.G, np.zeros((3, 3)))
    assert len(serials) == 50  # 50 draws from 2**32: a collision has probability ~3e-7


def test_random_truth_is_deterministic_and_takes_overrides() -> None:
    a = Truth.random(np.random.default_rng(7), sample_rate_hz=1000, gyro_g_max=0.2)
    b = Truth.random(np.random.default_rng(7), sample_rate_hz=1000, gyro_g_max=0.2)
    assert a.to_dict() == b.to_dict()
    assert a.sample_rate_hz == 1000.0
    assert 0 < np.max(np.abs(a.gyro.G)) <= 0.2
    with pytest.raises(InputError, match="sample_rate_hz"):
        Truth.random(np.random.default_rng(7), sample_rate_hz=333)


@settings(derandomize=True, deadline=None, max_examples=30)
@given(st.integers(min_value=0, max_value=2**32 - 1))
def test_random_truth_round_trips(seed: int) -> None:
    t = Truth.random(np.random.default_rng(seed))
    d = json.loads(json.dumps(t.to_dict()))
    assert _close(Truth.from_dict(d).to_dict(), d)


def test_floor_tilt_deg_is_read_as_the_floor_slope() -> None:
    """DESIGN's truth key ``floor_tilt_deg`` is the same as ``floor_slope_deg``; not both."""
    doc = Truth.random(np.random.default_rng(1), tilt_max_deg=0.0).to_dict()
    del doc["base_tilt_deg"]
    slope = Truth.from_dict({**doc, "floor_slope_deg": [1.5, -0.5]})
    tilt = Truth.from_dict({**doc, "floor_tilt_deg": [1.5, -0.5]})
    assert (tilt.alpha0, tilt.beta0) == (slope.alpha0, slope.beta0) != (0.0, 0.0)
    with pytest.raises(SchemaError, match="not both"):
        Truth.from_dict({**doc, "floor_tilt_deg": [1.0, 0.0], "floor_slope_deg": [1.0, 0.0]})


def test_trials_biases_round_trip_and_give_each_trials_unit() -> None:
    """``trials`` (analyze --truth-out of a file of trials): each trial's biases, read back."""
    doc = {
        "accel": {"bias": [1.0, 2.0, 3.0]},
        "gyro": {"bias": [0.5, 0.0, -0.5]},
        "trials": [
            {"trial": 0, "accel_bias": [0.0, 2.0, 3.0], "gyro_bias": [0.0, 0.0, 0.0]},
            {"trial": 1, "accel_bias": [2.0, 2.0, 3.0], "gyro_bias": [1.0, 0.0, -1.0]},
        ],
    }
    truth = Truth.from_dict(doc)
    assert [t.trial for t in truth.trials] == [0, 1]
    units = truth.trial_units()
    np.testing.assert_array_equal(units[1].accel.bias, [2.0, 2.0, 3.0])
    np.testing.assert_array_equal(units[1].gyro.bias, [1.0, 0.0, -1.0])
    assert units[0].trials == () and units[0].accel.K.tolist() == truth.accel.K.tolist()
    again = Truth.from_dict(json.loads(json.dumps(truth.to_dict())))
    assert [t.to_dict() for t in again.trials] == doc["trials"]
    assert "trials" not in Truth.from_dict({}).to_dict()
    for bad, where in (
        ([{"trial": 0}], "trials[0]"),
        ([{"trial": 0, "accel_bias": [1.0, 2.0]}], "trials[0].accel_bias"),
        ([{"trial": 0, "accel_bias": [0.0] * 3}] * 2, "trials"),
        ([{"trial": -2, "accel_bias": [0.0] * 3}], "trials[0].trial"),
    ):
        with pytest.raises(SchemaError, match=where.replace("[", r"\[").replace("]", r"\]")):
            Truth.from_dict({"trials": bad})
