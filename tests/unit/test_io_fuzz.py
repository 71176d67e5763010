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
from hypothesis import strategies as st

from canimucal.errors import InputError
from canimucal.io.calibration import read_calibration
from canimucal.io.plans import read_plan
from canimucal.io.recording import read_recording

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

TOKENS = [
    b"nan",
    b"NaN",
    b"inf",
    b"-Infinity",
    b"Infinity",
    b"1e999",
    b"-1",
    b"0",
    b"1.5",
    b"99999999999",
    b",",
    b",,",
    b"\n",
    b"\r\n",
    b"\n\n",
    b"#",
    b"# schema: canimucal.recording/2\n",
    b"# x: 1\n",
    b":",
    b" ",
    b"\t",
    b"\x00",
    b"\xff",
    b"\xc3",
    b"\xe2\x82\xac",
    b'"',
    b"{",
    b"}",
    b"[",
    b"]",
    b"null",
    b"true",
    b"[[positions]]\n",
    b"=",
    b"'",
    b'"schema"',
    b"e",
    b"-",
    b".",
    b"\\",
]


@st.composite
def mutations(draw: st.DrawFn, base: bytes) -> bytes:
    data = bytearray(base)
    for _ in range(draw(st.integers(1, 4))):
        at = draw(st.integers(0, len(data)))
        kind = draw(st.sampled_from(["insert", "delete", "truncate", "overwrite", "dup", "drop"]))
        token = draw(st.one_of(st.sampled_from(TOKENS), st.binary(min_size=1, max_size=6)))
        if kind == "insert":
            data[at:at] = token
        elif kind == "delete":
            del data[at : at + draw(st.integers(1, 20))]
        elif kind == "truncate":
            del data[at:]
        elif kind == "overwrite":
            data[at : at + len(token)] = token
        else:
            lines = bytes(data).split(b"\n")
            i = draw(st.integers(0, max(len(lines) - 1, 0)))
            if kind == "dup":
                lines.insert(i, lines[i])
            else:
                del lines[i]
            data = bytearray(b"\n".join(lines))
    return bytes(data)


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
        ("r.csv", RECORDING, read_recording),
        ("c.json", CALIBRATION, read_calibration),
        ("p.json", PLAN_JSON, read_plan),
        ("p.toml", PLAN_TOML, read_plan),
    ]:
        (scratch / name).write_bytes(data)
        reader(scratch / name)


@FUZZ
@given(data=mutations(RECORDING))
def test_fuzz_recording(scratch: Path, data: bytes) -> None:
    _only_input_errors(read_recording, scratch / "r.csv", data)


@FUZZ
@given(data=mutations(CALIBRATION))
def test_fuzz_calibration(scratch: Path, data: bytes) -> None:
    _only_input_errors(read_calibration, scratch / "c.json", data)


@FUZZ
@given(data=mutations(PLAN_JSON))
def test_fuzz_plan_json(scratch: Path, data: bytes) -> None:
    _only_input_errors(read_plan, scratch / "p.json", data)


@FUZZ
@given(data=mutations(PLAN_TOML))
def test_fuzz_plan_toml(scratch: Path, data: bytes) -> None:
    _only_input_errors(read_plan, scratch / "p.toml", data)
