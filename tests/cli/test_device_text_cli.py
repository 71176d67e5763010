"""`read-params` against a node presenting a hostile identity (issue 13, failure 6)."""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import pytest

from canimucal.io.truth import write_truth
from canimucal.sim.truth import Truth
from canimucal.untrusted import printable
from tests.device.test_device_text import CONTROL, HOSTILE


def _truth(tmp_path: Path, **identity: str) -> Path:
    d = Truth().to_dict() | {"serial": 4242} | identity
    return write_truth(tmp_path / "truth.json", Truth.from_dict(d), overwrite=False)


def _read_params(cli: Callable[[Sequence[str]], Any], truth: Path, tmp_path: Path) -> Any:
    flags = ["--sim", "--truth", truth, "--state", tmp_path / "state.json"]
    return cli(["read-params", *flags, "--json", tmp_path / "r.json"])


def test_read_params_shows_hostile_identity_escaped(
    cli: Callable[[Sequence[str]], Any], tmp_path: Path
) -> None:
    truth = _truth(
        tmp_path, device_name=HOSTILE, hardware_version="\x1b[31mred", software_version="2.0"
    )
    run = _read_params(cli, truth, tmp_path)
    assert run.code == 0, run.err
    assert not any(CONTROL.search(line) for line in run.out.splitlines()), run.out
    assert not any(line.startswith("node 16: FAKE") for line in run.out.splitlines())
    assert run.out.count("serial 4242") == 1 and "hardware \\x1b[31mred, software 2.0" in run.out
    device = json.loads((tmp_path / "r.json").read_text())["device"]
    assert device["device_name"] == printable(HOSTILE) and device["software_version"] == "2.0"


def test_ten_megabyte_name_is_cut_at_256_bytes_and_aborted(
    cli: Callable[[Sequence[str]], Any], tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    truth = _truth(tmp_path, device_name="N" * 10_000_000)
    started = time.monotonic()
    run = _read_params(cli, truth, tmp_path)
    elapsed = time.monotonic() - started
    assert run.code == 0, run.err
    device = json.loads((tmp_path / "r.json").read_text())["device"]
    assert device["device_name"] == "N" * 256 + "…"
    assert "0x1008:00 is longer than 256 bytes: upload aborted" in caplog.text
    assert elapsed < 30.0  # was 150 s and 330 MiB for the whole upload
