"""`record --plan vehicle` records the K the node applies; `solve` holds it (docs/design.md §3)."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from canimucal.io.calibration import read_calibration
from canimucal.io.recording import header_matrix
from canimucal.io.truth import write_truth
from canimucal.model.sensor import DEFAULT_ACCEL_LSB
from canimucal.runtime.inputs import read_recording
from canimucal.sim.truth import Truth
from tests.support.device_state import state_file

Cli = Callable[[Sequence[Any]], Any]  # conftest.cli: argv -> CliRun(code, out, err)


def test_a_recorded_vehicle_plan_carries_the_device_k_into_solve(cli: Cli, tmp_path: Path) -> None:
    truth = Truth.random(np.random.default_rng(31), cross_axis_max=0.0, tilt_max_deg=0.3)
    truth_path = write_truth(tmp_path / "truth.json", truth, overwrite=False)
    factory = np.asarray(truth.accel.K) * 1.003
    state = state_file(tmp_path / "state.json", np.linalg.inv(factory))
    flags = ["--sim", "--truth", truth_path, "--state", state, "--time-scale", "25"]
    out = tmp_path / "vehicle.csv"
    run = cli(["record", out, "--plan", "vehicle", "--seconds", "2", *flags])
    assert run.code == 0, run.err
    header = read_recording(out).header
    held = np.linalg.inv(np.float32(np.linalg.inv(factory)).astype(float))  # M as REAL32
    np.testing.assert_allclose(header_matrix(header["prior_k"]), held, rtol=1e-12)
    assert header["prior_k_sigma"] == 0.01 and "0x2101" in str(header["prior_k_source"])
    cal = tmp_path / "cal.json"
    run = cli(["solve", out, "--no-check", "--json", cal])
    assert run.code == 0, run.err
    priors = {p.name: p for p in read_calibration(cal).priors or ()}
    assert priors["accel.K[1][1]"].mean == header_matrix(header["prior_k"])[1, 1]
    assert priors["accel.K[1][1]"].sigma == pytest.approx(0.01 / DEFAULT_ACCEL_LSB)
    assert "node 16's 0x2101" in priors["accel.K[1][1]"].source
    assert "held at the stated prior (K = M⁻¹ read from node 16's 0x2101" in run.err
