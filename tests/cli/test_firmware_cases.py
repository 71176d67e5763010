"""Issue 24's four habits of a real CANopenNode firmware, on the in-process simulated node.

The simulated node takes them from its truth JSON (docs/hil.md): ``calibration_store_sub`` /
``documented_store_sub`` (where the calibration is stored, and what 0x2011 says),
``refuses_start`` (EMCY 0x5000 at boot, PRE-OPERATIONAL after every NMT start) and
``second_send_ms`` (TPDO1/2 sent again after each sample). The same cases against the
reference firmware itself run in ``make test-vcan`` (tests/hil/test_vcan_firmware.py).
"""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from canimucal.io.truth import write_truth
from canimucal.runtime.inputs import read_recording
from canimucal.sim.truth import Truth
from tests.cli.test_device_cmds import SERIAL, Cli, calibration_file, make_truth, sim_flags


def _flags(tmp_path: Path, scale: float = 20.0, **behaviour: Any) -> list[str]:
    truth = Truth.from_dict(make_truth().to_dict() | behaviour)
    path = write_truth(tmp_path / "truth.json", truth, overwrite=False)
    return sim_flags(path, tmp_path / "state.json", scale=scale)


def _stored(tmp_path: Path) -> dict[str, str]:
    """What the simulated node's flash holds (its ``--state`` file)."""
    state = tmp_path / "state.json"
    if not state.exists():
        return {}
    objects: dict[str, str] = json.loads(state.read_text())["objects"]
    return objects


def _write(cli: Cli, tmp_path: Path, flags: list[str], *extra: object) -> Any:
    cal = calibration_file(tmp_path, SERIAL)
    return cli(["write-params", cal, *flags, "--backup-dir", tmp_path / "backups", *extra])


# -- case 1: the calibration stored where the node says ---------------------------------------


def test_calibration_is_stored_on_the_sub_index_the_node_names(cli: Cli, tmp_path: Path) -> None:
    # calibration on 0x1010:03; a 'save' on sub 4 answers OK and stores nothing of it
    flags = _flags(tmp_path, calibration_store_sub=3)
    run = _write(cli, tmp_path, flags)
    assert run.code == 0, run.err
    assert "stored (0x1010:03)" in run.out
    assert _stored(tmp_path).get("0x2121:05") == "01"  # in flash, not only in RAM


def test_a_store_sub_the_node_contradicts_is_refused(cli: Cli, tmp_path: Path) -> None:
    flags = _flags(tmp_path, calibration_store_sub=3)
    run = _write(cli, tmp_path, flags, "--store-sub", "4")
    assert run.code == 2
    assert "node 16 stores its calibration with 0x1010:03 (0x2011); nothing written" in run.err
    assert not (tmp_path / "backups").exists()


def test_a_node_that_names_no_sub_index_is_stored_with_sub_1(
    cli: Cli, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    # firmware before issue 24: no 0x2011; sub 4 may be anything, "all parameters" is sure
    flags = _flags(tmp_path, calibration_store_sub=3, documented_store_sub=None)
    run = _write(cli, tmp_path, flags)
    assert run.code == 0, run.err
    assert "stored (0x1010:01)" in run.out and "no 0x2011" in caplog.text
    assert _stored(tmp_path).get("0x2121:05") == "01"


def test_verify_after_restart_reads_back_what_flash_kept(cli: Cli, tmp_path: Path) -> None:
    run = _write(cli, tmp_path, _flags(tmp_path), "--verify-after-restart")
    assert run.code == 0, run.err
    crc = re.search(r"CRC (0x[0-9A-F]{8})", run.out)
    assert crc is not None
    assert f"node 16: verified after a restart: valid, CRC {crc.group(1)}" in run.out


def test_verify_after_restart_catches_a_store_that_kept_nothing(cli: Cli, tmp_path: Path) -> None:
    # a firmware whose 0x2011 is wrong: it names sub 4, the calibration sits on sub 3
    flags = _flags(tmp_path, calibration_store_sub=3, documented_store_sub=4)
    run = _write(cli, tmp_path, flags, "--verify-after-restart")
    assert run.code == 3, run.err
    assert "stored (0x1010:04)" in run.out  # the store itself answered OK
    assert "after a restart node 16 holds valid = 0" in run.err
    assert "the store did not keep it" in run.err


def test_verify_after_restart_needs_a_store(cli: Cli, tmp_path: Path) -> None:
    run = _write(cli, tmp_path, _flags(tmp_path), "--no-store", "--verify-after-restart")
    assert run.code == 2 and "needs a store" in run.err


# -- case 2: a node that refuses to start -----------------------------------------------------


def test_a_node_that_stays_pre_operational_is_named(cli: Cli, tmp_path: Path) -> None:
    flags = _flags(tmp_path, refuses_start=True, heartbeat_ms=200)
    pose = ["--alpha-deg", "0", "--beta-deg", "0", "--seconds", "1", "--no-pose-check"]
    run = cli(["record", tmp_path / "r.csv", "--position", "0", *pose, *flags])
    assert run.code == 3, run.err
    assert "node 16 stays pre-operational after start: error register 0x01 (generic)" in run.err
    assert "the node refuses to start" in run.err and "sent no sample" not in run.err


# -- case 3: duplicate sends ------------------------------------------------------------------


@pytest.mark.parametrize("second_ms", [1.0, 4.0])
def test_duplicate_sends_are_reported_as_such_not_as_skew(
    cli: Cli, tmp_path: Path, caplog: pytest.LogCaptureFixture, second_ms: float
) -> None:
    # TPDO1/2 again 1 ms or 4 ms after each sample (200 Hz: a period is 5 ms), real time
    flags = _flags(tmp_path, scale=1.0, second_send_ms=second_ms)
    pose = ["--alpha-deg", "0", "--beta-deg", "0", "--seconds", "1.5", "--settle-s", "0.3"]
    out = tmp_path / "r.csv"
    run = cli(["record", out, "--position", "0", *pose, "--no-pose-check", *flags])
    assert run.code == 0, run.err
    found = re.search(
        r"(\d+) duplicate, \d+ late, (\d+) duplicate sends; timer skew (.*)$", run.out
    )
    assert found is not None, run.out
    duplicates, sends = int(found.group(1)), int(found.group(2))
    assert sends == duplicates > 300  # every sample twice, both halves
    assert found.group(3).startswith("not measured: the node sends its samples twice")
    assert "sends samples twice" in caplog.text  # the client's warning names the cause
    counter = read_recording(out).counter
    assert np.all(np.mod(np.diff(counter), 65536) == 1)  # nothing twice, nothing lost
