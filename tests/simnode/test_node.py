"""SimulatedImuNode on python-can's virtual bus, seen from a canopen client.

Timing checks use the CAN frame timestamps; tolerances are wide (the 2-core machine is
shared) but each check fails on a real fault (a wrong rate is off by a factor, not 15 %).
"""

from __future__ import annotations

import math
import struct
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

import can
import canopen
import numpy as np
import pytest

from canimucal.device import od
from canimucal.errors import InputError, NoDeviceError
from canimucal.model.frames import earth_rate_level, position_dcm, specific_force_level
from canimucal.model.positions import Plan, PlannedPosition
from canimucal.model.sensor import DEFAULT_ACCEL_LSB, DEFAULT_GYRO_LSB
from canimucal.model.vocabulary.plans import PLANS
from canimucal.sim.truth import Truth
from canimucal.simnode.node import SimulatedImuNode

if TYPE_CHECKING:
    from conftest import Frame, FrameRecorder

NODE_ID = 0x10  # the conftest's node
TPDO1, TPDO2, TPDO3 = 0x180 + NODE_ID, 0x280 + NODE_ID, 0x380 + NODE_ID
HEARTBEAT = 0x700 + NODE_ID
A_LSB = DEFAULT_ACCEL_LSB
FACTORY_CRC = od.block_crc(od.factory_block(DEFAULT_ACCEL_LSB, DEFAULT_GYRO_LSB).to_objects())


def _start(remote: canopen.RemoteNode) -> None:
    remote.nmt.send_command(0x01)  # NMT start (OPERATIONAL), to this node only


def _counter(frame: Frame) -> int:
    return struct.unpack_from("<H", frame.data, 6)[0]


def _counter3(frame: Frame) -> int:
    return struct.unpack_from("<H", frame.data, 2)[0]


def _boot_ups(frames: list[Frame]) -> int:
    return sum(f.cob_id == HEARTBEAT and f.data == b"\x00" for f in frames)


def _abort_code(action: Callable[[], object]) -> int:
    with pytest.raises(canopen.SdoAbortedError) as info:
        action()
    return int(info.value.code)


def _remote(network: canopen.Network) -> canopen.RemoteNode:
    node = network.add_node(NODE_ID, canopen.import_od(str(od.eds_path()), NODE_ID))
    node.sdo.RESPONSE_TIMEOUT = 1.0
    return node


def _rate_hz(frames: list[Frame]) -> float:
    return (len(frames) - 1) / (frames[-1].timestamp - frames[0].timestamp)


# -- NMT, boot-up, heartbeat -------------------------------------------------------------


def test_boot_up_frame_then_preoperational(
    sim_node: SimulatedImuNode, bus_frames: FrameRecorder
) -> None:
    first = bus_frames.wait_count(HEARTBEAT, 1)[0]
    assert first.data == b"\x00"  # boot-up
    assert sim_node.nmt_state == "PRE-OPERATIONAL"
    heartbeats = bus_frames.wait_count(HEARTBEAT, 2)
    assert heartbeats[1].data == b"\x7f"  # first heartbeat: PRE-OPERATIONAL


def test_heartbeat_period_follows_0x1017(
    remote_node: canopen.RemoteNode, bus_frames: FrameRecorder
) -> None:
    assert remote_node.sdo[0x1017].raw == 1000
    remote_node.sdo[0x1017].raw = 50
    time.sleep(0.05)
    bus_frames.clear()
    beats = bus_frames.wait_count(HEARTBEAT, 12, timeout=3.0)
    intervals = np.diff([f.timestamp for f in beats])
    assert 0.040 < float(np.median(intervals)) < 0.060, intervals
    _start(remote_node)
    bus_frames.wait_for(lambda fs: any(f.cob_id == HEARTBEAT and f.data == b"\x05" for f in fs))


def test_no_tpdo_while_preoperational_then_stopped(
    remote_node: canopen.RemoteNode, bus_frames: FrameRecorder
) -> None:
    time.sleep(0.3)
    assert not [f for f in bus_frames.frames() if f.cob_id in (TPDO1, TPDO2, TPDO3)]
    _start(remote_node)
    bus_frames.wait_count(TPDO1, 5)
    remote_node.nmt.send_command(0x02)  # NMT stop
    time.sleep(0.1)
    bus_frames.clear()
    time.sleep(0.3)
    assert not [f for f in bus_frames.frames() if f.cob_id in (TPDO1, TPDO2, TPDO3)]


def test_tpdos_after_start_ids_lengths_counters(
    remote_node: canopen.RemoteNode, bus_frames: FrameRecorder
) -> None:
    _start(remote_node)
    bus_frames.wait_count(TPDO1, 80)
    bus_frames.wait_count(TPDO3, 3)
    t1, t2, t3 = (bus_frames.frames(c) for c in (TPDO1, TPDO2, TPDO3))
    assert {len(f.data) for f in t1} == {8} and {len(f.data) for f in t2} == {8}
    assert {len(f.data) for f in t3} == {5}
    c1, c2 = [_counter(f) for f in t1], [_counter(f) for f in t2]
    n = min(len(c1), len(c2))
    assert c1[:n] == c2[:n]  # a sample is the TPDO1/TPDO2 pair with equal counters
    assert set(np.diff(c1) % 65536) == {1}  # 200 Hz output, 5 ms timers: every sample
    temp, counter, status = struct.unpack("<hHB", t3[-1].data)
    assert temp == 2500 and status & od.STATUS_CAL_ACTIVE == 0
    assert abs(counter - c1[-1]) < 100
    # TPDO3 every 100 ms of simulated time = every 20 samples
    assert set(np.diff([_counter3(f) for f in t3])) == {20}


def test_counter_wraps_at_65536(
    sim_node: SimulatedImuNode, remote_node: canopen.RemoteNode, bus_frames: FrameRecorder
) -> None:
    # white-box: reaching the wrap takes 5.5 min at 200 Hz. The counter keeps running in
    # PRE-OPERATIONAL, so leave 100 samples (0.5 s) for the NMT start to arrive.
    with sim_node._producer.lock:
        sim_node._producer.counter = 65536 - 100
    _start(remote_node)
    counters = [_counter(f) for f in bus_frames.wait_count(TPDO1, 200)]
    assert set(np.diff(counters) % 65536) == {1}
    assert 65535 in counters and 0 in counters and counters.index(0) > counters.index(65535)


def test_sdo_reads_live_values(remote_node: canopen.RemoteNode) -> None:
    time.sleep(0.1)
    first = remote_node.sdo[0x2002][2].raw
    time.sleep(0.1)
    assert (remote_node.sdo[0x2002][2].raw - first) % 65536 >= 10  # ≈ 20 at 200 Hz
    level_y = -specific_force_level(Truth.from_dict({}).g)[1] / A_LSB
    assert abs(remote_node.sdo[0x2000][2].raw + level_y) < 30  # ≈ −2049 counts, σ 4.4
    assert remote_node.sdo[0x2002][1].raw == 2500
    assert remote_node.sdo[0x2010][1].raw == pytest.approx(A_LSB, rel=1e-7)
    assert remote_node.sdo[0x1010][4].raw == 1


# -- data --------------------------------------------------------------------------------


def test_static_means_match_truth(
    make_sim_node: Callable[..., SimulatedImuNode],
    client_network: canopen.Network,
    bus_frames: FrameRecorder,
) -> None:
    truth = Truth.random(np.random.default_rng(11))
    node = make_sim_node(truth=truth, time_scale=20.0, seed=5, start=False)
    alpha, beta, psi = 0.4, 0.1, 0.3
    node.set_pose(alpha, beta, psi)  # from t = 0, 1 s transient
    node.start()
    _start(_remote(client_network))
    remote_id = node.local_node.id
    assert remote_id == NODE_ID
    t1 = bus_frames.wait_count(TPDO1, 1600, timeout=10.0)
    t2 = bus_frames.wait_count(TPDO2, 1600, timeout=10.0)
    # counter k is the sample at t = (k − 1)/200 s; keep t ≥ 1.5 s (transient over at 1 s)
    accel = np.array([struct.unpack("<hhhH", f.data) for f in t1[:1600]], float)
    gyro = np.array([struct.unpack("<hhhH", f.data) for f in t2[:1600]], float)
    accel, gyro = accel[accel[:, 3] > 300, :3], gyro[gyro[:, 3] > 300, :3]
    assert accel.shape[0] >= 1200
    c = position_dcm(alpha, beta, psi, truth.alpha0, truth.beta0, truth.tilt_model)
    f = c @ specific_force_level(truth.g)
    w = c @ earth_rate_level(truth.latitude, truth.heading)
    expect_a = truth.accel.bias + truth.accel.K @ f + truth.accel.quadratic * f * f
    expect_g = truth.gyro.bias + truth.gyro.S @ w + truth.gyro.G @ f
    # per-sample σ = N √fs |K_ii| (+ rounding 1/√12): accel ≈ 4.4, gyro ≈ 1.6 counts
    sigma_a = np.hypot(1.5e-3 * math.sqrt(200) * np.abs(np.diag(truth.accel.K)), 0.29)
    sigma_g = np.hypot(1.2e-4 * math.sqrt(200) * np.abs(np.diag(truth.gyro.S)), 0.29)
    n = accel.shape[0]
    # 4σ of the mean per axis: two-sided p = 6e-5 each, 4e-4 over 6 axes (fixed seed anyway)
    assert np.all(np.abs(accel.mean(0) - expect_a) < 4 * sigma_a / math.sqrt(n))
    assert np.all(np.abs(gyro.mean(0) - expect_g) < 4 * sigma_g / math.sqrt(n))
    # sample std: relative sampling error 1/√(2n) ≈ 2 %; 15 % is > 7σ
    np.testing.assert_allclose(accel.std(0, ddof=1), sigma_a, rtol=0.15)


def test_time_scale_runs_simulated_time_fast(
    make_sim_node: Callable[..., SimulatedImuNode],
    client_network: canopen.Network,
    bus_frames: FrameRecorder,
) -> None:
    node = make_sim_node(time_scale=10.0)
    _start(_remote(client_network))
    time.sleep(0.2)
    bus_frames.clear()
    n0, w0 = node.samples_produced, time.monotonic()
    time.sleep(1.0)
    n1, w1 = node.samples_produced, time.monotonic()
    rate = (n1 - n0) / (w1 - w0)  # 10 simulated s per wall s at 200 Hz: 2000 samples/s
    # the lower bound tells 10× from 5× and below; a loaded 2-core machine stalled the node to
    # 1507/s once inside the suite (throughput figures: benchmarks/, not a unit test)
    assert 1000 < rate < 2300, rate
    frames = bus_frames.frames(TPDO1)
    counters = [_counter(f) for f in frames]
    assert set(np.diff(counters) % 65536) == {1}
    assert 1000 < _rate_hz(frames) < 2300
    # paced, not one burst: frames spread over the second (a burst would leave ~1 s gaps);
    # 0.5 s leaves room for scheduling stalls on the shared machine (CI's lowest-versions run
    # beside the other xdist worker: one gap of 0.28 s)
    assert max(np.diff([f.timestamp for f in frames])) < 0.5


def test_output_data_rate_change(
    remote_node: canopen.RemoteNode, bus_frames: FrameRecorder
) -> None:
    remote_node.sdo[0x2010][3].raw = 500
    assert remote_node.sdo[0x1800][5].raw == 2 and remote_node.sdo[0x1801][5].raw == 2
    assert remote_node.sdo[0x1802][5].raw == 100
    assert _abort_code(lambda: setattr(remote_node.sdo[0x2010][3], "raw", 300)) == 0x06090030
    assert remote_node.sdo[0x2010][3].raw == 500
    _start(remote_node)
    time.sleep(0.2)
    bus_frames.clear()
    frames = bus_frames.wait_count(TPDO1, 300, timeout=3.0)
    assert 425 < _rate_hz(frames) < 575  # 500 Hz ± 15 %
    assert set(np.diff([_counter(f) for f in frames]) % 65536) == {1}
    t3 = bus_frames.wait_count(TPDO3, 3)
    assert set(np.diff([_counter3(f) for f in t3])) == {50}  # 100 ms at 500 Hz


def test_sync_mode(
    remote_node: canopen.RemoteNode, client_network: canopen.Network, bus_frames: FrameRecorder
) -> None:
    remote_node.sdo[0x1800][2].raw = 2  # every 2nd SYNC
    remote_node.sdo[0x1801][2].raw = 2
    _start(remote_node)
    time.sleep(0.25)
    assert not bus_frames.frames(TPDO1) and not bus_frames.frames(TPDO2)
    assert bus_frames.frames(TPDO3)  # TPDO3 stays event-driven
    for _ in range(10):
        client_network.sync.transmit()
        time.sleep(0.02)
    t1 = bus_frames.wait_count(TPDO1, 5)
    t2 = bus_frames.wait_count(TPDO2, 5)
    time.sleep(0.1)
    assert len(bus_frames.frames(TPDO1)) == 5 and len(bus_frames.frames(TPDO2)) == 5
    assert [_counter(f) for f in t1] == [_counter(f) for f in t2]
    assert all(np.diff([_counter(f) for f in t1]) > 0)  # 40 ms of samples between them


def test_tpdo_remap_and_refused_mapping(
    remote_node: canopen.RemoteNode, bus_frames: FrameRecorder
) -> None:
    mapping = remote_node.sdo[0x1A00]
    mapping[0].raw = 0
    mapping[4].raw = 0
    mapping[0].raw = 3  # accel x/y/z only: 6 bytes
    code = _abort_code(lambda: setattr(mapping[1], "raw", 0x21000120))
    assert code == 0x06040041  # 0x2100:01 is not PDO-mappable
    _start(remote_node)
    frames = bus_frames.wait_count(TPDO1, 5)
    assert {len(f.data) for f in frames} == {6}


def test_schedule_starts_at_first_nmt_start(
    sim_node: SimulatedImuNode, remote_node: canopen.RemoteNode
) -> None:
    plan = Plan("two", (PlannedPosition(0.0, 0.0, seconds=2.0), PlannedPosition(0.5, 0.05)))
    sim_node.set_schedule(plan)
    time.sleep(0.1)
    assert sim_node.simulator.schedule_end_s is None
    _start(remote_node)
    deadline = time.monotonic() + 2.0
    while sim_node.simulator.schedule_end_s is None and time.monotonic() < deadline:
        time.sleep(0.01)
    assert sim_node.simulator.schedule_end_s is not None


# -- writes, store, restore --------------------------------------------------------------


def test_out_of_range_writes_refused_value_unchanged(remote_node: canopen.RemoteNode) -> None:
    nan32 = struct.pack("<f", math.nan)
    cases = [
        (0x2100, 1, nan32),
        (0x2110, 2, struct.pack("<f", math.inf)),
        (0x2100, 3, od.encode("f32", 7e4)),
        (0x2101, 1, od.encode("f32", 2 * A_LSB)),
        (0x2101, 2, od.encode("f32", 0.3 * A_LSB)),
        (0x2111, 5, od.encode("f32", 0.2 * DEFAULT_GYRO_LSB)),
        (0x2112, 1, od.encode("f32", 1e4)),
        (0x2120, 2, od.encode("f32", 0.3)),
        (0x2121, 5, od.encode("u8", 2)),
        (0x2121, 2, od.encode("u8", 9)),
        (0x2121, 4, od.encode("f32", -1.0)),
        (0x2010, 3, od.encode("u16", 300)),
    ]
    for index, sub, data in cases:
        before = remote_node.sdo.upload(index, sub)
        code = _abort_code(lambda i=index, s=sub, d=data: remote_node.sdo.download(i, s, d))
        assert code == 0x06090030, f"0x{index:04X}:{sub:02X}"
        assert remote_node.sdo.upload(index, sub) == before


def test_read_only_and_missing_objects_refused(remote_node: canopen.RemoteNode) -> None:
    sdo = remote_node.sdo
    assert _abort_code(lambda: sdo.download(0x2000, 1, b"\x01\x00")) == 0x06010002
    assert _abort_code(lambda: sdo.download(0x2010, 1, od.encode("f32", A_LSB))) == 0x06010002
    assert _abort_code(lambda: sdo.download(0x1018, 4, od.encode("u32", 5))) == 0x06010002
    assert _abort_code(lambda: sdo.upload(0x2100, 4)) == 0x06090011
    assert _abort_code(lambda: sdo.download(0x2101, 10, od.encode("f32", 0.0))) == 0x06090011
    assert _abort_code(lambda: sdo.upload(0x3000, 0)) == 0x06020000
    assert _abort_code(lambda: sdo.download(0x1010, 4, od.encode("u32", 1))) == 0x08000020


def test_off_diagonal_checked_against_current_row_diagonal(
    remote_node: canopen.RemoteNode,
) -> None:
    m = remote_node.sdo[0x2101]
    m[5].raw = 1.4 * A_LSB
    m[4].raw = 0.27 * A_LSB  # ≤ 0.2 × 1.4 LSB
    assert _abort_code(lambda: setattr(m[6], "raw", 0.29 * A_LSB)) == 0x06090030
    assert m[4].raw == pytest.approx(0.27 * A_LSB, rel=1e-6)
    assert m[6].raw == 0.0


def test_store_survives_reboot_and_new_instance(
    make_sim_node: Callable[..., SimulatedImuNode],
    client_network: canopen.Network,
    bus_frames: FrameRecorder,
    tmp_path: Path,
) -> None:
    state = tmp_path / "node.json"
    node = make_sim_node(state_file=state)
    remote = _remote(client_network)
    remote.sdo[0x2100][1].raw = 12.5
    remote.sdo[0x2010][3].raw = 100  # application group: not stored by 0x1010:04
    remote.sdo[0x1010][4].raw = od.SAVE_SIGNATURE
    remote.sdo[0x2100][2].raw = 7.0  # unsaved
    assert state.is_file()
    node.reboot()
    bus_frames.wait_for(lambda fs: _boot_ups(fs) == 2)  # the first boot-up and the reboot's
    assert remote.sdo[0x2100][1].raw == 12.5
    assert remote.sdo[0x2100][2].raw == 0.0
    assert remote.sdo[0x2010][3].raw == 200
    node.stop()
    make_sim_node(state_file=state)
    assert remote.sdo[0x2100][1].raw == 12.5
    assert remote.sdo[0x2121][6].raw == FACTORY_CRC  # the CRC was not rewritten


def test_nmt_reset_node_and_reset_communication(
    sim_node: SimulatedImuNode, remote_node: canopen.RemoteNode, bus_frames: FrameRecorder
) -> None:
    remote_node.sdo[0x2100][1].raw = 3.0
    remote_node.sdo[0x1017].raw = 200
    remote_node.nmt.send_command(0x82)  # reset communication: comm objects reloaded
    bus_frames.wait_for(lambda fs: _boot_ups(fs) == 2)
    time.sleep(0.05)
    assert sim_node.nmt_state == "PRE-OPERATIONAL"
    assert remote_node.sdo[0x1017].raw == 1000
    assert remote_node.sdo[0x2100][1].raw == 3.0
    remote_node.nmt.send_command(0x81)  # reset node: unsaved application values lost
    bus_frames.wait_for(lambda fs: _boot_ups(fs) == 3)
    time.sleep(0.05)
    assert remote_node.sdo[0x2100][1].raw == 0.0


def test_restore_defaults_takes_effect_at_reset(
    make_sim_node: Callable[..., SimulatedImuNode],
    client_network: canopen.Network,
    tmp_path: Path,
) -> None:
    state = tmp_path / "node.json"
    node = make_sim_node(state_file=state)
    remote = _remote(client_network)
    remote.sdo[0x2100][1].raw = 12.5
    remote.sdo[0x1017].raw = 300
    remote.sdo[0x1010][1].raw = od.SAVE_SIGNATURE  # all
    code = _abort_code(lambda: setattr(remote.sdo[0x1011][4], "raw", 0x12345678))
    assert code == 0x08000020
    remote.sdo[0x1011][4].raw = od.LOAD_SIGNATURE  # calibration only
    assert remote.sdo[0x2100][1].raw == 12.5  # not before the reset (CiA 301)
    node.reboot()
    assert remote.sdo[0x2100][1].raw == 0.0
    assert remote.sdo[0x2121][6].raw == FACTORY_CRC
    assert remote.sdo[0x1017].raw == 300  # the communication group stays stored
    node.stop()
    make_sim_node(state_file=state)
    assert remote.sdo[0x2100][1].raw == 0.0


def test_crc_and_firmware_semantics(
    make_sim_node: Callable[..., SimulatedImuNode],
    client_network: canopen.Network,
    bus_frames: FrameRecorder,
) -> None:
    truth = Truth.random(np.random.default_rng(4), gyro_g_max=1.0)
    node = make_sim_node(truth=truth)
    remote = _remote(client_network)
    assert remote.sdo[0x2121][6].raw == FACTORY_CRC
    block = od.CalibrationBlock(
        accel_bias=np.array(truth.accel.bias),
        accel_correction=np.linalg.inv(truth.accel.K),
        gyro_bias=np.array(truth.gyro.bias),
        gyro_correction=np.linalg.inv(truth.gyro.S),
        gyro_g=np.array(truth.gyro.G),
        base_tilt_rad=np.array([truth.alpha0, truth.beta0]),
        time_unix_s=1_700_000_000,
        plan_code=PLANS["five"].device_code,
        temp_c=25.0,
        rms_ms2=0.01,
    )
    assert od.block_range_problems(block, A_LSB, DEFAULT_GYRO_LSB) == []
    objects = block.to_objects()
    for (index, sub), value in objects.items():
        remote.sdo.download(index, sub, od.encode(od.OBJECT_CODES[(index, sub)], value))
    remote.sdo[0x2121][6].raw = od.block_crc(objects)
    assert not node.calibration_active()  # valid still 0
    remote.sdo[0x2121][5].raw = 1
    assert node.calibration_active()
    _start(remote)
    t3 = bus_frames.wait_count(TPDO3, 2)
    assert t3[-1].data[4] & od.STATUS_CAL_ACTIVE
    accel, gyro = node.corrected_sample()
    # one sample: accel noise 1.5e-3·√200 ≈ 0.021 m/s² per axis; 0.15 is > 4σ of the norm
    assert abs(float(np.linalg.norm(accel)) - truth.g) < 0.15
    assert float(np.linalg.norm(gyro)) < 0.02  # gyro noise ≈ 1.7e-3 rad/s per axis
    remote.sdo[0x2121][6].raw = od.block_crc(objects) ^ 1  # CRC mismatch: nominal output
    assert not node.calibration_active()
    accel, _ = node.corrected_sample()
    raw = np.array([node.od_value(0x2000, k) for k in (1, 2, 3)], float)
    assert np.linalg.norm(accel) == pytest.approx(np.linalg.norm(raw) * A_LSB, rel=0.01)


# -- construction ------------------------------------------------------------------------


def test_context_manager_on_a_given_network(
    open_bus: Callable[[], can.BusABC], bus_frames: FrameRecorder, client_network: canopen.Network
) -> None:
    network = canopen.Network(open_bus())
    network.NOTIFIER_CYCLE = 0.1
    network.connect()
    truth = Truth.from_dict({"serial": 1234, "sample_rate_hz": 100})
    node = SimulatedImuNode(network, 0x22, truth, seed=3)
    assert node.od_value(0x1018, 4) == 1234  # before start too
    assert node.od_value(0x1801, 5) == 10  # 1000/ODR ms
    with node:
        bus_frames.wait_for(lambda fs: any(f.cob_id == 0x722 and f.data == b"\x00" for f in fs))
        assert network[0x22] is node.local_node
    assert 0x22 not in network
    network.notifier.stop(1.0)
    with pytest.raises(InputError):
        node.reboot()


def test_constructor_refuses_bad_arguments(open_bus: Callable[[], can.BusABC]) -> None:
    bus = open_bus()
    with pytest.raises(InputError, match="node id"):
        SimulatedImuNode(bus, 0)
    with pytest.raises(InputError, match="time_scale"):
        SimulatedImuNode(bus, time_scale=0.0)
    with pytest.raises(NoDeviceError):
        SimulatedImuNode(canopen.Network())
