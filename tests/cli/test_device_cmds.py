"""The device verbs against the in-process simulated IMU (``--sim``, python-can virtual bus).

Each test runs ``canimucal`` in-process. The simulated node's non-volatile memory is a
``--state`` file, so what ``write-params`` stores is what the next command's node boots with.
Recordings run with ``--time-scale`` so a plan of a few simulated minutes takes seconds.
"""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time as time_module
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from canimucal.cli.read_params_cmd import SCHEMA as READ_SCHEMA
from canimucal.cli.record_cmd import report
from canimucal.device import od
from canimucal.device.calibration_map import block_from_record, readback_of
from canimucal.io.calibration import read_calibration
from canimucal.io.truth import write_truth
from canimucal.runtime.inputs import read_recording
from canimucal.runtime.recorder import NodeTally
from canimucal.schema import to_plain
from canimucal.sim.truth import Truth
from tests.support.moves import TURN_POSES_DEG

Cli = Callable[[list[Any]], Any]  # the ``cli`` fixture of tests/cli/conftest.py
SERIAL = 4242
TRUTH_SEED = 20261121


def make_truth() -> Truth:
    """Seeded random unit: no cross-axis terms, base tilt within ±1°, serial 4242."""
    d = Truth.random(np.random.default_rng(TRUTH_SEED), cross_axis_max=0.0).to_dict()
    d["serial"] = SERIAL
    return Truth.from_dict(d)


@pytest.fixture
def truth_file(tmp_path: Path) -> Path:
    """A diagonal-K truth (seeded) with base tilt, serial 4242, written to a file."""
    return write_truth(tmp_path / "truth.json", make_truth(), overwrite=False)


def sim_flags(truth: Path, state: Path, scale: float = 20.0) -> list[str]:
    return ["--sim", "--truth", str(truth), "--state", str(state), "--time-scale", str(scale)]


def read_params(cli: Cli, flags: list[str], out: Path) -> dict[str, Any]:
    run = cli(["read-params", *flags, "--json", out, "--overwrite"])
    assert run.code == 0, run.err
    document: dict[str, Any] = json.loads(out.read_text())
    return document


def calibration_file(tmp_path: Path, serial: int, k_scale: float = 1.0) -> Path:
    """A small calibration JSON: biases, K (nominal × per-axis factors × ``k_scale``), tilt."""
    k = np.diag(np.array([1.01, 0.99, 1.002]) * k_scale / od.to_float32(9.80665 / 2048.0))
    document = {
        "schema": "canimucal.calibration/1",
        "plan": "five",
        "device": {"serial": serial},
        "accel": {"bias": [3.0, -2.5, 1.25], "K": k.tolist()},
        "gyro": {"bias": [0.5, -0.25, 2.0]},
        "base_tilt_deg": {"alpha0": 0.2, "beta0": -0.1},
    }
    path = tmp_path / f"cal_{serial}_{k_scale:g}.json"
    path.write_text(json.dumps(document))
    return path


def test_read_params_json(cli: Cli, tmp_path: Path, truth_file: Path) -> None:
    doc = read_params(cli, sim_flags(truth_file, tmp_path / "s.json"), tmp_path / "r.json")
    assert doc["schema"] == READ_SCHEMA
    assert doc["device"]["serial"] == SERIAL and doc["device"]["node_id"] == 16
    assert doc["nominal"]["output_data_rate_hz"] == 200
    factory = od.factory_block(doc["nominal"]["accel_lsb"], doc["nominal"]["gyro_lsb"])
    assert doc["readback"] == to_plain(readback_of(factory, 0, True))  # factory: valid 0, CRC ok
    assert set(doc["calibration"]["objects"]) == {
        od.format_key(i, s) for i, s, _ in od.CALIBRATION_OBJECTS
    }
    read_calibration(json.dumps(doc["calibration"]))  # a valid calibration JSON (a backup)


def test_write_params_cycle_and_restore(cli: Cli, tmp_path: Path, truth_file: Path) -> None:
    flags = sim_flags(truth_file, tmp_path / "state.json")
    before = read_params(cli, flags, tmp_path / "before.json")
    cal = calibration_file(tmp_path, SERIAL)
    run = cli(["write-params", cal, *flags, "--backup-dir", tmp_path / "bk"])
    assert run.code == 0, run.err
    backups = list((tmp_path / "bk").glob(f"{SERIAL}-*.json"))
    assert len(backups) == 1 and str(backups[0]) in run.out
    # a new process (node booted from its state file) holds exactly the block of the file
    after = read_params(cli, flags, tmp_path / "after.json")
    nominal = after["nominal"]
    block = block_from_record(read_calibration(cal), nominal["accel_lsb"], nominal["gyro_lsb"])
    expected = readback_of(od.CalibrationBlock.from_objects(block.to_objects()), 1, True)
    assert after["readback"] == to_plain(expected)
    # the backup restores the factory block bit-exactly
    run = cli(["write-params", backups[0], *flags, "--backup-dir", tmp_path / "bk"])
    assert run.code == 0, run.err
    restored = read_params(cli, flags, tmp_path / "restored.json")
    assert restored["calibration"]["objects"] == before["calibration"]["objects"]
    assert restored["readback"] == before["readback"]


def test_dry_run_writes_nothing(cli: Cli, tmp_path: Path, truth_file: Path) -> None:
    state = tmp_path / "state.json"
    flags = sim_flags(truth_file, state)
    cal = calibration_file(tmp_path, SERIAL)
    run = cli(["write-params", cal, *flags, "--dry-run", "--backup-dir", tmp_path / "bk"])
    assert run.code == 0, run.err
    assert "0x2121:05" in run.out and "nothing written" in run.out
    assert not (tmp_path / "bk").exists() and not state.exists()
    assert read_params(cli, flags, tmp_path / "r.json")["readback"]["valid"] == 0


def test_bad_file_exit_2_before_connecting(cli: Cli, tmp_path: Path) -> None:
    bad = tmp_path / "bad.json"
    bad.write_text('{"schema": "canimucal.calibration/1", "device": {"serial": 1}, "accel": {}}')
    # this bus cannot be opened here (exit 4 if the command got that far)
    bus = ["--interface", "virtual-nonexistent", "--channel", "x"]
    run = cli(["write-params", bad, *bus])
    assert run.code == 2 and run.err.startswith("error: ") and "accel" in run.err
    extra = tmp_path / "extra.json"
    extra.write_text(json.dumps({**json.loads(calibration_file(tmp_path, 1).read_text()), "x": 1}))
    assert cli(["write-params", extra, *bus]).code == 2
    assert cli(["write-params", tmp_path / "missing.json", *bus]).code == 2
    assert cli(["read-params", *bus]).code in (2, 4)  # the bus itself: usage or no bus


def test_out_of_range_exit_2_nothing_written(cli: Cli, tmp_path: Path, truth_file: Path) -> None:
    state = tmp_path / "state.json"
    flags = sim_flags(truth_file, state)
    cal = calibration_file(tmp_path, SERIAL, k_scale=3.0)  # M at 1/3 of nominal: outside ±50 %
    run = cli(["write-params", cal, *flags, "--backup-dir", tmp_path / "bk"])
    assert run.code == 2 and "range" in run.err
    assert not (tmp_path / "bk").exists() and not state.exists()


def test_serial_mismatch_exit_3_unless_forced(cli: Cli, tmp_path: Path, truth_file: Path) -> None:
    flags = sim_flags(truth_file, tmp_path / "state.json")
    cal = calibration_file(tmp_path, SERIAL + 1)
    run = cli(["write-params", cal, *flags, "--backup-dir", tmp_path / "bk"])
    assert run.code == 3 and "serial" in run.err
    assert read_params(cli, flags, tmp_path / "r.json")["readback"]["valid"] == 0
    run = cli(["write-params", cal, *flags, "--backup-dir", tmp_path / "bk", "--force"])
    assert run.code == 0, run.err
    assert read_params(cli, flags, tmp_path / "r.json")["readback"]["valid"] == 1


def test_record_single_position_and_append(cli: Cli, tmp_path: Path, truth_file: Path) -> None:
    flags = sim_flags(truth_file, tmp_path / "state.json", scale=10.0)
    out = tmp_path / "one.csv"
    pos = ["--alpha-deg", "22.5", "--beta-deg", "2.5", "--seconds", "2"]
    run = cli(["record", out, "--position", "0", *pos, *flags])
    assert run.code == 0, run.err
    run = cli(["record", out, "--position", "1", *pos[:3], "0", *pos[4:], "--append", *flags])
    assert run.code == 0, run.err
    rec = read_recording(out)
    assert rec.header["device_serial"] == SERIAL and rec.header["sample_rate_hz"] == 200.0
    for index, beta in ((0, 2.5), (1, 0.0)):
        rows = rec.position == index
        assert rows.sum() == 400  # 2 s at 200 Hz, labelled after the settle time
        assert np.all(rec.alpha_deg[rows] == 22.5) and np.all(rec.beta_deg[rows] == beta)
        step = np.diff(rec.counter[rows]) % 65536
        assert np.all(step == 1)  # consecutive counters: nothing lost on the virtual bus
    assert np.all(np.diff(rec.t) >= 0)
    # a position recorded again without --append or --overwrite: refused, exit 2
    assert cli(["record", out, "--position", "2", *pos, *flags]).code == 2


def test_record_gyro_g_names_g_in_the_header_for_solve(
    cli: Cli, tmp_path: Path, truth_file: Path
) -> None:
    flags = sim_flags(truth_file, tmp_path / "state.json", scale=10.0)
    pos = ["--position", "0", "--alpha-deg", "0", "--beta-deg", "0", "--seconds", "1"]
    for name, extra in (("g.csv", ["--gyro-g"]), ("plain.csv", [])):
        run = cli(["record", tmp_path / name, *pos, *extra, *flags])
        assert run.code == 0, run.err
    assert read_recording(tmp_path / "g.csv").header["gyro_g"] is True
    assert "gyro_g" not in read_recording(tmp_path / "plain.csv").header


@pytest.mark.parametrize("skew_ppm", [5000.0, -5000.0])
def test_record_reports_the_timer_skew_per_node(cli: Cli, tmp_path: Path, skew_ppm: float) -> None:
    # an event timer 0.5 % off the sample clock, in real time (a scaled clock has no skew to
    # measure): slow skips counters (lost samples), fast re-sends them (duplicates)
    truth = make_truth().to_dict() | {"timer_skew_ppm": skew_ppm}
    path = write_truth(tmp_path / "skew.json", Truth.from_dict(truth), overwrite=False)
    flags = sim_flags(path, tmp_path / "state.json", scale=1.0)
    pose = ["--alpha-deg", "0", "--beta-deg", "0", "--seconds", "1.5", "--settle-s", "0.3"]
    run = cli(["record", tmp_path / "r.csv", "--position", "0", *pose, *flags])
    assert run.code == 0, run.err
    found = re.search(r"node 16: wrote .*; (\d+) duplicate.*; timer skew ([+-]\d+) ppm$", run.out)
    assert found is not None, run.out
    duplicates, skew = int(found.group(1)), float(found.group(2))
    assert abs(skew - skew_ppm) < 2500, run.out  # resolution: 10⁶ / ~400 intervals
    lost = int(re.search(r"lost (\d+) samples", run.out).group(1))  # type: ignore[union-attr]
    assert (lost > 0, duplicates > 0) == (skew_ppm > 0, skew_ppm < 0), run.out


def test_record_summary_says_when_the_skew_was_not_measured(tmp_path: Path) -> None:
    tallies = [NodeTally(16, rows=150), NodeTally(17, rows=900, skew_ppm=-12.4)]
    lines = report(tallies, [tmp_path / "a.csv", tmp_path / "b.csv"]).splitlines()
    assert lines[0].startswith("node 16: wrote 150 rows") and lines[0].endswith("not measured")
    assert lines[1].startswith("node 17: wrote 900 rows") and lines[1].endswith("skew -12 ppm")


def test_record_plan_then_solve(cli: Cli, tmp_path: Path, truth_file: Path) -> None:
    flags = sim_flags(truth_file, tmp_path / "state.json", scale=25.0)
    out = tmp_path / "plan.csv"
    run = cli(["record", out, "--plan", "recommended", "--seconds", "8", *flags])
    assert run.code == 0, run.err
    lost = re.search(
        r"lost (\d+) samples, (\d+) accel and (\d+) gyro halves; (\d+) dup\w+, (\d+) late", run.out
    )
    assert lost is not None, run.out
    samples, accel, gyro, duplicates, late = map(int, lost.groups())
    # the virtual bus drops nothing: no sample lost outright; a half given up by the pairer
    # (a thread starved past its 0.25 s grace on a loaded machine) must have arrived late
    assert samples == duplicates == 0 and accel + gyro == late, run.out
    rec = read_recording(out)
    assert sorted(set(rec.position.tolist()) - {-1}) == list(range(8))
    cal = tmp_path / "cal.json"
    run = cli(["solve", out, "--tilt", "--json", cal])
    assert run.code == 0, run.err
    record = read_calibration(cal)
    truth = Truth.from_dict(json.loads(truth_file.read_text()))
    assert record.device.serial == SERIAL
    est = np.array(record.accel.bias + tuple(np.diag(np.array(record.accel.K))), dtype=float)
    sig = np.array(
        record.accel.bias_sigma + tuple(np.diag(np.array(record.accel.K_sigma))), dtype=float
    )
    true = np.concatenate([truth.accel.bias, np.diag(truth.accel.K)])
    # 6 parameters within 4σ: P(any beyond | Gaussian) = 1 - (1 - 6.3e-5)^6 ≈ 4e-4 per run
    assert np.all(np.abs(est - true) < 4 * sig), (est - true) / sig


def test_sim_runs_until_sigterm(tmp_path: Path, truth_file: Path) -> None:
    plan = tmp_path / "poses.json"
    plan.write_text('{"positions": [{"alpha_deg": 0, "beta_deg": 0, "seconds": 2}]}')
    cmd = [sys.executable, "-m", "canimucal", "sim", "--interface", "virtual", "--channel"]
    cmd += [f"canimucal-simcmd-{os.getpid()}", "--truth", str(truth_file), "--poses", str(plan)]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline()  # blocks until the ready line (or exit)
        assert line.startswith("ready: ") and f"serial {SERIAL}" in line, line
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=20) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def test_several_nodes_one_output_each(cli: Cli, tmp_path: Path, truth_file: Path) -> None:
    flags = sim_flags(truth_file, tmp_path / "state.json", scale=10.0)
    run = cli(["read-params", *flags, "--node-id", "16", "--node-id", "0x11", "--json", "-"])
    assert run.code == 2 and "--json -" in run.err  # several nodes need a file name
    out = tmp_path / "r.json"
    run = cli(["read-params", *flags, "--node-id", "16", "--node-id", "0x11", "--json", out])
    assert run.code == 0, run.err
    for node in (16, 17):
        doc = json.loads((tmp_path / f"r.node{node}.json").read_text())
        assert doc["device"]["node_id"] == node
    assert not out.exists()
    rec = tmp_path / "two.csv"
    pos = ["--position", "0", "--alpha-deg", "0", "--beta-deg", "0", "--seconds", "1"]
    run = cli(["record", rec, *pos, *flags, "--node-id", "16", "--node-id", "17"])
    assert run.code == 0, run.err
    for node in (16, 17):
        recording = read_recording(tmp_path / f"two.node{node}.csv")
        assert recording.header["node_id"] == node and np.sum(recording.position == 0) == 200


def test_record_defaults_match_the_simulated_node() -> None:
    from canimucal.cli import record_cmd
    from canimucal.runtime.recorder import DEFAULT_GUARD_S
    from canimucal.simnode.node import POSE_TRANSIENT_S

    assert record_cmd.POSE_TRANSIENT_S == POSE_TRANSIENT_S
    assert record_cmd.GUARD_S == DEFAULT_GUARD_S


def test_device_verbs_load_the_can_stack_only_when_run() -> None:
    mods = ", ".join(f"canimucal.cli.{m}" for m in ("sim_cmd", "read_params_cmd", "record_cmd"))
    probe = (
        f"import sys, {mods}, canimucal.cli.write_params_cmd, canimucal.cli.bus_options\n"
        "print(sorted({m.split('.')[0] for m in sys.modules} & {'can', 'canopen', 'textual'}))"
    )
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True)
    assert out.stdout.strip().splitlines()[-1] == "[]"


def test_recorder_prompted_plan_follows_the_operator(tmp_path: Path) -> None:
    """The prompt path of ``record --plan`` (no --sim): the callback moves the simulated unit."""
    import can

    from canimucal.device.client import ImuClient
    from canimucal.io.recording_writer import RecordingWriter
    from canimucal.model.vocabulary.plans import builtin_plan
    from canimucal.runtime.recorder import Recorder
    from canimucal.simnode.node import SimulatedImuNode

    channel = f"canimucal-prompt-{os.getpid()}"
    node_bus, client_bus = (can.Bus(interface="virtual", channel=channel) for _ in range(2))
    node = SimulatedImuNode(node_bus, 0x10, make_truth(), time_scale=10.0, seed=3).start()
    plan = builtin_plan("two").with_total_seconds(2.0)
    prompts: list[int] = []

    def prompt(index: int, position: Any) -> None:
        prompts.append(index)
        node.set_pose(position.alpha, position.beta, position.psi)

    out = tmp_path / "prompted.csv"
    try:
        with ImuClient(client_bus, 0x10) as client:
            header = {"sample_rate_hz": 200.0, "device_serial": SERIAL}
            with RecordingWriter.open(out, header) as writer:
                recorder = Recorder([(client, writer, 200.0)])
                recorder.start()
                try:
                    recorder.record_prompted(plan, prompt, settle_s=1.5)
                finally:
                    recorder.stop()
    finally:
        node.stop()
        node_bus.shutdown()
        client_bus.shutdown()
    assert prompts == [0, 1]
    rec = read_recording(out)
    for index, position in enumerate(plan.positions):
        rows = rec.position == index
        assert rows.sum() == 200
        assert np.allclose(rec.alpha_deg[rows], np.rad2deg(position.alpha))
        # settled: the labelled samples sit at the pose (x accel ≈ K f of that pose, not moving)
        assert np.ptp(np.nanmean(rec.accel[rows].reshape(4, 50, 3), axis=1)[:, 0]) < 10.0


def _default_sigint() -> None:
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def test_record_interrupted_keeps_what_was_recorded(tmp_path: Path) -> None:
    out = tmp_path / "cut.csv"
    # -X faulthandler: if Ctrl-C ever hangs, SIGABRT makes the child print every thread's stack
    cmd = [sys.executable, "-X", "faulthandler", "-m", "canimucal", "record", str(out), "--sim"]
    proc = subprocess.Popen(
        [*cmd, "--plan", "five"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        # a shell without job control starts background jobs with SIGINT ignored, and the
        # child would inherit that (pytest run as `... &`): give it the terminal's default
        preexec_fn=_default_sigint,
    )
    partial = tmp_path / "cut.csv.partial"
    try:
        for _ in range(300):  # until rows are being written (≤ 30 s)
            if partial.exists() and partial.stat().st_size > 10_000:
                break
            time_module.sleep(0.1)
        proc.send_signal(signal.SIGINT)
        try:
            _, err = proc.communicate(timeout=30)
        except subprocess.TimeoutExpired:
            proc.send_signal(signal.SIGABRT)
            _, err = proc.communicate(timeout=10)
            pytest.fail(f"record did not stop within 30 s of Ctrl-C; its threads:\n{err}")
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 130, err
    assert out.exists() and not partial.exists()
    assert read_recording(out).n_rows > 100


def test_hidden_gyro_s_recovered_through_the_canopen_path(cli: Cli, tmp_path: Path) -> None:
    """The simulated node's S off nominal (scales ±3 %, cross-axis ±1 %): the turns plan
    recorded over the bus, ``solve --gyro moves``, then S⁻¹ written to 0x2111 and read back.
    """
    d = Truth.random(np.random.default_rng(TRUTH_SEED + 1), cross_axis_max=0.01).to_dict()
    d["serial"] = SERIAL
    truth = Truth.from_dict(d)
    truth_path = write_truth(tmp_path / "truth.json", truth, overwrite=False)
    plan = tmp_path / "turns.json"
    positions = [
        {"alpha_deg": a, "beta_deg": b, "psi_deg": p, "seconds": 3.0} for a, b, p in TURN_POSES_DEG
    ]
    plan.write_text(json.dumps({"positions": positions}))
    flags = sim_flags(truth_path, tmp_path / "state.json", scale=25.0)
    out = tmp_path / "turns.csv"
    assert cli(["record", out, "--plan", plan, *flags]).code == 0
    cal = tmp_path / "cal.json"
    run = cli(["solve", out, "--gyro", "moves", "--model", "full", "--tilt", "--json", cal])
    assert run.code == 0, run.err
    record = read_calibration(cal)
    assert record.gyro is not None and record.gyro.S is not None
    s = np.array(record.gyro.S, dtype=float)
    sigma = np.array(record.gyro.S_sigma, dtype=float)
    z = (s - truth.gyro.S) / sigma
    # 9 entries within 4σ: P(any beyond | Gaussian) ≈ 6e-4 per run (fixed seeds)
    assert np.all(np.abs(z) < 4.0), z
    assert np.all(sigma * truth.gyro.nominal_lsb < 0.005)
    run = cli(["write-params", cal, *flags])
    assert run.code == 0, run.err  # read back bit-exactly inside the transaction
    after = read_params(cli, flags, tmp_path / "read.json")  # a new process: from its store
    nominal = after["nominal"]
    block = block_from_record(record, nominal["accel_lsb"], nominal["gyro_lsb"])
    expected = readback_of(od.CalibrationBlock.from_objects(block.to_objects()), 1, True)
    assert after["readback"] == to_plain(expected)  # S⁻¹ (0x2111) and G (0x2112) bit-exact
    held = np.linalg.inv(np.array(after["readback"]["gyro_correction"], dtype=float))
    np.testing.assert_allclose(held, s, rtol=1e-5)  # float32 of S⁻¹, inverted back


def test_write_params_refuses_a_failed_calibration_unless_no_check(
    cli: Cli, tmp_path: Path, truth_file: Path
) -> None:
    cal = calibration_file(tmp_path, SERIAL)
    document = json.loads(cal.read_text())
    document["acceptance"] = {
        "passed": False,
        "limits": {"max_bias_sigma_mg": 5.0, "min_fit_p": 1e-4},
        "values": {"max_bias_sigma_mg": 8.2, "min_fit_p": 0.3},
    }
    cal.write_text(json.dumps(document))
    state = tmp_path / "state.json"
    flags = sim_flags(truth_file, state)
    run = cli(["write-params", cal, *flags, "--backup-dir", tmp_path / "bk"])
    assert run.code == 2 and run.err.count("\n") == 1
    assert "acceptance failed (max_bias_sigma_mg)" in run.err and "--no-check" in run.err
    assert not state.exists() and not (tmp_path / "bk").exists()  # refused before connecting
    run = cli(["write-params", cal, *flags, "--no-check", "--backup-dir", tmp_path / "bk"])
    assert run.code == 0, run.err
    assert read_params(cli, flags, tmp_path / "r.json")["readback"]["valid"] == 1


def _record_prompted(
    plan: Any, out: Path, seed: int, sets_pose: Callable[[int, int], bool]
) -> tuple[list[int], list[tuple[int, str]]]:
    """Record ``plan`` prompted from a simulated node; the operator sets the pose only when
    ``sets_pose(index, times_prompted)``. Returns the prompts and the refusals."""
    import can

    from canimucal.device.client import ImuClient
    from canimucal.io.recording_writer import RecordingWriter
    from canimucal.runtime.recorder import Recorder
    from canimucal.simnode.node import SimulatedImuNode

    channel = f"canimucal-prompted-{os.getpid()}-{seed}"
    node_bus, client_bus = (can.Bus(interface="virtual", channel=channel) for _ in range(2))
    node = SimulatedImuNode(node_bus, 0x10, make_truth(), time_scale=10.0, seed=seed).start()
    prompts: list[int] = []
    refusals: list[tuple[int, str]] = []

    def prompt(index: int, position: Any) -> None:
        prompts.append(index)
        if sets_pose(index, prompts.count(index)):
            node.set_pose(position.alpha, position.beta, position.psi)

    try:
        with ImuClient(client_bus, 0x10) as client:
            header = {"sample_rate_hz": 200.0, "device_serial": SERIAL}
            with RecordingWriter.open(out, header) as writer:
                recorder = Recorder([(client, writer, 200.0)])
                recorder.start()
                try:
                    recorder.record_prompted(
                        plan, prompt, settle_s=1.0, refused=lambda i, why: refusals.append((i, why))
                    )
                finally:
                    recorder.stop()
    finally:
        node.stop()
        node_bus.shutdown()
        client_bus.shutdown()
    return prompts, refusals


def test_record_prompted_refuses_a_pose_the_unit_is_not_at(tmp_path: Path) -> None:
    """The operator first leaves the unit level at the 45° pose: refused, prompted again."""
    from canimucal.model.vocabulary.plans import builtin_plan

    plan = builtin_plan("two").with_total_seconds(2.0)
    out = tmp_path / "refused.csv"
    # the second time, the pose is set
    prompts, refusals = _record_prompted(plan, out, 4, lambda i, times: times > 1 or i == 0)
    assert prompts == [0, 1, 1]
    assert [i for i, _ in refusals] == [1]
    assert "against target +45.0°, +5.0°" in refusals[0][1] and "> 3°" in refusals[0][1]
    rec = read_recording(out)
    for index, position in enumerate(plan.positions):  # only the pose the unit was at
        rows = rec.position == index
        assert rows.sum() == 200
        x = np.nanmean(rec.accel[rows, 0]) * od.to_float32(9.80665 / 2048.0)
        expected = -9.80665 * np.sin(position.alpha) * np.cos(position.beta)
        assert abs(x - expected) < 0.5, (index, x, expected)


def test_record_prompted_refuses_a_turn_the_gyro_did_not_see(tmp_path: Path) -> None:
    """``record --plan vehicle``: a turn on the spot that was not made is refused (issue 22).

    The accelerometer cannot see a turn about the vertical; the gyro's check the TUI runs
    (:class:`~canimucal.procedure.movecheck.MoveTracker`) can. The operator first presses
    Enter without turning the vehicle: refused, prompted again, then turned and recorded.
    """
    from dataclasses import replace

    from canimucal.model.vocabulary.plans import builtin_plan

    vehicle = builtin_plan("vehicle")
    plan = replace(vehicle, positions=vehicle.positions[:3]).with_total_seconds(3.0)
    out = tmp_path / "turns.csv"
    # the 90° turn: made the second time
    prompts, refusals = _record_prompted(plan, out, 5, lambda i, times: times > 1 or i != 1)
    assert prompts == [0, 1, 1, 2]
    assert [i for i, _ in refusals] == [1]
    # the turns are 5° 1σ each: a move may be 4σ of their combined 7.1° off, 28.3°
    assert "the turn was not made" in refusals[0][1] and "> 28.3°" in refusals[0][1]
    rec = read_recording(out)
    assert sorted(set(rec.position.tolist()) - {-1}) == [0, 1, 2]
