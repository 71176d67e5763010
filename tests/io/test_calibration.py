"""Calibration JSON: record round trips, strict validation, records from solver estimates."""

from __future__ import annotations

import dataclasses
import hashlib
import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from canimucal.errors import InputError, ModelError
from canimucal.io.calibration import (
    Calibration,
    Conditions,
    Device,
    Fit,
    RecordingRef,
    as_array,
    calibration_to_dict,
    calibration_to_json,
    covariance_si,
    read_calibration,
    record_from_estimates,
    sha256_of,
    slope_trim_correlation,
    summarize_position,
    write_calibration,
)
from canimucal.model.positions import PlannedPosition
from canimucal.model.sensor import AccelParams
from canimucal.sim.averages import simulate_averages

V3 = [1.0, 2.0, 3.0]
M3 = [[1.0, 0.0, 0.0], [0.0, 2.0, 0.0], [0.0, 0.0, 3.0]]


def full_document() -> dict[str, Any]:
    """Every key docs/design.md §5 lists, with values of the right shapes."""
    return {
        "schema": "canimucal.calibration/1",
        "created": "2026-01-01T00:00:00Z",
        "plan": "five",
        "tool": {"name": "canimucal", "version": "0.1.0"},
        "device": {"node_id": 16, "vendor_id": 0, "product_code": 0, "revision": 0, "serial": 0},
        "conditions": {
            "g": 9.81,
            "latitude_deg": 50.45,
            "height_m": 0.0,
            "heading_deg": 0.0,
            "temp_c": 25.0,
        },
        "accel": {"bias": V3, "bias_sigma": V3, "K": M3, "K_sigma": M3},
        "gyro": {"bias": V3, "bias_sigma": V3, "S": M3, "S_sigma": M3, "G": M3, "G_sigma": M3},
        "base_tilt_deg": {"alpha0": 0.0, "beta0": 0.0, "sigma": [0.1, 0.2]},
        "covariance": {
            "order": ["accel.bias[0]", "base_tilt.beta0"],
            "matrix": [[1.0, 0.1], [0.1, 2.0]],
        },
        "positions": [
            {
                "alpha_deg": 0.0,
                "beta_deg": 0.0,
                "psi_deg": 0.0,
                "seconds": 30.0,
                "n": 6000,
                "lost": 0,
                "mean_accel": V3,
                "mean_gyro": V3,
                "std_accel": V3,
                "std_gyro": V3,
                "temp_c": 25.0,
            }
        ],
        "fit": {"rms": 0.0, "dof": 0},
        "recording": {"file": "name.csv", "sha256": "0" * 64},
        "objects": {"0x2100:01": 1.5, "0x2121:05": 1, "0x2121:06": 3735928559},
        "readback": {
            "accel_bias": V3,
            "accel_correction": M3,
            "gyro_bias": V3,
            "gyro_correction": M3,
            "gyro_g": M3,
            "base_tilt_rad": [0.0, 0.0],
            "valid": 1,
            "crc_ok": True,
        },
    }


def test_full_document_round_trips_key_for_key(tmp_path: Path) -> None:
    record = read_calibration(json.dumps(full_document()))
    assert calibration_to_dict(record) == full_document()
    path = write_calibration(tmp_path / "cal.json", record, overwrite=False)
    again = read_calibration(path)
    assert again == record
    assert read_calibration(str(path)) == record
    text = path.read_text()
    assert text.endswith("\n") and text.startswith('{\n  "schema": "canimucal.calibration/1"')
    assert list(json.loads(text)) == list(full_document())  # the contract's key order


def test_a_byte_order_mark_before_the_json_is_skipped(tmp_path: Path) -> None:
    path = tmp_path / "cal.json"
    path.write_bytes(b"\xef\xbb\xbf" + json.dumps(full_document()).encode())
    assert calibration_to_dict(read_calibration(path)) == full_document()


def test_objects_keep_their_int_or_float_type() -> None:
    record = read_calibration(json.dumps(full_document()))
    assert record.objects is not None
    assert isinstance(record.objects["0x2121:06"], int)
    assert isinstance(record.objects["0x2100:01"], float)


def test_minimal_document_and_nulls() -> None:
    doc = {
        "schema": "canimucal.calibration/1",
        "device": {"serial": 7},
        "accel": {"bias": [1, None, 3], "K": [[1, 0, 0], [0, None, 0], [0, 0, 1]]},
        "gyro": None,
    }
    record = read_calibration(json.dumps(doc))
    assert record.device.serial == 7 and record.gyro is None
    assert record.accel.bias == (1.0, None, 3.0)
    np.testing.assert_array_equal(as_array(record.accel.bias, (3,)), [1.0, np.nan, 3.0])
    assert np.isnan(as_array(record.accel.K_sigma, (3, 3))).all()
    # a null and an absent key mean the same; the writer omits None
    assert "gyro" not in calibration_to_dict(record)


def _mutate(path: str, value: Any) -> str:
    """The full document with the value at dotted ``path`` replaced (``...`` deletes it)."""
    doc = full_document()
    keys = path.split(".")
    target = doc
    for key in keys[:-1]:
        target = target[int(key)] if isinstance(target, list) else target[key]
    if value is ...:
        del target[keys[-1]]
    else:
        target[keys[-1]] = value
    return json.dumps(doc)


MALFORMED = [
    ("schema missing", _mutate("schema", ...), "schema must be 'canimucal.calibration/1'"),
    ("schema v2", _mutate("schema", "canimucal.calibration/2"), "schema must be"),
    ("serial missing", _mutate("device.serial", ...), "device.serial: required"),
    ("device missing", _mutate("device", ...), "device: required"),
    ("bias missing", _mutate("accel.bias", ...), "accel.bias: required"),
    ("K missing", _mutate("accel.K", ...), "accel.K: required"),
    ("K null", _mutate("accel.K", None), "accel.K: required (null given)"),
    ("unknown top", _mutate("warnings", ["x"]), "warnings: unknown key"),
    ("unknown nested", _mutate("gyro.T", M3), "gyro.T: unknown key"),
    ("unknown in list", _mutate("positions.0.foo", 1), "positions[0].foo: unknown key"),
    ("unknown readback", _mutate("readback.crc", 1), "readback.crc: unknown key"),
    ("bias shape", _mutate("accel.bias", [1, 2]), "accel.bias: must be a 3 array"),
    ("K shape", _mutate("accel.K", [[1, 2, 3]] * 2), "accel.K: must be a 3x3 array"),
    ("K row shape", _mutate("accel.K", [[1, 2], [1, 2], [1, 2]]), "accel.K[0]: must be a 3"),
    ("sigma shape", _mutate("base_tilt_deg.sigma", [1.0]), "base_tilt_deg.sigma: must be a 2"),
    ("string number", _mutate("accel.bias", [1, "2", 3]), "accel.bias[1]: must be a finite number"),
    ("bool number", _mutate("fit.rms", True), "fit.rms: must be a finite number"),
    ("overflow", _mutate("accel.bias", [1, 2, 10**400]), "accel.bias[2]: number out of range"),
    ("serial float", _mutate("device.serial", 1.0), "device.serial: must be an integer"),
    ("serial negative", _mutate("device.serial", -1), "device.serial: must be 0..4294967295"),
    ("serial bool", _mutate("device.serial", True), "device.serial: must be an integer"),
    ("node 0", _mutate("device.node_id", 0), "device.node_id: must be 1..127"),
    ("plan", _mutate("plan", "six"), "plan: must be one of two, five, recommended"),
    ("created", _mutate("created", "yesterday"), "created: not an ISO 8601 time"),
    ("sha256", _mutate("recording.sha256", "abc"), "recording.sha256: malformed"),
    ("object key", _mutate("objects", {"2100:01": 1}), "malformed object key"),
    ("object value", _mutate("objects", {"0x2100:01": "1"}), "objects.0x2100:01: must be a"),
    ("valid 2", _mutate("readback.valid", 2), "readback.valid: must be 0..1"),
    ("crc_ok int", _mutate("readback.crc_ok", 1), "readback.crc_ok: must be true or false"),
    ("g zero", _mutate("conditions.g", 0), "conditions.g: must be > 0"),
    ("dof negative", _mutate("fit.dof", -1), "fit.dof: must be ≥ 0"),
    ("cov size", _mutate("covariance.order", ["accel.bias[0]"]), "covariance.matrix is 2x2"),
    ("cov asym", _mutate("covariance.matrix", [[1.0, 0.1], [0.2, 2.0]]), "not a covariance"),
    ("cov negative", _mutate("covariance.matrix", [[-1.0, 0], [0, 2.0]]), "not a covariance"),
    ("cov ragged", _mutate("covariance.matrix", [[1.0], [0.1, 2.0]]), "must be a square"),
    ("cov name", _mutate("covariance.order", ["accel.bias[3]", "x"]), "unknown parameter"),
    ("positions obj", _mutate("positions", {"a": 1}), "positions: must be a list"),
    ("NaN", _mutate("fit.rms", 0.5).replace("0.5", "NaN"), "NaN is not allowed"),
    ("Infinity", _mutate("fit.rms", 0.5).replace("0.5", "Infinity"), "Infinity is not allowed"),
    ("-Infinity", _mutate("fit.rms", 0.5).replace("0.5", "-Infinity"), "-Infinity is not all"),
    ("duplicate", '{"schema": "canimucal.calibration/1", "schema": "x"}', "duplicate key"),
    ("array top", "[1, 2]", "top level is not a JSON object"),
    ("syntax", '{"schema": "canimucal.calibration/1",\n "device": {serial: 1}}', ":2:13: inv"),
]


@pytest.mark.parametrize(
    ("text", "words"), [m[1:] for m in MALFORMED], ids=[m[0] for m in MALFORMED]
)
def test_malformed_calibration_is_an_input_error(tmp_path: Path, text: str, words: str) -> None:
    path = tmp_path / "cal.json"
    path.write_text(text)
    with pytest.raises(InputError) as info:
        read_calibration(path)
    message = str(info.value)
    assert "\n" not in message
    assert message.startswith(str(path))
    assert words in message


def test_unreadable_file(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="cannot read"):
        read_calibration(tmp_path / "none.json")
    (tmp_path / "bin.json").write_bytes(b"\xff\xfe{")
    with pytest.raises(InputError, match="not UTF-8"):
        read_calibration(tmp_path / "bin.json")


def test_write_refuses_to_overwrite(tmp_path: Path) -> None:
    record = read_calibration(json.dumps(full_document()))
    path = write_calibration(tmp_path / "c.json", record, overwrite=False)
    with pytest.raises(InputError, match="exists; use overwrite=True"):
        write_calibration(path, record, overwrite=False)


def test_non_finite_record_is_refused_on_write(tmp_path: Path) -> None:
    record = read_calibration(json.dumps(full_document()))
    bad = dataclasses.replace(record, fit=Fit(rms=float("nan"), dof=1))
    with pytest.raises(InputError, match="non-finite"):
        write_calibration(tmp_path / "nan.json", bad, overwrite=False)
    assert not list(tmp_path.iterdir())


def test_sha256_of(tmp_path: Path) -> None:
    path = tmp_path / "r.csv"
    path.write_bytes(b"abc" * 1000)
    assert sha256_of(path) == hashlib.sha256(b"abc" * 1000).hexdigest()


# -------------------------------------------------------------------- from estimates

NAMES_DIAG = [f"accel.bias[{i}]" for i in range(3)] + [f"accel.K[{i}][{i}]" for i in range(3)]
NAMES_TILT = [*NAMES_DIAG, "base_tilt.alpha0", "base_tilt.beta0"]


def _estimates(names: list[str], seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    a = rng.normal(size=(len(names), len(names)))
    return rng.normal(size=len(names)), a @ a.T * 1e-4 + np.eye(len(names)) * 1e-4


def test_diagonal_k_gives_zero_off_diagonal_with_null_sigma() -> None:
    values, cov = _estimates(NAMES_TILT)
    record = record_from_estimates(
        NAMES_TILT, values, cov, device=Device(serial=1), created="2026-01-01T00:00:00Z"
    )
    k = as_array(record.accel.K, (3, 3))
    k_sigma = as_array(record.accel.K_sigma, (3, 3))
    np.testing.assert_array_equal(np.diag(k), values[3:6])
    assert (k[~np.eye(3, dtype=bool)] == 0.0).all()
    assert np.isnan(k_sigma[~np.eye(3, dtype=bool)]).all()
    np.testing.assert_allclose(np.diag(k_sigma), np.sqrt(np.diag(cov))[3:6])
    assert record.gyro is None


def test_tilt_is_degrees_in_the_file_and_radians_back() -> None:
    values, cov = _estimates(NAMES_TILT, seed=1)
    record = record_from_estimates(NAMES_TILT, values, cov, device=Device(serial=1))
    tilt = record.base_tilt_deg
    assert tilt is not None
    assert tilt.alpha0 == pytest.approx(np.rad2deg(values[6]))
    assert tilt.sigma == pytest.approx(np.rad2deg(np.sqrt(np.diag(cov)[6:])))
    assert record.covariance is not None
    matrix = np.array(record.covariance.matrix)
    assert matrix[6, 6] == pytest.approx(cov[6, 6] * (180 / np.pi) ** 2)
    assert matrix[0, 6] == pytest.approx(cov[0, 6] * 180 / np.pi)
    names, back = covariance_si(read_calibration(calibration_to_json(record)))
    assert names == NAMES_TILT
    np.testing.assert_allclose(back, cov, rtol=1e-12)


def test_mounting_trim_is_degrees_in_the_file_with_its_correlation_to_the_slope() -> None:
    names = [*NAMES_TILT, "mounting_trim.alpha", "mounting_trim.beta", "mounting_trim.psi"]
    values, cov = _estimates(names, seed=2)
    record = record_from_estimates(names, values, cov, device=Device(serial=1))
    trim = record.mounting_trim_deg
    assert trim is not None
    assert (trim.alpha, trim.beta, trim.psi) == pytest.approx(tuple(np.rad2deg(values[8:])))
    assert trim.sigma == pytest.approx(np.rad2deg(np.sqrt(np.diag(cov)[8:])))
    np.testing.assert_allclose(trim.radians(), values[8:], rtol=1e-12)
    again = read_calibration(calibration_to_json(record))
    assert again.mounting_trim_deg == trim
    back_names, back = covariance_si(again)
    assert back_names == names
    np.testing.assert_allclose(back, cov, rtol=1e-12)
    sd = np.sqrt(np.diag(cov))
    corr = cov[6:8, 8:] / np.outer(sd[6:8], sd[8:])
    assert slope_trim_correlation(again) == pytest.approx(corr.flat[np.argmax(np.abs(corr))])
    assert (
        slope_trim_correlation(
            record_from_estimates(NAMES_TILT, *_estimates(NAMES_TILT), device=Device(serial=1))
        )
        is None
    )
    assert (
        record_from_estimates(
            NAMES_TILT, *_estimates(NAMES_TILT), device=Device(serial=1)
        ).mounting_trim_deg
        is None
    )


def test_parameters_not_estimated_are_null_and_held_fixed_too() -> None:
    names = [*NAMES_DIAG, "accel.K[0][1]", "gyro.bias[0]", "gyro.bias[1]", "gyro.bias[2]"]
    values, cov = _estimates(names, seed=2)
    held = {"accel.K[1][0]": "not identifiable", "base_tilt.beta0": "not identifiable"}
    record = record_from_estimates(names, values, cov, device=Device(serial=1), held_fixed=held)
    k = record.accel.K
    assert k[0][1] == values[6] and k[1][0] is None and k[2][0] == 0.0
    assert record.gyro is not None
    assert record.gyro.bias == tuple(values[7:10])
    assert record.gyro.S == ((None,) * 3,) * 3  # no S estimated: nothing held at zero
    assert record.gyro.G_sigma == ((None,) * 3,) * 3
    assert record.base_tilt_deg is not None
    assert record.base_tilt_deg.beta0 is None and record.base_tilt_deg.alpha0 is None
    read_calibration(calibration_to_json(record))  # what we build, we can read


@pytest.mark.parametrize(
    ("names", "values", "cov", "words"),
    [
        (["accel.bias[3]"], [1.0], [[1.0]], "unknown parameter name"),
        (["base_tilt.alpha0.x"], [1.0], [[1.0]], "unknown parameter name"),
        (["accel.bias[0]", "accel.bias[0]"], [1.0, 1.0], np.eye(2), "repeat"),
        (["accel.bias[0]"], [1.0, 2.0], [[1.0]], "need 1 values"),
        (["accel.bias[0]"], [np.nan], [[1.0]], "finite"),
        (["accel.bias[0]"], [1.0], [[-1.0]], "negative variance"),
    ],
)
def test_bad_estimates_are_model_errors(
    names: list[str], values: Any, cov: Any, words: str
) -> None:
    with pytest.raises(ModelError, match=words):
        record_from_estimates(names, values, cov, device=Device(serial=1))


def test_simulated_positions_summarised_and_written(tmp_path: Path) -> None:
    plan = [
        PlannedPosition(np.deg2rad(a), np.deg2rad(b), seconds=30.0)
        for a, b in [(0, 0), (22.5, 0), (22.5, 2.5), (45, 2.5), (45, 5)]
    ]
    averages = simulate_averages(plan, AccelParams.nominal(), np.random.default_rng(3))
    summaries = [summarize_position(a) for a in averages]
    values, cov = _estimates(NAMES_DIAG, seed=4)
    record = record_from_estimates(
        NAMES_DIAG,
        values,
        cov,
        device=Device(serial=9, node_id=16),
        plan="five",
        conditions=Conditions(g=9.80665),
        positions=summaries,
        fit=Fit(rms=0.001, dof=9),
        recording=RecordingRef(file="r.csv", sha256="a" * 64),
    )
    back = read_calibration(write_calibration(tmp_path / "sim.json", record, overwrite=False))
    assert back == record
    assert back.positions is not None and back.positions[3].alpha_deg == pytest.approx(45.0)
    assert back.positions[0].mean_gyro is None
    assert back.positions[4].mean_accel == pytest.approx(tuple(averages[4].mean_accel))
    assert isinstance(back, Calibration)
