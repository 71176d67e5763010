"""The CAN runner against a simulated node on the virtual bus: files, silence, readback."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from canimucal.errors import DeviceError
from canimucal.io.calibration import read_calibration
from canimucal.model.vocabulary.plans import builtin_plan
from canimucal.procedure import events as ev
from canimucal.procedure.averaging import AveragingPolicy
from canimucal.procedure.machine import Phase
from canimucal.runtime.inputs import read_recording
from canimucal.runtime.operator import run_automatic
from canimucal.runtime.session import WriteOptions
from canimucal.runtime.wiring import Devices, demo_settings, open_devices
from canimucal.sim.truth import Truth


def _rig() -> Devices:
    truth = Truth.random(np.random.default_rng(8), cross_axis_max=0.0, tilt_max_deg=0.0)
    return open_devices(demo_settings([truth], time_scale=30.0, seed=3))


def test_a_silent_node_stops_the_session_and_the_recording_is_kept(tmp_path: Path) -> None:
    with _rig() as rig:
        session = rig.session(
            builtin_plan("two"),
            tmp_path,
            plan_name="two",
            warmup=True,
            averaging=AveragingPolicy(fixed_s=3.0),
        )
        session.silence_timeout_s = 0.5
        session.start()
        for _ in range(20):
            session.poll()
        assert session.procedure.phase is Phase.WARMUP
        rig.sim_nodes[0x10].stop()
        with pytest.raises(DeviceError, match="sent no samples"):
            for _ in range(200):
                session.poll()
        session.finish()
    rec = read_recording(tmp_path / "recording.csv")
    assert rec.n_rows > 100 and np.all(rec.position == -1)
    assert not (tmp_path / "recording.csv.partial").exists()


def test_the_session_saves_the_record_before_writing_and_adds_the_readback(
    tmp_path: Path,
) -> None:
    with _rig() as rig:
        session = rig.session(
            builtin_plan("two"),
            tmp_path,
            plan_name="two",
            warmup=False,
            averaging=AveragingPolicy(fixed_s=3.0),
            verify_seconds=2.0,
        )
        history = run_automatic(session, write_anyway=True)
        truth = rig.truths[0x10]
    kinds = [type(e) for e in history]
    assert kinds.index(ev.RecordSaved) < kinds.index(ev.WriteFinished)
    record = read_calibration(tmp_path / "calibration.json")
    assert record.readback is not None and record.readback.valid == 1
    assert record.recording is not None and record.recording.file == "recording.csv"
    assert record.device.serial == truth.serial
    rec = read_recording(tmp_path / "recording.csv")
    assert sorted(set(rec.position.tolist()) - {-1}) == [0, 1]
    assert read_recording(tmp_path / "verification.csv").n_rows > 2 * rec.sample_rate_hz
    assert list((tmp_path / "backups").glob(f"{truth.serial}-*.json"))
    # two verification poses away from the fit's level one: the most tilted, a level turn
    verified = [e for e in history if isinstance(e, ev.PoseVerified)]
    assert [np.rad2deg(e.position.angles).round(3).tolist() for e in verified] == [
        [45.0, 5.0, 0.0],
        [0.0, 0.0, 90.0],
    ]
    for e in verified:
        assert abs(e.norm_error_calibrated_ms2) < 0.01 and e.tilt_error_calibrated_deg < 1.0
    final = record.verification
    assert (
        final is not None
        and final.done
        and set(final.values)
        == {
            "max_verify_norm_error_mg",
            "max_verify_tilt_error_deg",
        }
    )


def test_a_session_interrupted_after_the_write_records_the_verification_as_not_done(
    tmp_path: Path,
) -> None:
    with _rig() as rig:
        session = rig.session(
            builtin_plan("two"),
            tmp_path,
            plan_name="two",
            warmup=True,  # the automatic operator skips it: the certificate must say so
            averaging=AveragingPolicy(fixed_s=3.0),
            verify_seconds=2.0,
        )
        write = session.write

        def write_then_ctrl_c(options: WriteOptions | None = None) -> list[ev.Event]:
            write(options)
            raise KeyboardInterrupt  # the operator quits before the level re-read

        session.write = write_then_ctrl_c  # type: ignore[method-assign]
        with pytest.raises(KeyboardInterrupt):
            run_automatic(session, write_anyway=True)
    record = read_calibration(tmp_path / "calibration.json")
    assert record.readback is not None and record.readback.valid == 1  # it was written
    assert record.acceptance is not None and "max_bias_sigma_mg" in record.acceptance.limits
    assert record.verification is not None
    assert record.verification.written is True
    assert record.verification.done is False and record.verification.passed is False
    for page in ("certificate.md", "certificate.html"):
        text = (tmp_path / page).read_text()
        assert "NOT DONE" in text and "skipped by the operator" in text, page
