"""Per-axis averaging optima, the common time chosen from them, and the noise terms' intervals."""

from __future__ import annotations

import numpy as np
import pytest

from canimucal.model.noise import (
    NoiseTerms,
    allan_deviation,
    axis_optima_s,
    choose_averaging,
    fit_noise,
    noise_intervals,
)


def _terms(n: list[float], q: list[float]) -> NoiseTerms:
    z = np.zeros(3)
    return NoiseTerms(np.array(n, float), z, np.array(q, float), z, z)


def test_axis_optima_are_where_the_fitted_adev_is_least() -> None:
    t = _terms([1.0, 2.0, 1.0], [0.05, 0.0, 0.01])
    best = axis_optima_s(t)
    assert best[1] == np.inf
    for axis in (0, 2):
        taus = best[axis] * np.array([0.9, 1.0, 1.1])
        adev = t.adev(taus)[:, axis]
        assert adev[1] < adev[0] and adev[1] < adev[2]


def test_one_drifting_axis_limits_the_time_and_is_named() -> None:
    # gyro z drifts (optimum √3·1/0.05 = 34.6 s); every other axis is white (no optimum)
    terms = {
        "accel": _terms([1.0, 1.0, 1.0], [0.0, 0.0, 0.0]),
        "gyro": _terms([1.0, 1.0, 1.0], [0.0, 0.0, 0.05]),
    }
    choice = choose_averaging(terms)
    assert choice.limiting_axis == "gyro.z"
    assert choice.optima_s["gyro"][2] == pytest.approx(np.sqrt(3) / 0.05)
    assert 34.6 < choice.seconds < 120.0
    # the old rule (largest optimum, 120 s) costs gyro z far more than the minimax time does
    at_120 = terms["gyro"].adev([120.0])[0, 2] / terms["gyro"].adev([34.64])[0, 2]
    assert at_120 > 1.25
    assert choice.loss["gyro"][2] < at_120
    assert max(float(np.max(v)) for v in choice.loss.values()) == pytest.approx(
        choice.loss["gyro"][2], rel=0.03
    )


def test_white_axes_take_the_upper_clip_and_equal_optima_their_own() -> None:
    white = choose_averaging({"accel": _terms([1.0, 2.0, 3.0], [0.0, 0.0, 0.0])})
    assert white.seconds == pytest.approx(120.0)
    same = choose_averaging({"accel": _terms([1.0, 2.0, 3.0], [0.0433, 0.0866, 0.1299])})
    assert same.seconds == pytest.approx(40.0, rel=0.01)
    assert np.allclose(same.loss["accel"], 1.0, atol=1e-3)


def test_noise_intervals_cover_the_simulated_terms() -> None:
    fs, n = 100.0, 30000
    density = np.array([2.0, 3.0, 1.5])
    walk = np.array([0.2, 0.0, 0.1])
    covered_n = covered_q = 0
    for seed in range(8):
        rng = np.random.default_rng(1400 + seed)
        x = rng.normal(0.0, 1.0, (n, 3)) * density * np.sqrt(fs)
        x += np.cumsum(rng.normal(0.0, 1.0, (n, 3)), axis=0) * walk / np.sqrt(fs)
        allan = allan_deviation(x, fs)
        ci = noise_intervals(allan, fit_noise(allan))
        covered_n += int(np.sum((ci.white_noise_density[:, 0] <= density)
                                & (density <= ci.white_noise_density[:, 1])))  # fmt: skip
        covered_q += int(np.sum((ci.random_walk[:, 0] <= walk) & (walk <= ci.random_walk[:, 1])))
        assert np.all(ci.bias_instability[:, 0] <= ci.bias_instability[:, 1])
    # 24 nominal 95 % intervals each: fewer than 21 covering has binomial probability < 1 %
    assert covered_n >= 21 and covered_q >= 21


@pytest.mark.parametrize("kind", ["white+walk", "held", "filtered", "hump"])
def test_every_interval_holds_its_estimate_and_is_ordered(kind: str) -> None:
    """Issue 21 item 11: also where the three-term model misfits (held, filtered, a hump)."""
    fs, n = 100.0, 20000
    for seed in range(6):
        rng = np.random.default_rng(2100 + seed)
        x = rng.normal(0.0, 3.0, (n, 3)) + np.cumsum(rng.normal(0.0, 0.02, (n, 3)), axis=0)
        if kind == "held":  # a 25 Hz sensor logged at 100 Hz
            x = np.repeat(x[::4], 4, axis=0)
        elif kind == "filtered":
            box = np.ones(8) / 8.0
            x = np.column_stack([np.convolve(x[:, i], box, "same") for i in range(3)])
        elif kind == "hump":  # a Gauss–Markov bias, T = 5 s
            phi = np.exp(-1.0 / (5.0 * fs))
            b = np.zeros((n, 3))
            for i in range(1, n):
                b[i] = phi * b[i - 1] + rng.normal(0.0, 0.05, 3)
            x += b
        allan = allan_deviation(x, fs)
        terms = fit_noise(allan)
        ci = noise_intervals(allan, terms)
        for value, band in (
            (terms.white_noise_density, ci.white_noise_density),
            (terms.random_walk, ci.random_walk),
            (terms.bias_instability, ci.bias_instability),
        ):
            assert np.all(band[:, 0] <= band[:, 1])
            assert np.all((band[:, 0] <= value) & (value <= band[:, 1])), (seed, value, band)
        if kind == "white+walk":
            assert np.all(ci.widening == 1.0)  # the band needs no widening where the model holds
