"""Duplicate sends against timer skew in the pairer (issue 24, case 3), synthetic frames.

A node with a second send trigger (CANopenNode's event timer beside data-ready sending)
sends a sample's TPDO1/TPDO2 again, unchanged, before the next sample: those are duplicate
sends, dropped from the rows and not a clock's skew. An event timer merely fast against the
sensor clock also repeats a counter now and then; at the clocks a node has (below
:data:`SECOND_TRIGGER_SHARE`) that stays a skew, measured as before.
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


def test_a_fast_timer_stays_a_skew() -> None:
    # an event timer 1 % fast against the sensor clock: a counter repeats every 100 ticks
    skew_ppm = -10000.0
    pairer = make_pairer()
    for k in range(SAMPLES):
        counter = int(np.floor(k * (1.0 + skew_ppm * 1e-6)))
        t = 1.0 + k * PERIOD_S * (1.0 + skew_ppm * 1e-6)
        pairer.feed(T1, accel_frame(counter), t)
        pairer.feed(T2, gyro_frame(counter), t)
    pairer.flush()
    block = pairer.take()
    assert block.duplicate_sends == block.duplicates == 2 * round(SAMPLES * 0.01)
    assert not pairer.second_trigger
    assert pairer.skew_ppm == pytest.approx(skew_ppm, abs=1e6 / SAMPLES)
    assert 0.01 < SECOND_TRIGGER_SHARE  # the share leaves room for clocks a node has


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
