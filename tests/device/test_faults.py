"""Each fault mode of the simulated node, and the client surviving it (issue 6, items 1–2).

Streaming runs on python-can's virtual bus (which never drops a frame itself, docs/design.md §8),
so every loss the client reports must be one the node injected: the tests compare the
client's counts with the injector's, exactly. Counting identity for TPDO1/TPDO2 frames:
``lost_accel + lost_gyro + 2·lost_samples`` = frames that never arrived in time.

The fault injector is the simulated node's: the fault modes stay on it (heartbeat loss,
error frames, SDO and TPDO faults). The node events a test can cause from outside (a power
cycle mid-stream, a reboot as another unit, an EMCY, a bus that raises on send) run against
both nodes (``either_rig``, ``make_device``); the independent durand node streams in real
time (200 Hz), the simulated one at ``TIME_SCALE``.
"""

from __future__ import annotations

import queue
import time
from collections.abc import Callable, Iterator
from typing import Any

import can
import canopen
import pytest

from canimucal.device import od
from canimucal.device.bus import SdoChannel
from canimucal.device.client import ImuClient
from canimucal.device.events import (
    BusErrorReceived,
    DeviceEvent,
    EmergencyReceived,
    HeartbeatLost,
    HeartbeatResumed,
    NodeRebooted,
    SerialChanged,
)
from canimucal.errors import DeviceError, DeviceSilentError, InputError, SdoAbort
from canimucal.model.samples import SampleBlock, concat_blocks
from canimucal.sim.truth import Truth
from canimucal.simnode.faults import FaultInjector, parse_faults
from canimucal.simnode.node import SimulatedImuNode
from tests.support.buses import FaultyBus
from tests.support.nodes import DeviceUnderTest

NODE_ID = 0x10
T1, T2, T3 = 0x180 + NODE_ID, 0x280 + NODE_ID, 0x380 + NODE_ID
SERIAL = 5150
TIME_SCALE = 4.0  # 200 Hz simulated → 800 samples per wall second


def _client(client_network: canopen.Network) -> ImuClient:
    client = ImuClient(client_network, NODE_ID, sdo_timeout_s=0.3, sdo_backoff_s=0.01)
    assert client.find_node(2.0) in ("boot-up", "heartbeat")
    # The node's own first boot-up frame may still have been queued on the virtual bus when
    # the client subscribed: drop it, so every event a test waits for is one it caused.
    while True:
        try:
            client.events.get_nowait()
        except queue.Empty:
            break
    return client


@pytest.fixture
def rig(
    client_network: canopen.Network, make_sim_node: Callable[..., SimulatedImuNode]
) -> Iterator[tuple[SimulatedImuNode, ImuClient]]:
    truth = Truth.from_dict({"serial": SERIAL, "sample_rate_hz": 200})
    node = make_sim_node(truth=truth, time_scale=TIME_SCALE, seed=7)
    client = _client(client_network)
    yield node, client
    client.close()


@pytest.fixture
def either_rig(
    client_network: canopen.Network,
    make_device: Callable[..., DeviceUnderTest],
    make_sim_node: Callable[..., SimulatedImuNode],
    device_kind: str,
) -> Iterator[tuple[DeviceUnderTest, ImuClient, float]]:
    """Either node (serial ``SERIAL``), a client, and the node's samples per wall second."""
    if device_kind == "simulated":
        truth = Truth.from_dict({"serial": SERIAL, "sample_rate_hz": 200})
        node = make_sim_node(truth=truth, time_scale=TIME_SCALE, seed=7)
        device = DeviceUnderTest(device_kind, node)
    else:
        device = make_device(serial=SERIAL)
    client = _client(client_network)
    yield device, client, 200.0 * (TIME_SCALE if device_kind == "simulated" else 1.0)
    client.close()


def _collect(client: ImuClient, n: int, timeout_s: float = 20.0) -> list[SampleBlock]:
    blocks: list[SampleBlock] = []
    deadline = time.monotonic() + timeout_s
    while sum(b.n for b in blocks) < n and time.monotonic() < deadline:
        block = client.get_block(0.2)
        if block is not None:
            blocks.append(block)
    assert sum(b.n for b in blocks) >= n, "stream stalled"
    return blocks


def _faulted_stream(
    node: SimulatedImuNode, client: ImuClient, n: int, **faults: Any
) -> SampleBlock:
    """Stream clean, inject ``faults`` for ``n`` samples, clean again; return everything."""
    client.start_streaming()
    blocks = _collect(client, 50)
    node.faults.set(**faults)
    blocks += _collect(client, n)
    node.faults.clear()
    blocks += _collect(client, 100)
    client.stop_streaming()
    while (block := client.get_block(0.1)) is not None:
        blocks.append(block)
    return concat_blocks(blocks)


def _missing_halves(b: SampleBlock) -> int:
    return b.lost_accel + b.lost_gyro + 2 * b.lost_samples


def _events(client: ImuClient, kind: type, timeout_s: float = 5.0) -> list[DeviceEvent]:
    """Wait for an event of ``kind``; return every event seen up to it."""
    seen: list[DeviceEvent] = []
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            seen.append(client.events.get(timeout=0.05))
        except queue.Empty:
            continue
        if isinstance(seen[-1], kind):
            return seen
    raise AssertionError(f"no {kind.__name__} within {timeout_s} s (saw {seen})")


# -- schema --------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("doc", "named"),
    [
        ({"tpdo_drop_fraction": 1.5}, "faults.tpdo_drop_fraction"),
        ({"tpdo_drop_fraction": "x"}, "faults.tpdo_drop_fraction"),
        ({"drop": 0.1}, "faults.drop: unknown key"),
        ({"sdo_aborts": [{"object": "2101"}]}, "faults.sdo_aborts[0].object"),
        ({"sdo_aborts": [{}]}, "faults.sdo_aborts[0].object: is required"),
        ({"sdo_aborts": {"object": "0x2101:01"}}, "faults.sdo_aborts: must be a JSON array"),
        ({"sdo_silent_mode": "loud"}, "faults.sdo_silent_mode"),
        ({"burst_loss": {"frames": 0}}, "faults.burst_loss.frames"),
        ({"heartbeat_loss": {"from_s": 5, "until_s": 1}}, "faults.heartbeat_loss.until_s"),
        ({"emergency": [{"code": 0x10000}]}, "faults.emergency[0]"),
        ({"reboot_at_s": float("nan")}, "faults.reboot_at_s"),
        ([], "faults: must be a JSON object"),
    ],
)
def test_bad_faults_block_names_the_key(doc: Any, named: str) -> None:
    with pytest.raises(InputError) as info:
        parse_faults(doc)
    assert str(info.value).startswith("truth: " + named) and "\n" not in str(info.value)
    with pytest.raises(InputError):  # the node refuses such a truth at construction
        FaultInjector(doc)


def test_faults_from_truth_json_reach_the_node(
    make_sim_node: Callable[..., SimulatedImuNode],
) -> None:
    truth = Truth.from_dict({"faults": {"tpdo_drop_fraction": 0.25, "seed": 3}})
    node = make_sim_node(truth=truth, start=False)
    assert node.faults.config.tpdo_drop_fraction == 0.25 and node.faults.config.seed == 3
    with pytest.raises(InputError, match="faults.seed"):
        make_sim_node(truth=Truth.from_dict({"faults": {"seed": -1}}), start=False)


# -- TPDO faults: every missing, repeated, late or malformed frame is counted ---------------


def test_dropped_and_burst_lost_frames_are_all_counted(
    rig: tuple[SimulatedImuNode, ImuClient],
) -> None:
    node, client = rig
    b = _faulted_stream(
        node, client, 3000, tpdo_drop_fraction=0.03, burst_loss={"probability": 0.003, "frames": 7}
    )
    dropped = node.faults.stats.count("dropped", T1, T2)
    assert dropped > 150  # ~3 % of ~6000 frames plus bursts: the fault really fired
    assert _missing_halves(b) == dropped
    assert b.lost_samples > 0  # bursts took both halves of whole samples
    assert b.duplicates == b.late == b.malformed == 0
    assert b.suspect


def test_duplicated_frames_are_counted_and_dropped(rig: tuple[SimulatedImuNode, ImuClient]) -> None:
    node, client = rig
    b = _faulted_stream(node, client, 2000, duplicate_fraction=0.05, seed=11)
    duplicated = node.faults.stats.count("duplicated", T1, T2)
    assert duplicated > 100
    assert b.duplicates == duplicated and _missing_halves(b) == 0
    counters = b.counter.tolist()
    assert len(set(counters)) == len(counters)  # no sample twice


def test_delayed_frames_are_counted_late_and_their_halves_lost(
    rig: tuple[SimulatedImuNode, ImuClient],
) -> None:
    node, client = rig
    b = _faulted_stream(node, client, 2000, delay_fraction=0.02, delay_frames=9, seed=12)
    delayed = node.faults.stats.count("delayed", T1, T2)
    assert delayed > 30
    # 9 frames ≈ 4 samples later: past the two-period pairing window, so each is late
    assert b.late == delayed and _missing_halves(b) == delayed


def test_short_frames_are_malformed_and_counted(rig: tuple[SimulatedImuNode, ImuClient]) -> None:
    node, client = rig
    b = _faulted_stream(node, client, 2000, wrong_length_fraction=0.03, seed=13)
    truncated = node.faults.stats
    assert truncated.count("truncated", T1, T2) > 60
    assert b.malformed == truncated.count("truncated", T1, T2, T3)
    assert _missing_halves(b) == truncated.count("truncated", T1, T2)


# -- SDO faults ----------------------------------------------------------------------------


def test_abort_on_a_chosen_object_at_the_kth_access(
    rig: tuple[SimulatedImuNode, ImuClient],
) -> None:
    node, client = rig
    node.faults.set(sdo_aborts=[{"object": "0x2010:03", "access": "read", "at_access": 2}])
    assert client.output_data_rate() == 200
    with pytest.raises(SdoAbort) as info:
        client.output_data_rate()
    assert info.value.exit_code == 3 and info.value.code == 0x08000020
    assert str(info.value).startswith(
        "device refused read of 0x2010:03: 0x08000020 data cannot be transferred or stored"
    )
    assert node.faults.stats.sdo_requests == 2  # an abort is never retried
    assert client.output_data_rate() == 200


def test_abort_after_n_writes(rig: tuple[SimulatedImuNode, ImuClient]) -> None:
    node, client = rig
    node.faults.set(sdo_aborts=[{"object": "0x1017:00", "after_writes": 2, "code": 0x06090030}])
    client.write_value(od.HEARTBEAT, 0, "u16", 500)
    client.write_value(od.HEARTBEAT, 0, "u16", 400)
    with pytest.raises(SdoAbort, match="value range of parameter exceeded"):
        client.write_value(od.HEARTBEAT, 0, "u16", 300)
    assert node.od_value(od.HEARTBEAT) == 400  # the refused write changed nothing


@pytest.mark.parametrize("mode", ["request", "response"])
def test_silent_server_retried_with_backoff_then_reported(
    rig: tuple[SimulatedImuNode, ImuClient], mode: str
) -> None:
    node, client = rig
    client.sdo = SdoChannel(client.node, 0.05, 2, backoff_s=0.03, boots=lambda: client.boots)
    node.faults.set(sdo_silent_after=1, sdo_silent_mode=mode)
    assert client.read_value(od.IDENTITY, 4, "u32") == SERIAL  # request 1 answered
    started = time.monotonic()
    with pytest.raises(DeviceSilentError) as info:
        client.read_value(od.IDENTITY, 4, "u32")
    elapsed = time.monotonic() - started
    assert str(info.value).startswith("no SDO answer to read of 0x1018:04 after 3 tries")
    assert info.value.exit_code == 3
    assert node.faults.stats.sdo_ignored == 3  # every retry reached the node
    # 3 timeouts of 0.05 s plus backoff 0.03 + 0.06 s; generous upper bound for a loaded box
    assert 0.22 <= elapsed < 2.0
    node.faults.clear()
    assert client.read_value(od.IDENTITY, 4, "u32") == SERIAL  # recovers when it answers again


# -- node events ---------------------------------------------------------------------------


def test_reboot_mid_stream_is_reported_and_streaming_resumes(
    either_rig: tuple[DeviceUnderTest, ImuClient, float],
) -> None:
    node, client, rate_hz = either_rig
    client.write_value(od.HEARTBEAT, 0, "u16", 250)  # not stored: gone after the reboot
    client.start_streaming()
    before = _collect(client, int(1.5 * rate_hz))  # the simulated node: past counter 1000
    boots = client.boots  # 1 when the client saw the first boot-up frame, else 0
    node.power_cycle()
    events = _events(client, NodeRebooted)
    # the boot-up frame goes out in INITIALISING; PRE-OPERATIONAL follows it on the node
    deadline = time.monotonic() + 2.0
    while node.nmt_state != "PRE-OPERATIONAL" and time.monotonic() < deadline:
        time.sleep(0.01)
    assert node.nmt_state == "PRE-OPERATIONAL"
    assert not any(isinstance(e, SerialChanged) for e in events)
    while (block := client.get_block(0.3)) is not None:  # drain what came before the reboot
        before.append(block)
    last_before = int(concat_blocks(before).counter[-1])
    client.resume_streaming()
    after = concat_blocks(_collect(client, int(0.5 * rate_hz)))
    client.stop_streaming()
    # counters restarted below the last one seen; the pairer followed instead of calling
    # every new sample late
    assert after.counter[0] < last_before
    assert after.late == after.duplicates == 0 and _missing_halves(after) == 0
    assert client.read_value(od.HEARTBEAT, 0, "u16") == 1000  # unsaved value gone
    assert client.boots == boots + 1


def test_emergency_is_reported_with_its_register(
    either_rig: tuple[DeviceUnderTest, ImuClient, float],
) -> None:
    node, client, rate_hz = either_rig
    client.start_streaming()
    _collect(client, int(rate_hz / 4))
    node.emcy(0x5000, 0x05)
    event = _events(client, EmergencyReceived)[-1]
    assert isinstance(event, EmergencyReceived)
    assert (event.code, event.register) == (0x5000, 0x05)
    assert event.text == "0x5000 device hardware (error register 0x05)"
    assert client.read_value(od.ERROR_REGISTER, 0, "u8") == 0x05
    n = int(rate_hz / 2)
    assert sum(b.n for b in _collect(client, n)) >= n  # streaming carries on
    client.stop_streaming()


def test_heartbeat_loss_and_return_are_reported(rig: tuple[SimulatedImuNode, ImuClient]) -> None:
    node, client = rig
    client.write_value(od.HEARTBEAT, 0, "u16", 100)
    assert client.watch_heartbeat() == pytest.approx(0.3)  # three periods
    now_s = node.simulator.time_s  # simulated: 4 s per wall second here
    node.faults.set(heartbeat_loss={"from_s": now_s + 0.4, "until_s": now_s + 8.0})
    lost = _events(client, HeartbeatLost)[-1]
    assert isinstance(lost, HeartbeatLost) and lost.timeout_s == pytest.approx(0.3)
    assert client.heartbeat.lost
    _events(client, HeartbeatResumed)
    assert not client.heartbeat.lost


def test_serial_change_after_reboot_is_reported(
    either_rig: tuple[DeviceUnderTest, ImuClient, float],
) -> None:
    node, client, _ = either_rig
    assert client.identity().serial == SERIAL
    node.reboot_as(SERIAL + 1)
    _events(client, NodeRebooted)
    assert client.identity().serial == SERIAL + 1
    changed = _events(client, SerialChanged)[-1]
    assert changed == SerialChanged(NODE_ID, SERIAL, SERIAL + 1)


def test_error_frames_are_reported_and_streaming_survives(
    rig: tuple[SimulatedImuNode, ImuClient],
) -> None:
    node, client = rig
    client.start_streaming()
    _collect(client, 100)
    now_s = node.simulator.time_s
    node.faults.set(error_frames_at_s=[now_s + 0.1, now_s + 0.2])
    _events(client, BusErrorReceived)
    b = concat_blocks(_collect(client, 400))
    client.stop_streaming()
    assert client.heartbeat.bus_errors >= 1 and node.faults.stats.error_frames == 2
    assert _missing_halves(b) == 0


def test_bus_that_raises_on_send(
    bus_channel: str, make_device: Callable[..., DeviceUnderTest]
) -> None:
    make_device(serial=SERIAL)
    faulty = FaultyBus(can.Bus(interface="virtual", channel=bus_channel))
    client = ImuClient(faulty, NODE_ID, sdo_timeout_s=0.2, sdo_retries=2, sdo_backoff_s=0.01)
    try:
        faulty.fail_sends(2)  # two transient failures: the third try goes through
        assert client.read_value(od.IDENTITY, 4, "u32") == SERIAL
        assert faulty.failed_sends == 2
        layout = client.pdo_mapping()
        client.observe_nmt_state()  # the state found, read before the bus goes off
        faulty.fail_sends(-1)  # bus off
        with pytest.raises(DeviceSilentError, match="bus-off"):
            client.read_value(od.IDENTITY, 4, "u32")
        with pytest.raises(DeviceError, match="cannot send NMT 0x01 to node 16"):
            client.start_streaming(layout=layout, rate_hz=200)
        assert client.consumer_thread is None  # nothing left half-started
        faulty.heal()
        assert client.read_value(od.IDENTITY, 4, "u32") == SERIAL
        client.start_streaming(layout=layout, rate_hz=200)
        assert client.read_samples(100, 5.0).n >= 100
    finally:
        client.close()
        faulty.shutdown()
