"""The whole job over SocketCAN vcan, node and tool in separate processes (docs/design.md §8).

``canimucal sim --poses P --truth T`` runs the simulated unit; this test, as the operator's
laptop, runs ``record --plan P --follow-schedule``, ``solve``, ``write-params`` and
``read-params --json`` as separate ``python -m canimucal`` processes and checks that the
device ends up holding exactly the solved calibration, and that it agrees with the truth.
Simulated node only: the job needs its pose schedule and truth-driven sensor physics.
"""

from __future__ import annotations

import json
import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from canimucal.device.calibration_map import block_from_record, readback_of
from canimucal.device.od import CalibrationBlock
from canimucal.io.calibration import read_calibration
from canimucal.io.plans import write_plan
from canimucal.io.truth import write_truth
from canimucal.model.positions import Plan
from canimucal.model.vocabulary.plans import builtin_plan
from canimucal.runtime.inputs import read_recording
from canimucal.schema import to_plain
from canimucal.sim.truth import Truth

pytestmark = pytest.mark.vcan

NODE = 0x21
SERIAL = 31337
TRUTH_SEED = 20261121
SECONDS = 5.0
"""Seconds per position: the eight recommended poses in ~47 s of real vcan time."""


def _wrapped(psi: float) -> float:
    """Turn into (-180°, 180°] (plan files allow |psi| ≤ 180°; 270° is -90°)."""
    return float(np.angle(np.exp(1j * psi)))


def test_record_solve_write_read_over_vcan(
    tmp_path: Path, start_sim, run_cli, vcan_channel: str
) -> None:
    rng = np.random.default_rng(TRUTH_SEED)
    truth = Truth.random(rng, cross_axis_max=0.0, serial=SERIAL)
    truth_path = write_truth(tmp_path / "truth.json", truth, overwrite=False)
    plan = builtin_plan("recommended")
    plan = plan.with_total_seconds(SECONDS * len(plan.positions))
    plan = Plan(plan.name, tuple(replace(p, psi=_wrapped(p.psi)) for p in plan.positions))
    poses = write_plan(tmp_path / "poses.json", plan, overwrite=False)
    bus = ["--channel", vcan_channel, "--node-id", str(NODE)]
    sim = start_sim("--node-id", NODE, "--truth", truth_path, "--poses", poses, "--seed", 5)

    out = tmp_path / "session.csv"
    rec = run_cli("record", out, "--plan", poses, "--follow-schedule", "--g", truth.g, *bus)
    assert rec.returncode == 0, rec.stderr + rec.stdout
    print(rec.stdout, rec.stderr)  # the loss counts and any rate warning, for the report (-rP)
    recording = read_recording(out)
    labels, counts = np.unique(recording.position[recording.position >= 0], return_counts=True)
    assert labels.tolist() == list(range(8))
    # each position is (5 s - 2 guards) x 200 Hz = 800 samples; in the emulated VM on a
    # loaded host the receive side loses a share (measured 0-80 % per position, see
    # docs/hil.md): ask for 50, enough for a mean. Losses are counted, never hidden: rows
    # plus counter gaps span the whole stream.
    assert np.all(counts >= 50), counts
    span = int(np.sum(np.mod(np.diff(recording.counter), 65536))) + 1
    found = re.search(r"lost (\d+) samples", rec.stdout)
    assert found is not None and span == recording.n_rows + int(found.group(1))
    assert recording.header["device_serial"] == SERIAL

    cal = tmp_path / "cal.json"
    solved = run_cli("solve", out, "--tilt", "--json", cal)
    assert solved.returncode == 0, solved.stderr
    # the node kept the wall clock: what its host could not send is counted lost above, and
    # the schedule was labelled at the rate it claims (a slowed clock mislabelled it, CI)
    assert "samples arrive at" not in rec.stderr, rec.stderr
    written = run_cli("write-params", cal, *bus, "--backup-dir", tmp_path / "backups")
    assert written.returncode == 0, written.stderr + written.stdout
    assert "backup of the previous calibration" in written.stdout
    readback_path = tmp_path / "readback.json"
    read = run_cli("read-params", *bus, "--json", readback_path)
    assert read.returncode == 0, read.stderr
    assert sim.stop() == 0, "\n".join(sim.lines)

    # the device holds, bit for bit, the block computed from the calibration JSON
    document = json.loads(readback_path.read_text())
    record = read_calibration(cal)
    nominal = document["nominal"]
    block = block_from_record(record, nominal["accel_lsb"], nominal["gyro_lsb"])
    expected = readback_of(CalibrationBlock.from_objects(block.to_objects()), 1, True)
    assert document["readback"] == to_plain(expected)
    assert document["device"]["serial"] == SERIAL

    # and the solved values agree with the truth: 8 parameters within 4σ
    # (P(some |z| > 4) = 1 - (1 - 6.3e-5)^8 ≈ 5e-4 for a correct solver)
    est = np.array([*record.accel.bias, *np.diag(np.array(record.accel.K, dtype=float))])
    sig = np.array(
        [*record.accel.bias_sigma, *np.diag(np.array(record.accel.K_sigma, dtype=float))]
    )
    true = np.concatenate([truth.accel.bias, np.diag(truth.accel.K)])
    assert record.base_tilt_deg is not None and record.base_tilt_deg.sigma is not None
    est = np.append(est, [record.base_tilt_deg.alpha0, record.base_tilt_deg.beta0])
    sig = np.append(sig, record.base_tilt_deg.sigma)
    true = np.append(true, np.rad2deg([truth.alpha0, truth.beta0]))
    z = (est.astype(float) - true) / sig.astype(float)
    assert np.all(np.abs(z) < 4.0), z
