"""Two devices answering as node 16 (issue 25, item 3): every command refuses, exit 4.

The simulated node runs a twin (truth ``faults.twin_serial``): a second ``LocalNode`` with
serial 5555 on the same bus and node-id, its own non-volatile memory beside the first
unit's (``STATE.twin.json``). Nothing may be written to either unit, nothing recorded.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from pathlib import Path

import pytest

from tests.support.calibrations import calibration
from tests.support.cli_run import CliRun

Run = Callable[[Sequence[object]], CliRun]
MESSAGE = "error: two devices answer as node 16 (serials 4242 and 5555): "


@pytest.fixture
def twin_flags(tmp_path: Path) -> list[object]:
    truth = tmp_path / "truth.json"
    truth.write_text(json.dumps({"serial": 4242, "faults": {"twin_serial": 5555}}))
    return ["--sim", "--truth", truth, "--state", tmp_path / "flash.json"]


def test_write_params_writes_nothing_to_either_unit(
    tmp_path: Path, cli: Run, twin_flags: list[object]
) -> None:
    cal = tmp_path / "cal.json"
    cal.write_text(json.dumps(calibration(0.97, -12.0)))
    run = cli(["write-params", cal, "--backup-dir", tmp_path / "backups", *twin_flags])
    assert run.code == 4, run.err
    assert run.err.splitlines()[-1] == MESSAGE + "nothing written"
    assert not (tmp_path / "backups").exists()  # not even a backup: nothing was read for it
    for flash in ("flash.json", "flash.twin.json"):  # neither unit stored anything
        assert not (tmp_path / flash).exists()


def test_read_params_reads_no_mix_of_two_units(cli: Run, twin_flags: list[object]) -> None:
    run = cli(["read-params", *twin_flags])
    assert run.code == 4 and run.out == "", run.err
    assert run.err.splitlines()[-1] == MESSAGE + "their answers would mix; nothing read"


def test_record_records_nothing(tmp_path: Path, cli: Run, twin_flags: list[object]) -> None:
    out = tmp_path / "rec.csv"
    argv = ["record", out, "--position", "0", "--alpha-deg", "0", "--beta-deg", "0"]
    run = cli([*argv, "--seconds", "1", "--no-pose-check", *twin_flags])
    assert run.code == 4, run.err
    assert run.err.splitlines()[-1] == MESSAGE + "nothing recorded"
    assert not out.exists() and not out.with_name("rec.csv.partial").exists()


def test_one_unit_alone_is_read_as_before(cli: Run, tmp_path: Path) -> None:
    truth = tmp_path / "truth.json"
    truth.write_text(json.dumps({"serial": 4242}))
    run = cli(["read-params", "--sim", "--truth", truth])
    assert run.code == 0 and "serial 4242" in run.out, run.err
