"""Long recordings at a cost bounded per position (issue 23 item 2).

The settling fit reads each position's opening window only, and the replay simulates a
bounded number of samples per position with the same statistics; `analyze` of a long
recording therefore runs, and its replay reproduces the measurement.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

import canimucal.analysis.replay as replay_module
from canimucal.analysis.replay import REPLAY_SAMPLES_PER_POSITION, replay, replay_ratios
from canimucal.analysis.report import analyse_recording
from canimucal.analysis.settling import OPENING_S, fit_settling
from canimucal.analysis.simulated import simulate_plan_recording
from canimucal.io.grouping import position_averages
from canimucal.model.vocabulary.plans import builtin_plan
from canimucal.sim.truth import Truth


def _windows(rng: np.random.Generator, seconds: float, tau: float) -> list[Any]:
    """Eight windows at 100 Hz, white σ = 3, a transient of 3σ-units per axis."""
    out = []
    for p in range(8):
        t = np.arange(int(seconds * 100)) / 100.0 + 1000.0 * p
        x = rng.normal(0.0, 3.0, (t.size, 3))
        x += np.exp(-(t - t[0]) / tau)[:, None] * rng.normal(0.0, 9.0, 3)
        out.append((t, x))
    return out


def test_settling_reads_only_the_opening_window() -> None:
    rng = np.random.default_rng(231)
    long = _windows(rng, 10 * OPENING_S, 1.5)  # 960 000 samples
    opening = [(t[t - t[0] <= OPENING_S], x[t - t[0] <= OPENING_S]) for t, x in long]
    a, b = fit_settling(long), fit_settling(opening)
    assert a.found and a.tau_ci95_s[0] <= 1.5 <= a.tau_ci95_s[1]
    assert a.tau_s == pytest.approx(b.tau_s, rel=1e-9)
    assert a.statistic == pytest.approx(b.statistic, rel=1e-9)
    np.testing.assert_allclose(a.amplitude, b.amplitude, rtol=1e-9)
    np.testing.assert_allclose(a.trim_s, b.trim_s, rtol=1e-9)


def test_a_replay_at_a_lower_rate_has_the_same_statistics() -> None:
    truth = Truth.random(np.random.default_rng(232), cross_axis_max=0.0, tilt_max_deg=0.0)
    plan = builtin_plan("recommended").with_total_seconds(8 * 60.0)
    full = position_averages(simulate_plan_recording(truth, plan, seed=5, angle_errors=False))
    low = simulate_plan_recording(truth, plan, seed=5, angle_errors=False, sample_rate_hz=25.0)
    assert low.sample_rate_hz == 25.0
    reduced = position_averages(low)
    for f, r in zip(full, reduced, strict=True):
        assert r.n < f.n / 7
        # the mean's variance from 1 500 samples: 3.7 % relative sd, 5 sd allowed
        np.testing.assert_allclose(np.diag(r.cov_accel), np.diag(f.cov_accel), rtol=0.2)
        assert r.cov_gyro is not None and f.cov_gyro is not None
        np.testing.assert_allclose(np.diag(r.cov_gyro), np.diag(f.cov_gyro), rtol=0.2)
        # the means agree within their σ (5σ of the difference)
        sd = np.sqrt(np.diag(r.cov_accel) + np.diag(f.cov_accel))
        assert np.all(np.abs(r.mean_accel - f.mean_accel) < 5 * sd)


def test_analyze_of_a_long_recording_replays_a_bounded_number_of_samples(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    truth = Truth.random(np.random.default_rng(233), cross_axis_max=0.0)
    plan = builtin_plan("recommended").with_total_seconds(8 * 125.0)  # 2×10⁵ rows at 200 Hz
    rec = simulate_plan_recording(truth, plan, seed=7)
    assert rec.n_rows > 200_000
    simulated_rows: list[int] = []

    def counted(*args: Any, **kwargs: Any) -> Any:
        out = simulate_plan_recording(*args, **kwargs)
        simulated_rows.append(out.n_rows)
        return out

    monkeypatch.setattr(replay_module, "simulate_plan_recording", counted)
    a = analyse_recording(rec, g=truth.g, latitude=truth.latitude, heading=truth.heading)
    rows = replay(a)
    assert rows is not None and len(simulated_rows) == 6
    moves = 8 * 2.0 * REPLAY_SAMPLES_PER_POSITION / 125.0  # the 2 s moves at the replay's rate
    assert max(simulated_rows) <= 8 * REPLAY_SAMPLES_PER_POSITION + moves + 16  # rounding
    ratios = replay_ratios(rows)
    assert ratios is not None
    low, high = ratios["rms_ratio_ci95"]
    assert low <= 1.0 <= high, ratios  # the extended replay reproduces the measurement
