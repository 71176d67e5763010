"""Fuzzing the file readers through the CLI verbs, in process (issue 6, item 3).

Every malformed input must end as one ``error: …`` line and exit 2 — never a traceback,
never ``internal error`` (exit 1). A mutation may also leave the file valid: then the verb
does its job (exit 0). Two mutation families: byte edits of a valid file (tokens such as
``nan``, truncation, dropped lines) and, for JSON, edits of the parsed tree (a leaf replaced
by NaN, ±Infinity, a huge number, a string, null, a list; a key deleted or an unknown key
added), which reach the deeper validators.

``demo --truth`` is stubbed right after the truth is loaded: the stub builds a real
:class:`SimulatedImuNode` from each truth (validating its ``faults`` block as the demo's
rig does) and stops there, so valid truths do not run a whole demo.
"""

from __future__ import annotations

import json
import math
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import can
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from canimucal.analysis.simulated import simulate_plan_recording
from canimucal.cli import demo_cmd
from canimucal.cli.main import COMMANDS, main
from canimucal.io.recording_writer import write_recording
from canimucal.model.vocabulary.plans import builtin_plan
from canimucal.sim.truth import Truth
from canimucal.simnode.node import SimulatedImuNode
from tests.support.fuzzing import byte_mutations


def _recording() -> bytes:
    """A small valid recording: the five-position plan, 0.3 s per position, 50 Hz."""
    plan = builtin_plan("five").with_total_seconds(1.5)
    truth = Truth.from_dict({"sample_rate_hz": 50, "serial": 42})
    rec = simulate_plan_recording(truth, plan, seed=5, transient_s=0.1, angle_errors=False)
    with tempfile.TemporaryDirectory() as name:
        path = write_recording(Path(name) / "r.csv", rec, overwrite=False)
        return path.read_bytes()


RECORDING = _recording()
CALIBRATION: dict[str, Any] = {
    "schema": "canimucal.calibration/1",
    "plan": "five",
    "device": {"node_id": 16, "serial": 0},
    "accel": {"bias": [1.0, None, 3.0], "K": [[208.0, 0.5, 0.0], [0, 209, 0], [0, 0, -210]]},
    "gyro": {"bias": [0.5, 0.5, -1], "S": [[940, 0, 0], [0, 939, 0], [0, 0, 941]]},
    "base_tilt_deg": {"alpha0": 0.1, "beta0": -0.2},
    "fit": {"rms": 0.001, "dof": 4},
}
TRUTH: dict[str, Any] = {
    "schema": "canimucal.truth/1",
    "sample_rate_hz": 200,
    "serial": 9,
    "base_tilt_deg": {"alpha0": 0.2, "beta0": -0.1},
    "accel": {"bias": [10, -5, 3], "noise_density": [0.001, 0.001, 0.001]},
    "gyro": {"bias": [1, 2, 3]},
    "faults": {
        "tpdo_drop_fraction": 0.01,
        "burst_loss": {"probability": 0.001, "frames": 5},
        "sdo_aborts": [{"object": "0x2101:05", "access": "write", "after_writes": 1}],
        "emergency": [{"at_s": 3.0, "code": 20480, "register": 1}],
        "heartbeat_loss": {"from_s": 1.0, "until_s": 2.0},
    },
}
PLAN: dict[str, Any] = {
    "positions": [
        {"alpha_deg": 0, "beta_deg": 0, "seconds": 10},
        {"alpha_deg": 45, "beta_deg": 5, "psi_deg": 90, "seconds": 20, "tolerance_deg": 0.2},
        {"alpha_deg": -45, "beta_deg": 5, "psi_deg": 180},
    ]
}
NASTY: list[Any] = [math.nan, math.inf, -math.inf, 1e308, -1, 0, "x", None, [], {}, True]


class _ReachedRig(BaseException):
    """The truth was accepted and a node was built from it: stop the demo here."""


def _stub_open(settings: Any) -> None:
    """Build each simulated node from its truth, then stop the demo (no session runs)."""
    for truth in settings.sim.truths:
        bus = can.Bus(interface="virtual", channel="canimucal-fuzz-stub")
        try:
            SimulatedImuNode(bus, 0x10, truth).stop()
        finally:
            bus.shutdown()
    raise _ReachedRig


def _paths(node: Any, prefix: tuple[Any, ...] = ()) -> list[tuple[Any, ...]]:
    out = [prefix]
    if isinstance(node, dict):
        for key, value in node.items():
            out += _paths(value, (*prefix, key))
    elif isinstance(node, list):
        for i, value in enumerate(node):
            out += _paths(value, (*prefix, i))
    return out


@st.composite
def tree_mutations(draw: st.DrawFn, base: dict[str, Any]) -> bytes:
    """1–2 edits of the parsed JSON tree, serialized (NaN/Infinity as Python's json writes)."""
    doc = json.loads(json.dumps(base))
    for _ in range(draw(st.integers(1, 2))):
        path = draw(st.sampled_from(_paths(doc)[1:]))
        parent = doc
        for key in path[:-1]:
            parent = parent[key]
        kind = draw(st.sampled_from(["replace", "scale", "scale", "delete", "unknown"]))
        value = parent[path[-1]]
        if kind == "scale" and isinstance(value, int | float) and not isinstance(value, bool):
            # finite and well-formed, but perhaps out of the device's ranges
            parent[path[-1]] = value * draw(st.sampled_from([0.0, 0.3, 1.6, 3.0, -1.0, 1e5]))
        elif kind in ("replace", "scale"):
            parent[path[-1]] = draw(st.sampled_from(NASTY))
        elif kind == "delete":
            del parent[path[-1]]
        elif isinstance(parent, dict):
            parent["surprise_key"] = 1
    return json.dumps(doc).encode()


def json_inputs(base: dict[str, Any]) -> st.SearchStrategy[bytes]:
    """Byte edits and tree edits of a JSON document."""
    return st.one_of(tree_mutations(base), byte_mutations(json.dumps(base, indent=1).encode()))


FUZZ = settings(
    derandomize=True,
    deadline=None,
    database=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
)


@pytest.fixture(scope="module")
def scratch() -> Iterator[Path]:
    with tempfile.TemporaryDirectory(prefix="canimucal-clifuzz-") as name:
        yield Path(name)


def _run_cli(capsys: pytest.CaptureFixture[str], argv: list[str]) -> tuple[int, str]:
    capsys.readouterr()
    code = main(argv)
    return code, capsys.readouterr().err


def _assert_clean(code: int, err: str, ok: tuple[int, ...] = (0,)) -> None:
    assert "Traceback" not in err and "internal error" not in err, err
    if code in ok:
        return
    assert code == 2, f"exit {code}: {err}"
    lines = [line for line in err.splitlines() if line.strip()]
    errors = [line for line in lines if line.startswith("error: ")]
    assert len(errors) == 1, err  # one line says what is wrong


def test_the_valid_bases_pass(scratch: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (scratch / "plan.json").write_text(json.dumps(PLAN))
    assert _run_cli(capsys, ["plan", "--plan", str(scratch / "plan.json")])[0] == 0
    (scratch / "cal.json").write_text(json.dumps(CALIBRATION))
    argv = ["write-params", str(scratch / "cal.json"), "--sim", "--dry-run", "--force"]
    assert _run_cli(capsys, argv)[0] == 0
    (scratch / "rec.csv").write_bytes(RECORDING)
    assert _run_cli(capsys, ["solve", str(scratch / "rec.csv"), "--no-check"])[0] == 0


@settings(FUZZ, max_examples=80)
@given(data=byte_mutations(RECORDING))
def test_fuzz_solve_recording(
    scratch: Path, capsys: pytest.CaptureFixture[str], data: bytes
) -> None:
    (scratch / "rec.csv").write_bytes(data)
    _assert_clean(*_run_cli(capsys, ["solve", str(scratch / "rec.csv"), "--no-check"]))


@settings(FUZZ, max_examples=80)
@given(data=json_inputs(PLAN))
def test_fuzz_plan_file(scratch: Path, capsys: pytest.CaptureFixture[str], data: bytes) -> None:
    (scratch / "plan.json").write_bytes(data)
    _assert_clean(*_run_cli(capsys, ["plan", "--plan", str(scratch / "plan.json")]))


@settings(FUZZ, max_examples=80)
@given(data=json_inputs(TRUTH))
def test_fuzz_demo_truth(
    scratch: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
    data: bytes,
) -> None:
    monkeypatch.setattr(demo_cmd, "open_devices", _stub_open)
    (scratch / "truth.json").write_bytes(data)
    argv = ["demo", "--headless", "--truth", str(scratch / "truth.json")]
    try:
        code, err = _run_cli(capsys, [*argv, "--out", str(scratch / "demo-out")])
    except _ReachedRig:
        return  # a valid truth: the node accepted it
    _assert_clean(code, err, ok=())


@settings(FUZZ, max_examples=50)
@given(data=json_inputs(CALIBRATION))
def test_fuzz_write_params_calibration(
    scratch: Path, capsys: pytest.CaptureFixture[str], data: bytes
) -> None:
    _needs_write_params()
    (scratch / "cal.json").write_bytes(data)
    argv = ["write-params", str(scratch / "cal.json"), "--sim", "--dry-run", "--force"]
    _assert_clean(*_run_cli(capsys, argv))


def _needs_write_params() -> None:
    if "write-params" not in COMMANDS:
        pytest.skip("the write-params verb is not registered yet")
