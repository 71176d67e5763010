"""The procedure survives what the node reports mid-session.

A session against a simulated node (:class:`Devices`) with faults injected while a position
is averaged: a reboot or an EMCY rejects that attempt and the position is averaged again
(never across the reboot); another unit after the reboot stops the session with
``ProcedureFailed``; a heartbeat loss is a notice and the session goes on.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np

from canimucal.device import od
from canimucal.errors import DeviceError
from canimucal.io.recording_writer import RecordingWriter
from canimucal.model.vocabulary.plans import builtin_plan
from canimucal.procedure import events as ev
from canimucal.procedure.averaging import AveragingPolicy
from canimucal.procedure.machine import Phase
from canimucal.runtime.inputs import read_recording
from canimucal.runtime.recorder import Recorder
from canimucal.runtime.session import Session, SessionCommand
from canimucal.runtime.wiring import Devices, demo_settings, open_devices
from canimucal.sim.truth import Truth

NODE = 0x10
Hook = Callable[[Devices, list[ev.Event]], None]


def _rig() -> Devices:
    truth = Truth.random(np.random.default_rng(8), cross_axis_max=0.0, tilt_max_deg=0.0)
    return open_devices(demo_settings([truth], time_scale=30.0, seed=3))


def _session(rig: Devices, out: Path, *, warmup: bool = False) -> Session:
    return rig.session(
        builtin_plan("two"),
        out,
        plan_name="two",
        warmup=warmup,
        averaging=AveragingPolicy(fixed_s=10.0),  # 0.33 s wall: the fault lands inside
    )


def _drive(rig: Devices, session: Session, hook: Hook, max_polls: int = 20_000) -> None:
    """An automatic operator that never writes; ``hook`` sees every batch of events."""
    try:
        hook(rig, session.start())
        for _ in range(max_polls):
            proc = session.procedure
            if proc.phase is Phase.INSTRUCT:
                hook(rig, session.confirm_pose())
            elif proc.phase is Phase.REVIEW_POSITION:
                hook(rig, session.command(SessionCommand.ACCEPT))
            elif proc.phase is Phase.READY_TO_SOLVE:
                hook(rig, session.solve())
            elif proc.phase is Phase.REVIEW:
                hook(rig, session.command(SessionCommand.FINISH_WITHOUT_WRITING))
            if session.procedure.phase in (Phase.DONE, Phase.CANCELLED):
                return
            hook(rig, session.poll())
        raise AssertionError("the session did not end")
    finally:
        session.finish()


def _at_averaging(index: int, **faults: object) -> Hook:
    """Inject ``faults`` (times relative to now, simulated) when ``index`` starts averaging."""
    done: list[bool] = []

    def hook(rig: Devices, events: list[ev.Event]) -> None:
        started = [e for e in events if isinstance(e, ev.AveragingStarted) and e.index == index]
        if started and not done:
            done.append(True)
            sim = rig.sim_nodes[NODE]
            now = sim.simulator.time_s
            keys = dict(faults)
            if "reboot_in_s" in keys:
                keys["reboot_at_s"] = now + float(keys.pop("reboot_in_s"))  # type: ignore[arg-type]
            if "emcy_in_s" in keys:
                at = now + float(keys.pop("emcy_in_s"))  # type: ignore[arg-type]
                codes = keys.pop("emcy_codes", [0x5000])
                keys["emergency"] = [
                    {"at_s": at + 0.01 * k, "code": code, "register": 0 if code == 0 else 0x11}
                    for k, code in enumerate(codes)  # type: ignore[arg-type]
                ]
            sim.faults.set(**keys)

    return hook


def _notices(history: list[ev.Event], kind: str) -> list[ev.DeviceEventReported]:
    return [e for e in history if isinstance(e, ev.DeviceEventReported) and e.kind == kind]


def test_reboot_while_averaging_rejects_and_redoes_the_position(tmp_path: Path) -> None:
    with _rig() as rig:
        session = _session(rig, tmp_path)
        _drive(rig, session, _at_averaging(1, reboot_in_s=0.3))
        history = session.history
    assert _notices(history, "reboot")
    rejected = [e for e in history if isinstance(e, ev.PositionRejected)]
    assert any(e.index == 1 and "rebooted" in e.reason for e in rejected)
    kinds = [type(e) for e in history]
    reject_at = next(i for i, e in enumerate(history) if isinstance(e, ev.PositionRejected))
    assert ev.PositionAveraged in kinds[reject_at:]  # averaged again after the reboot
    assert session.procedure.phase is Phase.DONE and session.procedure.solved is not None
    assert set(session.procedure.accepted[NODE]) == {0, 1}
    rec = read_recording(tmp_path / "recording.csv")
    counters = np.asarray(rec.counter)
    for index in (0, 1):  # no accepted average spans the reboot: its counters run on
        rows = counters[np.asarray(rec.position) == index]
        assert rows.size > 2 * rec.sample_rate_hz
        assert np.all(np.diff(rows) % 65536 < 50)
    assert np.any(np.diff(counters) % 65536 > 1000)  # the counter did fall back


def test_emergency_while_averaging_is_a_notice_and_rejects_the_attempt(tmp_path: Path) -> None:
    with _rig() as rig:
        session = _session(rig, tmp_path)
        _drive(rig, session, _at_averaging(0, emcy_in_s=0.3))
        history = session.history
    notice = _notices(history, "emergency")
    assert notice and "0x5000" in notice[0].message
    assert any(
        isinstance(e, ev.PositionRejected) and e.index == 0 and "emergency" in e.reason
        for e in history
    )
    assert session.procedure.phase is Phase.DONE and set(session.procedure.accepted[NODE]) == {
        0,
        1,
    }


def test_error_reset_and_communication_emergencies_do_not_interrupt_the_pose(
    tmp_path: Path,
) -> None:
    with _rig() as rig:
        session = _session(rig, tmp_path)
        codes = [0x0000, 0x8120, 0x8110, 0x8210]  # bus warning/reset, passive, overrun, PDO
        _drive(rig, session, _at_averaging(0, emcy_in_s=0.3, emcy_codes=codes))
        history = session.history
    notices = _notices(history, "emergency")
    assert {n.message.split(": ")[1][:6] for n in notices} == {
        "0x0000",
        "0x8120",
        "0x8110",
        "0x8210",
    }
    rejected = [e.reason for e in history if isinstance(e, ev.PositionRejected)]
    assert not rejected, rejected
    assert session.procedure.phase is Phase.DONE and set(session.procedure.accepted[NODE]) == {
        0,
        1,
    }


def test_another_unit_after_a_reboot_stops_the_session(tmp_path: Path) -> None:
    with _rig() as rig:
        session = _session(rig, tmp_path)
        serial = session.links[NODE].identity.serial
        hook = _at_averaging(1, reboot_in_s=0.3, serial_after_reboot=serial + 1)
        _drive(rig, session, hook)
        history = session.history
    failed = [e for e in history if isinstance(e, ev.ProcedureFailed)]
    assert len(failed) == 1 and "different unit" in failed[0].message
    assert f"serial {serial + 1}" in failed[0].message
    assert session.procedure.phase is Phase.CANCELLED  # stopped as on an error, no summary
    assert not session.procedure.solved
    assert not any(isinstance(e, ev.ProcedureFinished) for e in history)
    rec = read_recording(tmp_path / "recording.csv")  # what was recorded is kept
    assert rec.n_rows > 0 and not np.any(np.asarray(rec.position) == 1)


def test_heartbeat_loss_is_a_notice_and_the_session_goes_on(tmp_path: Path) -> None:
    with _rig() as rig:
        rig.identities()
        rig.clients[NODE].write_value(od.HEARTBEAT, 0, "u16", 100)  # watched: 3 × 0.1 s
        session = _session(rig, tmp_path, warmup=True)
        history = session.start()
        now = rig.sim_nodes[NODE].simulator.time_s
        rig.sim_nodes[NODE].faults.set(heartbeat_loss={"from_s": now, "until_s": now + 30.0})
        try:
            for _ in range(2000):
                history += session.poll()
                if _notices(history, "heartbeat_resumed"):
                    break
        finally:
            session.finish()
    lost = _notices(history, "heartbeat_lost")
    assert lost and "no heartbeat" in lost[0].message
    assert _notices(history, "heartbeat_resumed")
    assert session.procedure.phase is Phase.WARMUP  # not stopped
    assert not any(isinstance(e, ev.ProcedureFailed) for e in history)


def _record_with_reboot(
    tmp_path: Path, reboot_in_s: float, settle_s: float, seconds: float
) -> tuple[Recorder, Path, DeviceError | None]:
    """``record_pose`` of the level pose on a node that reboots ``reboot_in_s`` from now."""
    path = tmp_path / "recorded.csv"
    position = builtin_plan("two").with_total_seconds(2 * seconds).positions[0]
    error = None
    with _rig() as rig:
        rig.identities()
        client, sim = rig.clients[NODE], rig.sim_nodes[NODE]
        rate = float(client.output_data_rate())
        header = {"sample_rate_hz": rate, "device_serial": rig.truths[NODE].serial}
        with RecordingWriter.open(path, header) as writer:
            recorder = Recorder([(client, writer, rate)])
            recorder.start()
            sim.faults.set(reboot_at_s=sim.simulator.time_s + reboot_in_s)
            try:
                recorder.record_pose(0, position, settle_s=settle_s)
            except DeviceError as exc:
                error = exc
            finally:
                recorder.stop()
    return recorder, path, error


def test_record_resumes_after_a_reboot_while_settling(tmp_path: Path) -> None:
    recorder, path, error = _record_with_reboot(tmp_path, 1.0, settle_s=8.0, seconds=2.0)
    assert error is None and recorder.tallies[0].reboots == 1
    rec = read_recording(path)
    counters = np.asarray(rec.counter)
    labelled = counters[np.asarray(rec.position) == 0]
    assert labelled.size == round(2.0 * rec.sample_rate_hz)
    assert np.all(np.diff(labelled) % 65536 == 1)  # all after the reboot, none missing
    assert np.any(np.diff(counters) % 65536 > 1000)  # the counter fell back before them


def test_record_flags_a_position_interrupted_by_a_reboot(tmp_path: Path) -> None:
    recorder, path, error = _record_with_reboot(tmp_path, 15.0, settle_s=0.5, seconds=60.0)
    assert error is not None and "rebooted while position 0" in str(error)
    assert "record position 0 again" in str(error)
    rec = read_recording(path)  # what came before the reboot is kept, labelled
    labelled = np.asarray(rec.counter)[np.asarray(rec.position) == 0]
    assert 0 < labelled.size < round(60.0 * rec.sample_rate_hz)
    assert np.all(np.diff(labelled) % 65536 < 50)  # never across the reboot


def test_the_position_screen_tells_each_device_event() -> None:
    from canimucal.tui.screens.position import notice_text

    event = ev.DeviceEventReported(NODE, "heartbeat_lost", "node 16: no heartbeat for 0.3 s")
    assert notice_text(event) == "[b]heartbeat lost[/b]: node 16: no heartbeat for 0.3 s"
    rejected = ev.PositionRejected(1, "node 16 rebooted", NODE)
    assert "position 2 rejected" in notice_text(rejected) and "rebooted" in notice_text(rejected)
