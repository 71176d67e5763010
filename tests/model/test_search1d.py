"""model/search1d.py: the golden-section maximum and the Illinois root, against closed forms."""

from __future__ import annotations

import math

import pytest

from canimucal.model.search1d import maximise_bounded, root_bracketed

CASES = [(0.3, 0.0, 1.0), (1e-4, 0.0, 1e-3), (5.0, 4.9, 7.0)]


@pytest.mark.parametrize(("peak", "lo", "hi"), CASES)
def test_the_maximum_is_found_within_its_tolerance(peak: float, lo: float, hi: float) -> None:
    def f(t: float) -> float:
        return -math.cosh((t - peak) / (hi - lo))  # smooth, unimodal, flat near the top

    x = maximise_bounded(f, lo, hi, xtol=1e-6 * (hi - lo))
    assert abs(x - peak) <= 1e-6 * (hi - lo)
    # a smooth maximum is located to about √ε of its width at best: f is flat there
    x = maximise_bounded(f, lo, hi, xtol=1e-12 * (hi - lo))
    assert abs(x - peak) <= 1e-7 * (hi - lo)


def test_a_maximum_at_an_end_is_approached() -> None:
    x = maximise_bounded(lambda t: t, 0.0, 2.0, xtol=1e-10)
    assert 2.0 - 1e-7 <= x <= 2.0  # within 2·tol = 2(√ε·|x| + xtol/3) of the end


@pytest.mark.parametrize(
    ("f", "lo", "hi", "root"),
    [
        (lambda t: t**3 - 2.0, 0.0, 3.0, 2.0 ** (1 / 3)),
        (lambda t: math.exp(t) - 10.0, -5.0, 5.0, math.log(10.0)),
        (lambda t: 1.0 - 1e6 * t * t, 0.0, 1.0, 1e-3),  # steep: plain regula falsi stalls here
    ],
)
def test_the_root_is_found_within_its_tolerance(f, lo: float, hi: float, root: float) -> None:  # noqa: ANN001
    x = root_bracketed(f, lo, hi, xtol=1e-12)
    assert abs(x - root) <= 1e-11


def test_no_sign_change_is_refused() -> None:
    with pytest.raises(ValueError, match="same sign"):
        root_bracketed(lambda t: t * t + 1.0, -1.0, 1.0, 1e-9)
