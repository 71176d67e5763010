"""TPDO decoding and pairing: synthetic frames (exact) and both IMU nodes (live).

The live tests run against the simulated node (sped up by its ``time_scale``) and the
independent durand node (real time, so it streams for longer to see as many samples).
"""

from __future__ import annotations

import struct
import time
import uuid
from collections.abc import Callable, Iterator
from dataclasses import dataclass

import can
import canopen
import numpy as np
import pytest

from canimucal.device.client import ImuClient
from canimucal.device.stream import (
    PdoLayout,
    SamplePairer,
    layout_from_mapping,
)
from canimucal.model.samples import SampleBlock, concat_blocks
from tests.support.nodes import DeviceUnderTest, node_on
from tests.support.pdo import design_layout

NODE = 0x10
T1, T2, T3 = 0x180 + NODE, 0x280 + NODE, 0x380 + NODE
PERIOD_S = 0.005


def entry(index: int, sub: int, bits: int) -> int:
    return (index << 16) | (sub << 8) | bits


INT16_MAPPING = {
    1: [entry(0x2000, 1, 16), entry(0x2000, 2, 16), entry(0x2000, 3, 16), entry(0x2002, 2, 16)],
    2: [entry(0x2001, 1, 16), entry(0x2001, 2, 16), entry(0x2001, 3, 16), entry(0x2002, 2, 16)],
    3: [entry(0x2002, 1, 16), entry(0x2002, 2, 16), entry(0x2002, 3, 8)],
}
COB_IDS = {1: T1, 2: T2, 3: T3}


def accel_frame(counter: int, xyz: tuple[int, int, int] = (1, -2, 2048)) -> bytes:
    return struct.pack("<hhhH", *xyz, counter % 65536)


def gyro_frame(counter: int, xyz: tuple[int, int, int] = (-5, 6, 7)) -> bytes:
    return struct.pack("<hhhH", *xyz, counter % 65536)


def make_pairer() -> SamplePairer:
    return SamplePairer(layout_from_mapping(COB_IDS, INT16_MAPPING), PERIOD_S)


def feed_pairs(
    pairer: SamplePairer,
    counters: range | list[int],
    *,
    skip: Callable[[int, str], bool] = lambda c, h: False,
    t0: float = 1000.0,
) -> None:
    for i, c in enumerate(counters):
        t = t0 + i * PERIOD_S
        if not skip(c, "accel"):
            pairer.feed(T1, accel_frame(c), t)
        if not skip(c, "gyro"):
            pairer.feed(T2, gyro_frame(c), t + 1e-4)


def test_pairs_complete_samples_in_order_with_tpdo2_time() -> None:
    pairer = make_pairer()
    feed_pairs(pairer, range(10))
    block = pairer.take()
    assert block.n == 10
    assert list(block.counter) == list(range(10))
    np.testing.assert_array_equal(block.accel[0], [1, -2, 2048])
    np.testing.assert_array_equal(block.gyro[3], [-5, 6, 7])
    np.testing.assert_allclose(block.t, 1000.0 + np.arange(10) * PERIOD_S + 1e-4)
    assert (block.lost_accel, block.lost_gyro, block.lost_samples) == (0, 0, 0)
    assert (block.duplicates, block.late) == (0, 0)


def test_lost_gyro_half_gives_nan_and_tpdo1_time() -> None:
    pairer = make_pairer()
    feed_pairs(pairer, range(6), skip=lambda c, h: c == 4 and h == "gyro")
    # sample 4 waits two sample periods for its TPDO2; 5, complete, waits behind it (order)
    assert pairer.take().n == 4
    feed_pairs(pairer, [6], t0=1000.0 + 6 * PERIOD_S)
    block = pairer.take()
    assert list(block.counter) == [4, 5, 6]
    assert block.lost_gyro == 1 and block.lost_accel == 0
    assert np.all(np.isnan(block.gyro[0])) and not np.any(np.isnan(block.accel[0]))
    assert block.t[0] == pytest.approx(1000.0 + 4 * PERIOD_S)  # TPDO1's time


def test_lost_accel_half_counted() -> None:
    pairer = make_pairer()
    feed_pairs(pairer, range(8), skip=lambda c, h: c == 3 and h == "accel")
    pairer.flush()
    block = pairer.take()
    assert block.n == 8 and block.lost_accel == 1 and block.lost_gyro == 0
    assert np.all(np.isnan(block.accel[3]))
    assert list(block.counter) == list(range(8))


def test_counter_gap_counts_lost_samples() -> None:
    pairer = make_pairer()
    feed_pairs(pairer, [0, 1, 2, 6, 7])
    block = pairer.take()
    assert block.lost_samples == 3  # counters 3, 4, 5: both halves missing
    assert list(block.counter) == [0, 1, 2, 6, 7]


def test_a_block_counts_only_the_losses_inside_its_own_span() -> None:
    """A gap is counted with the row after it, in the block that holds that row.

    Under heavy loss the row after a gap can still be waiting for its partner when a block
    is taken; its gap then belongs to the next block (rows + lost = the block's span).
    """
    pairer = make_pairer()
    feed_pairs(pairer, range(5))
    pairer.feed(T1, accel_frame(9), 1000.0 + 9 * PERIOD_S)  # 5..8 lost; 9 waits for TPDO2
    first = pairer.take()
    assert list(first.counter) == list(range(5))
    assert first.n + first.lost_samples == 5
    pairer.feed(T2, gyro_frame(9), 1000.0 + 9 * PERIOD_S + 1e-4)
    second = pairer.take()
    assert list(second.counter) == [9] and second.lost_samples == 4


def test_counter_wraps_at_65536() -> None:
    pairer = make_pairer()
    feed_pairs(pairer, list(range(65530, 65536)) + list(range(0, 6)))
    block = pairer.take()
    assert block.n == 12 and block.lost_samples == 0
    assert list(block.counter[:7]) == [65530, 65531, 65532, 65533, 65534, 65535, 0]


def test_duplicates_and_late_halves_counted_not_hidden() -> None:
    pairer = make_pairer()
    feed_pairs(pairer, range(5), skip=lambda c, h: c == 2 and h == "gyro")
    pairer.feed(T1, accel_frame(4), 2000.0)  # duplicate of a paired half
    pairer.feed(T2, gyro_frame(2), 2000.0)  # sample 2 was given up: late
    block = pairer.take()
    assert block.duplicates == 1 and block.late == 1
    assert block.lost_gyro == 1
    assert block.n == 5  # nothing emitted twice


def test_stream_joined_mid_sample_starts_at_first_tpdo1() -> None:
    pairer = make_pairer()
    pairer.feed(T2, gyro_frame(99), 1.0)
    feed_pairs(pairer, range(100, 104))
    block = pairer.take()
    assert block.n == 4 and block.lost_accel == 0 and block.lost_gyro == 0


def test_expire_gives_up_a_half_after_stall() -> None:
    pairer = make_pairer()
    pairer.feed(T1, accel_frame(0), 10.0)
    pairer.expire(10.0 + 0.1)
    assert pairer.ready == 0  # within the stall grace
    pairer.expire(10.0 + pairer.stall_s + 0.01)
    block = pairer.take()
    assert block.n == 1 and block.lost_gyro == 1


def test_temperature_and_status_from_tpdo3() -> None:
    pairer = make_pairer()
    pairer.feed(T3, struct.pack("<hHB", 2534, 0, 0x04), 1.0)
    feed_pairs(pairer, range(2))
    block = pairer.take()
    assert block.temp_c == pytest.approx(25.34) and block.status == 0x04


def test_int32_mapping_decodes() -> None:
    mapping = {
        1: [entry(0x2000, s, 32) for s in (1, 2)],
        2: [entry(0x2001, s, 16) for s in (1, 2, 3)] + [entry(0x2002, 2, 16)],
    }
    # INT32 fields use struct; odd bit widths use the generic bit decoder.
    layout = PdoLayout.from_entries(T1, mapping[1])
    assert layout.decode(struct.pack("<ii", -70000, 70000)) == (-70000, 70000)
    full = PdoLayout.from_entries(
        T1, [entry(0x2000, 1, 32), entry(0x2000, 2, 12), entry(0x2000, 3, 12), entry(0x2002, 2, 8)]
    )
    raw = (-5 & 0xFFFFFFFF) | ((-3 & 0xFFF) << 32) | ((100 & 0xFFF) << 44) | (200 << 56)
    assert full.decode(raw.to_bytes(8, "little")) == (-5, -3, 100, 200)
    assert full.size_bytes == 8


def test_int32_sample_layout_pairs() -> None:
    mapping = {
        1: [entry(0x2000, s, 16) for s in (1, 2, 3)] + [entry(0x2002, 2, 16)],
        2: [entry(0x2001, 1, 32), entry(0x2001, 2, 8), entry(0x2001, 3, 8), entry(0x2002, 2, 16)],
    }
    pairer = SamplePairer(layout_from_mapping({1: T1, 2: T2}, mapping), PERIOD_S)
    pairer.feed(T1, accel_frame(5), 1.0)
    pairer.feed(T2, struct.pack("<ibbH", -100000, -7, 9, 5), 1.0)
    block = pairer.take()
    np.testing.assert_array_equal(block.gyro[0], [-100000, -7, 9])


def test_short_frame_is_dropped_and_counted() -> None:
    pairer = make_pairer()
    pairer.feed(T1, accel_frame(0)[:5], 1.0)
    feed_pairs(pairer, range(1, 3))
    assert pairer.malformed == 1 and pairer.take().n == 2


def test_layout_without_counter_is_refused() -> None:
    mapping = {1: INT16_MAPPING[1][:3], 2: INT16_MAPPING[2]}
    with pytest.raises(ValueError, match="counter"):
        layout_from_mapping(COB_IDS, mapping)


def test_concat_blocks_sums_counts() -> None:
    pairer = make_pairer()
    feed_pairs(pairer, [0, 1, 5])
    first = pairer.take()
    feed_pairs(pairer, [6, 7], t0=2000.0)
    second = pairer.take()
    joined = concat_blocks([first, second])
    assert joined.n == first.n + second.n and joined.lost_samples == 3
    assert isinstance(concat_blocks([]), SampleBlock)


# --------------------------------------------------------------- live, against either node


class DroppingNetwork(canopen.Network):
    """Client-side network dropping the received frames ``drop`` selects (a bus-level shim)."""

    def __init__(self, bus: can.BusABC) -> None:
        super().__init__(bus)
        self.drop: Callable[[int, bytes], bool] = lambda can_id, data: False
        self.dropped: list[tuple[int, int]] = []  # (cob_id, counter)

    def notify(self, can_id: int, data: bytearray, timestamp: float) -> None:
        if self.drop(can_id, bytes(data)):
            self.dropped.append((can_id, int.from_bytes(bytes(data[6:8]), "little")))
            return
        super().notify(can_id, data, timestamp)


TIME_SCALE = {"simulated": 5.0, "independent": 1.0}
"""Device seconds per wall second: the simulated node's 200 Hz data at 1 kHz wall."""
WALL_S = {"simulated": 1.5, "independent": 3.0}
"""Streaming time of a live test: ≥ 500 samples from either node."""


@dataclass
class Live:
    client: ImuClient
    network: DroppingNetwork
    node: DeviceUnderTest
    time_scale: float
    wall_s: float


@pytest.fixture
def live(device_kind: str) -> Iterator[Live]:
    channel = f"h6b-stream-{uuid.uuid4().hex}"
    buses = [can.Bus(interface="virtual", channel=channel) for _ in range(2)]
    client_net = DroppingNetwork(buses[1])
    client_net.NOTIFIER_CYCLE = 0.05
    client_net.connect()
    scale = TIME_SCALE[device_kind]
    node = node_on(device_kind, buses[0], NODE, sim_options={"time_scale": scale, "seed": 11})
    client = ImuClient(client_net, NODE, sdo_timeout_s=0.5)
    yield Live(client, client_net, node, scale, WALL_S[device_kind])
    client.close()
    node.stop()
    assert client_net.notifier is not None
    client_net.notifier.stop()
    for bus in buses:
        bus.shutdown()


def stream_for(client: ImuClient, wall_s: float) -> SampleBlock:
    client.start_streaming()
    blocks = []
    deadline = time.monotonic() + wall_s
    while time.monotonic() < deadline:
        block = client.get_block(0.1)
        if block is not None:
            blocks.append(block)
    client.stop_streaming()
    while (block := client.get_block(0.5)) is not None:
        blocks.append(block)
    return concat_blocks(blocks)


def test_live_stream_rate_and_continuous_counters(live: Live) -> None:
    block = stream_for(live.client, live.wall_s)
    expected_hz = 200.0 * live.time_scale
    span_s = block.t[-1] - block.t[0]
    rate_hz = (block.n - 1) / span_s
    # the node paces its sends at the scaled rate; 25 % leaves room for a loaded machine
    assert 0.75 * expected_hz < rate_hz < 1.25 * expected_hz
    assert block.n > 0.5 * live.wall_s * expected_hz
    steps = np.diff(block.counter) % 65536
    assert np.all(steps == 1)  # the virtual bus never drops a frame
    assert (block.lost_accel, block.lost_gyro, block.lost_samples) == (0, 0, 0)
    assert (block.duplicates, block.late) == (0, 0)
    assert not np.isnan(block.accel).any() and not np.isnan(block.gyro).any()
    assert np.all(np.diff(block.t) >= 0)
    # level pose: body y senses -g, about -2048 counts at the nominal ±16 g LSB
    assert np.mean(block.accel[:, 1]) == pytest.approx(-2048, abs=30)
    assert block.temp_c == pytest.approx(25.0, abs=1.0)


def test_live_lost_halves_and_gaps_counted_exactly(live: Live) -> None:
    net = live.network
    layout_ids = (0x180 + NODE, 0x280 + NODE)

    def drop(can_id: int, data: bytes) -> bool:
        if can_id not in layout_ids:
            return False
        counter = int.from_bytes(data[6:8], "little")
        if counter % 97 == 3:
            return True  # both halves: a counter gap
        return can_id == layout_ids[1] and counter % 50 == 7  # a lost TPDO2 half

    net.drop = drop
    block = stream_for(live.client, live.wall_s)
    seq = block.counter[0] + np.concatenate([[0], np.cumsum(np.diff(block.counter) % 65536)])
    inside = np.arange(seq[0], seq[-1] + 1) % 65536
    gaps = inside % 97 == 3
    expected_lost_gyro = int(np.sum((inside % 50 == 7) & ~gaps))
    assert expected_lost_gyro >= 5 and int(gaps.sum()) >= 5  # the test can fail
    assert block.lost_samples == int(gaps.sum())
    assert block.lost_gyro == expected_lost_gyro and block.lost_accel == 0
    assert block.n == len(inside) - int(gaps.sum())
    lost_rows = np.isnan(block.gyro).all(axis=1)
    assert np.all(block.counter[lost_rows] % 50 == 7)
    assert (block.duplicates, block.late) == (0, 0)


def test_design_layout_is_the_mapping_of_design_and_of_both_nodes(
    client_network: canopen.Network, make_device: Callable[..., DeviceUnderTest]
) -> None:
    assert design_layout(NODE) == layout_from_mapping(COB_IDS, INT16_MAPPING)
    make_device()
    client = ImuClient(client_network, NODE)
    client.find_node(2.0)
    assert client.pdo_mapping() == design_layout(NODE)


def test_mapping_longer_than_a_classic_frame_is_refused() -> None:
    int32_xyz = [entry(0x2000, s, 32) for s in (1, 2, 3)] + [entry(0x2002, 2, 16)]
    with pytest.raises(ValueError, match=r"112 bits \(14 bytes\); a classic CAN frame holds 8"):
        layout_from_mapping(COB_IDS, {1: int32_xyz, 2: INT16_MAPPING[2]})


@pytest.mark.parametrize("skew_ppm", [5000.0, -5000.0, 0.0])
def test_skew_from_an_event_timer_off_the_sensor_clock(skew_ppm: float) -> None:
    # each event-timer tick sends the sample current then: the counter of tick k is
    # floor(k·(1 + skew)); jitter of ±20 % of a period and one frame pair lost on the bus
    rng = np.random.default_rng(11)
    pairer = make_pairer()
    ticks = 2000
    for k in range(ticks):
        if k == 700:
            continue  # lost on the bus
        counter = int(np.floor(k * (1.0 + skew_ppm * 1e-6)))
        t = 1.0 + k * PERIOD_S * (1.0 + skew_ppm * 1e-6) + rng.uniform(-0.2, 0.2) * PERIOD_S
        pairer.feed(T1, accel_frame(counter), t)
        pairer.feed(T2, gyro_frame(counter), t)
    pairer.flush()
    block = pairer.take()
    assert pairer.skew_ppm is not None
    assert pairer.skew_ppm == pytest.approx(skew_ppm, abs=1e6 / ticks)
    if skew_ppm < 0:  # repeated counters: both halves again, duplicates, never losses
        assert block.duplicates == 2 * round(-skew_ppm * 1e-6 * ticks)
        assert block.lost_accel == block.lost_gyro == 0 and block.lost_samples <= 1
