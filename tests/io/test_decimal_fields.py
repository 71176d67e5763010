"""The column-wise decimal parser against Python's own correctly rounded ``float``.

Python's ``float(str)`` is an independent correctly rounded conversion (David Gay's
``strtod``): every plain decimal the fast path accepts must give the same double, bit for
bit, sign of zero included; everything else must be declined (None) so the slow path, which
locates errors by line, sees it.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from canimucal.io.decimal_fields import MAX_DIGITS, decimal_table
from canimucal.io.recording import parse_rows


def reference(rows: list[list[str]]) -> np.ndarray:
    return np.array([[float(c) if c else math.nan for c in row] for row in rows], dtype=float)


@st.composite
def plain_decimal(draw: st.DrawFn) -> str:
    digits = draw(st.text("0123456789", min_size=1, max_size=MAX_DIGITS))
    sign = draw(st.sampled_from(["", "", "-", "+"]))
    point = draw(st.none() | st.integers(0, len(digits)))
    body = digits if point is None else digits[:point] + "." + digits[point:]
    return sign + body


cell = st.one_of(plain_decimal(), st.just(""), st.integers(-40000, 40000).map(str))


@st.composite
def table_text(draw: st.DrawFn) -> tuple[list[list[str]], int]:
    width = draw(st.integers(1, 14))
    rows = draw(st.lists(st.lists(cell, min_size=width, max_size=width), min_size=1, max_size=40))
    return rows, width


def same_bits(a: np.ndarray, b: np.ndarray) -> bool:
    return a.shape == b.shape and bool(np.array_equal(a.view(np.int64), b.view(np.int64)))


@settings(max_examples=400, deadline=None)
@given(table_text())
def test_plain_decimals_are_the_correctly_rounded_doubles(
    case: tuple[list[list[str]], int],
) -> None:
    rows, width = case
    text = "\n".join(",".join(row) for row in rows).encode()
    if width == 1 and any(row == [""] for row in rows):
        return  # an empty one-cell row is an empty line: declined, tested below
    table = decimal_table(text, width)
    assert table is not None
    # NaN has one bit pattern here (np.nan): compare bits, so -0.0 and 0.0 differ
    assert same_bits(table, reference(rows))


@pytest.mark.parametrize(
    "cell, value",
    [
        ("-0", -0.0),
        ("-0.000", -0.0),
        ("+7", 7.0),
        (".5", 0.5),
        ("5.", 5.0),
        ("007", 7.0),
        ("0.1", 0.1),
        ("123456789012345", 123456789012345.0),
        (".000000000000001", 1e-15),
        ("99999.999999999", 99999.999999999),
    ],
)
def test_edge_cells(cell: str, value: float) -> None:
    table = decimal_table(f"1,{cell}\n{cell},2".encode(), 2)
    assert table is not None
    assert same_bits(table, np.array([[1.0, value], [value, 2.0]]))


@pytest.mark.parametrize(
    "text",
    [
        "1,2e3",  # an exponent: the slow path reads it
        "1,2E3",
        "1,1234567890123456",  # 16 digits: beyond the exact fast path
        "1,--2",
        "1,2-3",
        "1,+-2",
        "1,.",
        "1,-",
        "1,-.",
        "1,1.2.3",
        "1, 2",
        "1,2,3",  # a row with 3 cells
        "1,2\n\n3,4",  # an empty line
        "1,2\n3",  # a short last row
        "1\n2,3",
        "1,nan",
    ],
)
def test_anything_else_is_declined(text: str) -> None:
    assert decimal_table(text.encode(), 2) is None


def test_declined_blocks_are_still_read_or_located_by_the_slow_path() -> None:
    width = 13
    row = ",".join(["1.5"] * width)
    long_row = ",".join(["0.30000000000000004"] + ["1e2"] * (width - 1))
    table = parse_rows(f"{row}\n{long_row}\n".encode(), 5, "f.csv", width)
    assert table[1, 0] == 0.30000000000000004 and table[1, 1] == 100.0
    bad = f"{row}\n{row}\n{row.replace('1.5', '1.5.1', 1)}\n".encode()
    with pytest.raises(Exception, match=r"f\.csv:7"):
        parse_rows(bad, 5, "f.csv", width)
