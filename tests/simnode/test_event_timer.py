"""The simulated node's TPDO event timer on a clock of its own (truth ``timer_skew_ppm``)."""

from __future__ import annotations

import pytest

from canimucal.simnode.pdo import EventTimer

PERIOD_S = 0.005  # 200 Hz, TPDO1/2 event timer 5 ms


def _ticks_per_sample(skew_ppm: float, samples: int = 10_000) -> list[list[float]]:
    timer = EventTimer()
    period = PERIOD_S * (1.0 + skew_ppm * 1e-6)
    return [timer.ticks(k * PERIOD_S, period, PERIOD_S) for k in range(samples)]


@pytest.mark.parametrize("skew_ppm", [5000.0, 1000.0, -1000.0, -5000.0])
def test_a_skewed_timer_skips_or_repeats_one_sample_per_million_over_ppm(skew_ppm: float) -> None:
    ticks = _ticks_per_sample(skew_ppm)
    counts = [len(t) for t in ticks]
    expected = 10_000 * abs(skew_ppm) * 1e-6  # 50 or 10 in 50 s
    if skew_ppm > 0:  # slow: some samples have no tick (their counters are skipped)
        assert set(counts) == {0, 1} and abs(counts.count(0) - expected) <= 1
    else:  # fast: some samples go out twice
        assert set(counts) == {1, 2} and abs(counts.count(2) - expected) <= 1
    offsets = [o for t in ticks for o in t]
    assert all(0.0 <= o < PERIOD_S for o in offsets)  # each tick before the next sample
    # the tick times themselves are the timer's own grid: anchor + k·period
    times = [k * PERIOD_S + o for k, t in enumerate(ticks) for o in t]
    period = PERIOD_S * (1.0 + skew_ppm * 1e-6)
    assert times == pytest.approx([k * period for k in range(len(times))], abs=1e-9)


def test_without_skew_every_sample_ticks_once_on_time() -> None:
    assert all(t == [0.0] for t in _ticks_per_sample(0.0, 2000))


def test_a_timer_late_by_more_than_a_period_starts_again() -> None:
    timer = EventTimer()
    assert timer.ticks(0.0, 0.00501, PERIOD_S) == [0.0]
    assert timer.ticks(1.0, 0.00501, PERIOD_S) == [0.0]  # a 1 s gap (slipped clock): no burst
    assert timer.next_due_s == pytest.approx(1.00501)
