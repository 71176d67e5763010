"""`record` against planted symlinks and a full disk (issue 13, failures 8 and 9)."""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from pathlib import Path

import pytest

from canimucal.io import recording_writer
from canimucal.io.truth import write_truth
from canimucal.runtime.inputs import read_recording
from tests.cli.test_device_cmds import make_truth, sim_flags
from tests.io.test_file_faults import full_disk_after
from tests.support.cli_run import CliRun

Cli = Callable[[Sequence[str]], CliRun]
POSE = ["--position", "0", "--alpha-deg", "0", "--beta-deg", "0", "--seconds", "2"]


@pytest.fixture
def flags(tmp_path: Path) -> list[str]:
    truth = write_truth(tmp_path / "truth.json", make_truth(), overwrite=False)
    return sim_flags(truth, tmp_path / "state.json", scale=20.0)


def test_record_overwrite_never_writes_through_a_planted_symlink(
    cli: Cli, tmp_path: Path, flags: list[str]
) -> None:
    victim = tmp_path / "victim.txt"
    victim.write_text("precious\n")
    out = tmp_path / "out.csv"
    out.write_text("old\n")
    os.symlink(victim, tmp_path / "out.csv.partial")
    run = cli(["record", out, *POSE, "--overwrite", *flags])
    assert run.code == 2, run.err
    assert "not a regular file" in run.err and "Traceback" not in run.err
    assert victim.read_text() == "precious\n" and out.read_text() == "old\n"


def test_record_on_a_full_disk_keeps_the_partial_and_exits_2(
    cli: Cli, tmp_path: Path, flags: list[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    out = tmp_path / "out.csv"
    monkeypatch.setattr(recording_writer.os, "write", full_disk_after(20_000))
    run = cli(["record", out, *POSE, *flags])
    monkeypatch.undo()
    assert run.code == 2, run.err
    assert not out.exists() and "wrote" not in run.out
    kept = read_recording(tmp_path / "out.csv.partial")
    assert f"error: disk full writing {out}; {kept.n_rows} rows kept in {out}.partial" in run.err
    assert 0 < kept.n_rows < 400
