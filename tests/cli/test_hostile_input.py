"""No internal error for bad input or a hostile environment (issue 25, items 6–9 and "Smaller").

Each case runs the command in process and expects what docs/design.md §7 says: one line
``error: …`` naming the cause, exit 2 (input) or 3 (the device's own data), never
``internal error`` or a traceback; where the command can go on (NaN on the device, a
negative LSB), it does and says so.
"""

from __future__ import annotations

import json
import logging
import os
import struct
import subprocess
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path

import numpy as np
import pytest

from canimucal.device import od
from tests.cli.conftest import Simulated
from tests.support.cli_run import CliRun

Run = Callable[[Sequence[object]], CliRun]


def one_line_error(run: CliRun, code: int, *fragments: str) -> str:
    """The run failed with ``code`` and one ``error:`` line holding every fragment."""
    lines = [line for line in run.err.splitlines() if line.startswith("error: ")]
    assert run.code == code, (run.code, run.err)
    assert len(lines) == 1 and "internal error" not in run.err, run.err
    assert "Traceback" not in run.err, run.err
    for fragment in fragments:
        assert fragment in lines[0], (fragment, lines[0])
    return lines[0]


def state_file(path: Path, objects: dict[tuple[int, int], bytes]) -> Path:
    """A simulated node's non-volatile memory holding ``objects`` (raw bytes)."""
    doc = {
        "schema": "canimucal.simnode-state/1",
        "objects": {od.format_key(*key): value.hex() for key, value in objects.items()},
    }
    path.write_text(json.dumps(doc))
    return path


# ---------------------------------------------------------------- item 6: NaN on the device


def test_read_params_shows_a_device_holding_nan(tmp_path: Path, cli: Run) -> None:
    nan = struct.pack("<f", float("nan"))
    state = state_file(tmp_path / "nan.json", {(0x2100, 1): nan})
    run = cli(["read-params", "--sim", "--state", state])
    assert run.code == 0, run.err
    assert "accel bias (counts): non-finite, 0, 0" in run.out
    run = cli(["read-params", "--sim", "--state", state, "--json", "-"])
    assert run.code == 0, run.err
    document = json.loads(run.out)
    assert document["readback"]["accel_bias"][0] is None  # JSON has no NaN
    assert document["calibration"]["objects_raw"]["0x2100:01"] == nan.hex()


# ------------------------------------------------------- item 7: a read-only file system


@pytest.fixture
def read_only(tmp_path: Path) -> Iterator[Path]:
    """A directory on a read-only file system (a tmpfs mounted ``ro``; needs root)."""
    where = tmp_path / "ro"
    where.mkdir()
    if os.geteuid() != 0:
        pytest.skip("mounting a read-only file system needs root")
    mounted = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", "ro,size=64k", "tmpfs", str(where)],
        capture_output=True,
        text=True,
    )
    if mounted.returncode != 0:
        pytest.skip(f"cannot mount a read-only tmpfs here: {mounted.stderr.strip()}")
    try:
        yield where
    finally:
        subprocess.run(["umount", str(where)], check=False)


def test_outputs_into_a_read_only_file_system_say_why(
    read_only: Path, cli: Run, simulated: Callable[..., Simulated]
) -> None:
    rec = simulated("five", "diag", 10.0).path
    cases = [
        (["plan", "--plan", "five", "--json", read_only / "plan.json"], read_only / "plan.json"),
        (["solve", rec, "--json", read_only / "cal.json"], read_only / "cal.json"),
        (["analyze", rec, "--truth-out", read_only / "truth.json"], read_only / "truth.json"),
        (["analyze", rec, "--plots", read_only], read_only / "residuals.png"),
    ]
    for argv, target in cases:
        run = cli(argv)
        one_line_error(run, 2, f"cannot write {target}: read-only file system")
    run = cli(["analyze", rec, "--plots", read_only / "plots"])
    one_line_error(run, 2, f"cannot create {read_only / 'plots'}: read-only file system")


# ------------------------------------------- item 8: integers and nesting beyond all reason

HUGE = "9" * 5001
DEEP = "[" * 5000 + "]" * 5000


@pytest.mark.parametrize("verb", ["solve", "tui", "demo"])
@pytest.mark.parametrize(
    ("text", "fragment"),
    [(f"max_bias_sigma_mg = {HUGE}\n", "more than 4300 digits"), (f"x = {DEEP}\n", "nested")],
)
def test_acceptance_limits_with_a_huge_integer_or_deep_arrays(
    tmp_path: Path,
    cli: Run,
    simulated: Callable[..., Simulated],
    monkeypatch: pytest.MonkeyPatch,
    text: str,
    fragment: str,
    verb: str,
) -> None:
    """The shells read the user's limits before anything opens: the TUI never starts on them."""
    config = tmp_path / "config" / "canimucal"
    config.mkdir(parents=True)
    (config / "acceptance.toml").write_text(text)
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "config"))
    argv = {
        "solve": ["solve", simulated("five", "diag", 10.0).path],
        "tui": ["tui", "--sim"],
        "demo": ["demo", "--headless", "--seconds", "2", "--out", tmp_path / "out"],
    }[verb]
    run = cli(argv)
    one_line_error(run, 2, "acceptance.toml", fragment)


@pytest.mark.parametrize("text", [f'x = "forward"\ny = {HUGE}\n', f"x = {DEEP}\n"])
def test_a_mounting_map_with_a_huge_integer_or_deep_arrays(
    tmp_path: Path, cli: Run, monkeypatch: pytest.MonkeyPatch, text: str
) -> None:
    mounting = tmp_path / "config" / "canimucal" / "mounting"
    mounting.mkdir(parents=True)
    (mounting / "777.toml").write_text(text)
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "config"))
    truth = tmp_path / "truth.json"
    truth.write_text(json.dumps({"serial": 777}))
    out = tmp_path / "out"
    run = cli(["demo", "--headless", "--plan", "vehicle", "--truth", truth, "--out", out])
    one_line_error(run, 2, "777.toml")


def test_an_imucal_section_list_nested_deep(tmp_path: Path, cli: Run) -> None:
    data = tmp_path / "session.csv"
    data.write_text("n_samples,gyr_x,gyr_y,gyr_z,acc_x,acc_y,acc_z\n0,0,0,0,0,0,9.8\n")
    sections = tmp_path / "sections.json"
    sections.write_text('{"x": ' + "[" * 5000 + "]" * 5000 + "}")
    argv = ["analyze", data, sections, "--format", "imucal", "--sample-rate-hz", "100"]
    one_line_error(cli(argv), 2, "sections.json", "nested")


# -------------------------------------------- item 9: repeated rows, a time column standing


def _rows_twice(src: Path, dst: Path, *, constant_t: bool = False) -> Path:
    lines = src.read_text().splitlines(keepends=True)
    head = [line for line in lines if not line[:1].isdigit()]
    body = [line for line in lines if line[:1].isdigit()]
    if constant_t:
        body = ["5.0" + line[line.index(",") :] for line in body]
    else:
        body = [line for line in body for _ in (0, 1)]
    dst.write_text("".join(head + body))
    return dst


@pytest.mark.parametrize("constant_t", [False, True], ids=["rows-twice", "constant-t"])
@pytest.mark.parametrize("command", ["analyze", "allan"])
def test_repeated_rows_or_a_standing_time_column(
    tmp_path: Path,
    cli: Run,
    simulated: Callable[..., Simulated],
    command: str,
    constant_t: bool,
) -> None:
    path = _rows_twice(
        simulated("five", "diag", 10.0).path, tmp_path / "bad.csv", constant_t=constant_t
    )
    one_line_error(cli([command, path]), 2, "bad.csv: t does not advance")


# ------------------------------------------------------------------------------- smaller


def _prior(tmp_path: Path, k: np.ndarray) -> Path:
    path = tmp_path / "prior.json"
    doc = {
        "schema": "canimucal.calibration/1",
        "plan": "five",
        "device": {"node_id": 16, "serial": 4242},
        "accel": {"bias": [0.0, 0.0, 0.0], "K": k.tolist()},
    }
    path.write_text(json.dumps(doc))
    return path


@pytest.mark.parametrize(
    ("k", "fragment"),
    [
        (np.array([[208.8, 0, 0], [208.8, 0, 0], [0, 0, 208.8]]), "singular"),
        (np.diag([208.8, -208.8, 208.8]), "mirrored"),
        (np.array([[0, 208.8, 0], [208.8, 0, 0], [0, 0, 208.8]]), "mirrored"),
    ],
    ids=["singular", "one-axis-negated", "axes-swapped"],
)
def test_a_prior_k_that_is_singular_or_mirrored_is_refused(
    tmp_path: Path,
    cli: Run,
    simulated: Callable[..., Simulated],
    k: np.ndarray,
    fragment: str,
) -> None:
    prior = _prior(tmp_path, k)
    rec = simulated("five", "diag", 10.0).path
    one_line_error(cli(["solve", rec, "--prior-k", prior]), 2, fragment)
    one_line_error(cli(["tui", "--sim", "--prior-k", prior]), 2, fragment)  # before the TUI


def test_a_prior_k_for_a_unit_with_a_negative_lsb_is_taken(
    tmp_path: Path, cli: Run, simulated: Callable[..., Simulated]
) -> None:
    prior = _prior(tmp_path, np.diag([-208.8, -209.1, -208.5]))  # all one sign: not a mirror
    run = cli(["solve", simulated("five", "diag", 10.0).path, "--prior-k", prior])
    assert run.code in (0, 3) and "internal error" not in run.err, run.err  # 3: acceptance


def test_a_tpdo_on_the_nodes_own_sdo_answer_id_is_refused_and_leaves_no_file(
    tmp_path: Path, cli: Run
) -> None:
    cob = od.encode("u32", 0x580 + 16)
    state = state_file(tmp_path / "state.json", {(od.TPDO_COMM[0], 1): cob})
    out = tmp_path / "rec.csv"
    argv = ["record", out, "--sim", "--state", state, "--position", "0"]
    argv += ["--alpha-deg", "0", "--beta-deg", "0", "--seconds", "1", "--no-pose-check"]
    run = cli(argv)
    one_line_error(run, 3, "TPDO1 has COB-ID 0x590", "SDO answers")
    assert "wrote" not in run.out
    assert sorted(p.name for p in tmp_path.iterdir()) == ["state.json"]  # no header-only CSV


def test_a_negative_device_lsb_is_said_and_a_nan_one_refused(
    tmp_path: Path, cli: Run, caplog: pytest.LogCaptureFixture
) -> None:
    truth = tmp_path / "truth.json"
    truth.write_text(json.dumps({"accel": {"nominal_lsb": -9.80665 / 2048}}))
    with caplog.at_level(logging.WARNING):
        run = cli(["read-params", "--sim", "--truth", truth])
    assert run.code == 0, run.err
    told = [r.getMessage() for r in caplog.records if "negative nominal accel LSB" in r.message]
    assert len(told) == 1, told  # once per node, not at every read
    state = state_file(tmp_path / "nan.json", {(od.NOMINAL, 1): struct.pack("<f", np.nan)})
    one_line_error(cli(["read-params", "--sim", "--state", state]), 3, "nominal accel LSB of nan")


def test_a_flood_of_emergencies_is_counted_not_logged_frame_by_frame(
    tmp_path: Path, cli: Run, caplog: pytest.LogCaptureFixture
) -> None:
    truth = tmp_path / "truth.json"
    emcy = [{"at_s": 0.0, "code": 0x5000, "register": 1}] * 8000
    truth.write_text(json.dumps({"faults": {"emergency": emcy}}))
    with caplog.at_level(logging.WARNING):
        run = cli(["read-params", "--sim", "--truth", truth])
    assert run.code == 0, run.err
    lines = [r.getMessage() for r in caplog.records if "EMCY" in r.message]
    lines += [r.getMessage() for r in caplog.records if "emergency" in r.message]
    assert 2 <= len(lines) <= 2 * (2 + 8), lines  # 1st, 10th, every 1000th; node and client
    assert any("8000" in line for line in lines), lines  # the count reaches the log
