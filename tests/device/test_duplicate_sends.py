"""Duplicate sends against timer skew in the pairer (issue 24, case 3), synthetic frames.

A node with a second send trigger (CANopenNode's event timer beside data-ready sending)
sends a sample's TPDO1/TPDO2 again, unchanged, before the next sample: those are duplicate
sends, dropped from the rows and not a clock's skew. Its event timer restarts at every send,
so it fires only when a data-ready send comes late: at a share set by the node's jitter (CI's
VM once 2 %), with the late sample close behind its copy. An event timer merely fast against
the sensor clock also repeats a counter now and then, but sends evenly; that stays a skew,
measured as before.
"""

from __future__ import annotations

import numpy as np
import pytest

from canimucal.device.stream import SECOND_TRIGGER_SHARE
from tests.device.test_stream import PERIOD_S, T1, T2, accel_frame, gyro_frame, make_pairer

SAMPLES = 2000


@pytest.mark.parametrize("fraction", [1.0, 0.3])
@pytest.mark.parametrize("delay_periods", [0.2, 0.6, 0.97])
def test_a_second_send_trigger_is_duplicate_sends_not_skew(
    fraction: float, delay_periods: float
) -> None:
    # ``fraction`` of the samples go out again ``delay_periods`` after the first copy
    rng = np.random.default_rng(24)
    pairer = make_pairer()
    again = rng.random(SAMPLES) < fraction
    for c in range(SAMPLES):
        t = 10.0 + c * PERIOD_S
        xyz = tuple(int(v) for v in rng.integers(-2000, 2000, 3))
        frames = [(T1, accel_frame(c, xyz)), (T2, gyro_frame(c))]
        for cob, data in frames:
            pairer.feed(cob, data, t)
        if again[c]:
            for cob, data in frames:
                pairer.feed(cob, data, t + delay_periods * PERIOD_S)
    pairer.flush()
    block = pairer.take()
    repeated = int(np.sum(again))
    assert block.duplicate_sends == block.duplicates == 2 * repeated
    assert block.n == SAMPLES and np.all(np.diff(block.counter) == 1)  # kept out of the rows
    assert block.lost_samples == block.lost_accel == block.lost_gyro == 0
    assert pairer.second_trigger and pairer.skew_ppm is None


@pytest.mark.parametrize("share", [0.01, 0.02, 0.035])
def test_a_second_trigger_fired_by_late_sends_is_not_skew(share: float) -> None:
    # CANopenNode's event timer (one period) beside data-ready sending: when the send of
    # sample c+1 comes late by 2-20 % of a period, the timer sends sample c again first
    rng = np.random.default_rng(2401)
    pairer = make_pairer()
    late = rng.random(SAMPLES) < share
    for c in range(SAMPLES):
        t = 10.0 + c * PERIOD_S
        if late[c]:
            t_copy = t  # the timer, a period after c-1's send
            if c > 0:
                pairer.feed(T1, accel_frame(c - 1), t_copy)
                pairer.feed(T2, gyro_frame(c - 1), t_copy)
            t += rng.uniform(0.02, 0.2) * PERIOD_S
        pairer.feed(T1, accel_frame(c), t)
        pairer.feed(T2, gyro_frame(c), t)
    pairer.flush()
    block = pairer.take()
    repeated = int(np.sum(late[1:]))
    assert block.duplicate_sends == 2 * repeated and repeated < SECOND_TRIGGER_SHARE * SAMPLES
    assert block.n == SAMPLES and block.lost_samples == 0
    assert pairer.second_trigger and pairer.skew_ppm is None


@pytest.mark.parametrize("skew_ppm", [-10000.0, -30000.0])
@pytest.mark.parametrize("jitter_periods", [0.0, 0.2])
def test_a_fast_timer_stays_a_skew(skew_ppm: float, jitter_periods: float) -> None:
    # an event timer 1 % or 3 % fast against the sensor clock (an RC oscillator's), frames
    # received with or without ±20 % of a period of jitter: a counter repeats every 100 or
    # 33 ticks, each a timer period after the frame before, as every frame is
    rng = np.random.default_rng(2402)
    pairer = make_pairer()
    for k in range(SAMPLES):
        counter = int(np.floor(k * (1.0 + skew_ppm * 1e-6)))
        t = 1.0 + k * PERIOD_S * (1.0 + skew_ppm * 1e-6)
        t += rng.uniform(-jitter_periods, jitter_periods) * PERIOD_S
        pairer.feed(T1, accel_frame(counter), t)
        pairer.feed(T2, gyro_frame(counter), t)
    pairer.flush()
    block = pairer.take()
    assert block.duplicate_sends == block.duplicates == 2 * round(SAMPLES * -skew_ppm * 1e-6)
    assert not pairer.second_trigger
    assert pairer.skew_ppm == pytest.approx(skew_ppm, abs=1e6 / SAMPLES)
    assert 0.03 < SECOND_TRIGGER_SHARE  # the share leaves room for clocks a node has


def test_a_repeated_counter_with_other_data_is_no_duplicate_send() -> None:
    pairer = make_pairer()
    for c in range(300):
        t = 10.0 + c * PERIOD_S
        pairer.feed(T1, accel_frame(c), t)
        pairer.feed(T2, gyro_frame(c), t)
        if c % 2:  # the same counter again, other values: a counter that did not advance
            pairer.feed(T1, accel_frame(c, (9, 9, 9)), t + 0.5 * PERIOD_S)
    pairer.flush()
    block = pairer.take()
    assert block.duplicates == 150 and block.duplicate_sends == 0
    assert not pairer.second_trigger
    np.testing.assert_array_equal(block.accel[1], [1, -2, 2048])  # the first copy is kept
