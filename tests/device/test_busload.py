"""Bus load meter: the bit count of known frames, the window, and a live node of either kind."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import can
import canopen
import pytest

from canimucal.device.busload import (
    DEFAULT_BITRATE_BPS,
    ERROR_FRAME_BITS,
    BusLoadMeter,
    frame_bits,
)
from canimucal.device.client import ImuClient
from tests.support.nodes import DeviceUnderTest

NODE_ID = 0x10


def message(n: int, *, extended: bool = False, **kwargs: object) -> can.Message:
    arbitration_id = 0x1234567 if extended else 0x190
    return can.Message(
        arbitration_id=arbitration_id, data=bytes(n), is_extended_id=extended, **kwargs
    )


@pytest.mark.parametrize(
    ("frame", "bits"),
    [
        (message(8), 135),  # 47 + 64 + floor(97 / 4): the textbook worst case
        (message(0), 55),  # 47 + floor(33 / 4)
        (message(1), 65),  # heartbeat: 47 + 8 + floor(41 / 4)
        (message(6), 115),  # 47 + 48 + floor(81 / 4)
        (message(8, extended=True), 160),  # 67 + 64 + floor(117 / 4)
        (message(0, extended=True), 80),
    ],
)
def test_frame_bits_of_known_frames(frame: can.Message, bits: int) -> None:
    assert frame_bits(frame) == bits


def test_remote_and_error_frames() -> None:
    remote = can.Message(arbitration_id=0x710, is_remote_frame=True, dlc=8, is_extended_id=False)
    assert frame_bits(remote) == 55  # no data field on the wire
    assert frame_bits(can.Message(is_error_frame=True)) == ERROR_FRAME_BITS


class FakeClock:
    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


def test_window_fraction_rate_and_error_frames() -> None:
    clock = FakeClock()
    meter = BusLoadMeter(clock=clock)
    assert meter.bitrate_bps == DEFAULT_BITRATE_BPS and meter.bitrate_assumed
    clock.t += 0.5
    assert meter.load().window_s == pytest.approx(0.5)  # younger than the window
    clock.t += 0.5
    for _ in range(100):
        clock.t += 0.005
        meter.on_message_received(message(8))
    meter.on_message_received(can.Message(is_error_frame=True))
    load = meter.load()
    assert load.window_s == pytest.approx(1.0)
    assert load.frames_per_s == pytest.approx(101.0)
    assert load.fraction == pytest.approx((100 * 135 + ERROR_FRAME_BITS) / 500_000)
    assert load.error_frames == 1 and load.error_frames_total == 1
    assert "(assumed)" in load.text() and "1 error frames" in load.text()
    clock.t += 1.5  # everything leaves the window; the total stays
    load = meter.load()
    assert load.frames_per_s == 0.0 and load.fraction == 0.0 and load.error_frames == 0
    assert load.error_frames_total == 1 and meter.frames_total == 101
    known = BusLoadMeter(250_000, clock=clock)
    assert not known.bitrate_assumed
    assert known.load().text().startswith("bus load: 0.0 % of 250 kbit/s (0 frames/s")
    with pytest.raises(ValueError, match="bitrate"):
        BusLoadMeter(0)


def test_counts_every_identifier(open_bus: Callable[[], can.BusABC]) -> None:
    listen, talk = open_bus(), open_bus()
    meter = BusLoadMeter()
    notifier = can.Notifier(listen, [meter], timeout=0.05)
    try:
        frames = [message(2), message(8, extended=True), message(0)] * 5
        for frame in frames:
            talk.send(frame)
        deadline = time.monotonic() + 2.0
        while meter.frames_total < len(frames) and time.monotonic() < deadline:
            time.sleep(0.01)
    finally:
        notifier.stop()
    assert meter.frames_total == 15
    expected = 5 * (75 + 160 + 55) / DEFAULT_BITRATE_BPS
    load = meter.load()
    assert load.fraction * load.window_s == pytest.approx(expected)


def test_live_node_streaming_at_200_hz(
    client_network: canopen.Network,
    make_device: Callable[..., DeviceUnderTest],
    bus_frames: Any,
) -> None:
    make_device()  # either node: TPDO1/2 on 5 ms event timers, TPDO3 on 100 ms
    client = ImuClient(client_network, NODE_ID, sdo_timeout_s=0.5, bitrate_bps=500_000)
    try:
        assert client.output_data_rate() == 200
        client.start_streaming()
        time.sleep(1.4)  # the window now holds streaming only (no SDO answers)
        load = client.bus_load()
    finally:
        client.close()
    # TPDO1 + TPDO2 at 200 Hz, TPDO3 at 10 Hz, heartbeat at 1 Hz
    expected_rate = 2 * 200 + 10 + 1
    assert load.window_s == pytest.approx(1.0)
    assert load.frames_per_s == pytest.approx(expected_rate, rel=0.1)
    assert load.error_frames == 0 and not load.bitrate_assumed
    dlc = {f.cob_id: len(f.data) for f in bus_frames.frames()}
    tpdo1, tpdo2, tpdo3 = (base + NODE_ID for base in (0x180, 0x280, 0x380))
    bits = (
        200 * (frame_bits(message(dlc[tpdo1])) + frame_bits(message(dlc[tpdo2])))
        + 10 * frame_bits(message(dlc[tpdo3]))
        + frame_bits(message(1))
    )
    assert load.fraction == pytest.approx(bits / 500_000, rel=0.1)
