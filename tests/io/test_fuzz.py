"""Fuzzing the strict readers with mutated valid files: InputError or success, nothing else.

Each reader gets 200 derandomised examples of 1-4 edits (insert a nasty token, delete a
range, truncate, overwrite bytes, duplicate or drop a line) of a valid file. Whatever the
result, the only exception allowed is :class:`InputError`, and its message is one line.
"""

from __future__ import annotations

import json
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings

from canimucal.errors import InputError
from canimucal.io.calibration import read_calibration
from canimucal.io.plans import read_plan
from canimucal.io.recording import read_recording_csv
from tests.support.fuzzing import byte_mutations

RECORDING = (
    b"# schema: canimucal.recording/1\n# sample_rate_hz: 200\n# device_serial: 42\n"
    b"# latitude_deg: 50.45\n# offset_binary: false\n"
    b"t,counter,position,alpha_deg,beta_deg,psi_deg,ax,ay,az,gx,gy,gz,temp_c\n"
    b"1700000000.000000,0,,,,,10,-2048,5,1,2,3,25.0\n"
    b"1700000000.005000,1,0,0,0,0,11,-2047,4,,,,25.0\n"
    b"1700000000.010000,2,0,0,0,0,12,-2049,6,2,1,3,\n"
    b"1700000000.015000,4,1,22.5,2.5,0,-780,-1890,80,1,2,3,25.5\n"
    b"1700000000.020000,5,1,22.5,2.5,0,,,,1,2,3,25.5\n"
)

CALIBRATION = json.dumps(
    {
        "schema": "canimucal.calibration/1",
        "created": "2026-01-01T00:00:00Z",
        "plan": "five",
        "device": {"node_id": 16, "serial": 3},
        "accel": {"bias": [1.0, None, 3.0], "K": [[208.0, 0.0, 0.0], [0, 209, 0], [0, 0, -210]]},
        "base_tilt_deg": {"alpha0": 0.5, "beta0": -1.0, "sigma": [0.1, 0.2]},
        "covariance": {"order": ["accel.bias[0]", "base_tilt.beta0"], "matrix": [[1, 0], [0, 2]]},
        "positions": [{"alpha_deg": 0, "beta_deg": 0, "n": 6000, "mean_accel": [1, 2, 3]}],
        "objects": {"0x2100:01": 1.5, "0x2121:05": 1},
        "readback": {"valid": 1, "crc_ok": True},
    },
    indent=1,
).encode()

PLAN_JSON = (
    b'{"positions": [{"alpha_deg": 0, "beta_deg": 0},\n'
    b' {"alpha_deg": 45, "beta_deg": 5, "psi_deg": 90, "seconds": 60, "tolerance_deg": 0.2}]}\n'
)
PLAN_TOML = (
    b"[[positions]]\nalpha_deg = 0\nbeta_deg = 0\n\n"
    b"[[positions]]\nalpha_deg = 45.0\nbeta_deg = 5\nseconds = 60\ntolerance_deg = 0.2\n"
)


FUZZ = settings(
    max_examples=200,
    derandomize=True,
    deadline=None,
    database=None,
    suppress_health_check=[HealthCheck.too_slow],
)


@pytest.fixture(scope="module")
def scratch() -> Iterator[Path]:
    with tempfile.TemporaryDirectory(prefix="canimucal-fuzz-") as name:
        yield Path(name)


def _only_input_errors(reader: Callable[[Path], Any], path: Path, data: bytes) -> None:
    path.write_bytes(data)
    try:
        reader(path)
    except InputError as exc:
        message = str(exc)
        assert message and "\n" not in message and "\r" not in message, repr(message)


def test_the_valid_bases_are_valid(scratch: Path) -> None:
    for name, data, reader in [
        ("r.csv", RECORDING, read_recording_csv),
        ("c.json", CALIBRATION, read_calibration),
        ("p.json", PLAN_JSON, read_plan),
        ("p.toml", PLAN_TOML, read_plan),
    ]:
        (scratch / name).write_bytes(data)
        reader(scratch / name)


@FUZZ
@given(data=byte_mutations(RECORDING))
def test_fuzz_recording(scratch: Path, data: bytes) -> None:
    _only_input_errors(read_recording_csv, scratch / "r.csv", data)


@FUZZ
@given(data=byte_mutations(CALIBRATION))
def test_fuzz_calibration(scratch: Path, data: bytes) -> None:
    _only_input_errors(read_calibration, scratch / "c.json", data)


@FUZZ
@given(data=byte_mutations(PLAN_JSON))
def test_fuzz_plan_json(scratch: Path, data: bytes) -> None:
    _only_input_errors(read_plan, scratch / "p.json", data)


@FUZZ
@given(data=byte_mutations(PLAN_TOML))
def test_fuzz_plan_toml(scratch: Path, data: bytes) -> None:
    _only_input_errors(read_plan, scratch / "p.toml", data)
