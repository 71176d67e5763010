"""The guided session fits the gyro's S to the moves it confirmed and writes S⁻¹ to the node.

The simulated unit's S is off nominal (scales ±3 %, cross-axis ±1 %) and it has a
g-sensitivity G; the session estimates G from its static positions and S from its moves
with ``G f`` removed, writes S⁻¹ (0x2111) and G (0x2112), and reads both back.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from canimucal.device.calibration_map import block_from_record
from canimucal.io.calibration import read_calibration
from canimucal.model.sensor import DEFAULT_ACCEL_LSB, DEFAULT_GYRO_LSB
from canimucal.procedure.averaging import AveragingPolicy
from canimucal.runtime.operator import run_automatic
from canimucal.runtime.readback_check import readback_deviations
from canimucal.runtime.wiring import demo_settings, open_devices
from canimucal.sim.truth import Truth
from tests.support.moves import turns_plan


def test_the_session_recovers_an_off_nominal_s_from_its_moves_and_reads_it_back(
    tmp_path: Path,
) -> None:
    truth = Truth.random(
        np.random.default_rng(5),
        scale_error_max=0.03,
        cross_axis_max=0.01,
        tilt_max_deg=0.0,
        gyro_g_max=0.5,
    )
    nominal = np.eye(3) / DEFAULT_GYRO_LSB
    rel = (truth.gyro.S - nominal) / np.diag(nominal)
    assert (
        np.max(np.abs(np.diag(rel))) > 0.01 and np.max(np.abs(rel - np.diag(np.diag(rel)))) > 0.002
    )
    with open_devices(demo_settings([truth], time_scale=30.0, seed=5)) as rig:
        session = rig.session(
            turns_plan(seconds=3.0),
            tmp_path,
            plan_name="custom",
            gyro_g=True,
            warmup=False,
            averaging=AveragingPolicy(fixed_s=3.0),
            verify_seconds=2.0,
        )
        run_automatic(session, write_anyway=True)
        truth = rig.truths[0x10]
    path = tmp_path / "calibration.json"
    raw = json.loads(path.read_text())
    S = np.array(raw["gyro"]["S"], dtype=float)
    sigma = np.array(raw["gyro"]["S_sigma"], dtype=float)
    assert np.all(np.isfinite(S)), "every column of S is identifiable from the turns plan"
    z = (S - truth.gyro.S) / sigma
    assert np.max(np.abs(z)) < 4.0, z
    assert np.max(sigma / np.abs(np.diag(nominal))) < 0.005  # the moves pin S to < 0.5 %
    # the device holds S⁻¹ of exactly this S (float32), read back
    record = read_calibration(path)
    written = block_from_record(record, DEFAULT_ACCEL_LSB, DEFAULT_GYRO_LSB)
    back = np.array(raw["readback"]["gyro_correction"], dtype=float)
    np.testing.assert_array_equal(
        back.astype(np.float32), written.gyro_correction.astype(np.float32)
    )
    deviations = {d.name: d for d in readback_deviations(raw, truth)}
    assert all(f"gyro.S[{i}][{j}]" in deviations for i in range(3) for j in range(3))
    assert all(f"gyro.G[{i}][{j}]" in deviations for i in range(3) for j in range(3))
    np.testing.assert_array_equal(
        np.array(raw["readback"]["gyro_g"], dtype=np.float32), written.gyro_g.astype(np.float32)
    )
    assert max(abs(d.dev_sigma) for d in deviations.values()) < 4.0
