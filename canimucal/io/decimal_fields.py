"""Plain decimal CSV cells to float64, exactly and without a per-number string conversion.

A recording's rows are short decimals: counts (``-2024``), whole angles and times with six
decimals (``12.345000``). ``np.loadtxt`` converts each through a correctly rounded ``strtod``
(about 170 ns a number on the project's machine: most of a long file's read). Here a block of
rows is converted with whole-array numpy operations, to the same doubles:

- **The value is exact.** A cell ``[+-]digits[.digits]`` with at most :data:`MAX_DIGITS`
  digits is ``±m / 10^f``, ``m`` the integer its digits spell and ``f`` the digits after the
  point. ``m < 10^15 < 2^53`` is exact in uint64 and in float64, and ``10^f`` is an exact
  double; one IEEE division of two exact doubles is correctly rounded, so ``m / 10^f`` is the
  double nearest the decimal, which is what a correctly rounded ``strtod`` returns (Clinger
  1990, "How to read floating point numbers accurately": the fast path).
- **Eight digits at a time.** The eight bytes that end at a run of digits are read as one
  big-endian uint64 (the last digit in the low byte), the bytes before the run masked off,
  ``'0'`` taken from each byte by an xor, and a byte above 9 detected by adding ``0x76`` to
  every byte at once (it then reaches the byte's high bit). Three multiply-adds join the eight
  digits: pairs (``·10``), quads (``·100``), the two halves (``·10⁴``), the usual SWAR
  reduction. A cell's digits left of its point are a second run read the same way.

:func:`decimal_table` returns None for anything outside that form (an exponent, more digits,
a sign or point out of place, a row with another number of cells, an empty line): the caller
then parses the block the slow way, which also locates any error by line.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

MAX_DIGITS = 15
"""Digits a cell may carry for the exact path (``10^15 < 2^53``)."""

_WORD = 8
_LEAD = b"0" * (2 * _WORD)  # lets the words of the first cells start before the data
_TAIL = b"0"  # a byte to read at an empty last cell's start
_PLAIN_BYTES = b"0123456789+-.,\n"
_COMMA, _NEWLINE, _MINUS, _PLUS, _POINT = (ord(c) for c in ",\n-+.")

_U = np.uint64
_MASKS = np.array([(1 << (8 * n)) - 1 for n in range(_WORD + 1)], dtype=_U)
"""``_MASKS[n]``: the low ``n`` bytes of a word."""
_ZEROS = _U(0x3030303030303030)  # '0' in every byte
_ABOVE_NINE = _U(0x7676767676767676)  # added to bytes 0..0x3f: sets the high bit iff > 9
_HIGH_BITS = _U(0x8080808080808080)
_POW10 = 10.0 ** np.arange(MAX_DIGITS + 1)
_POW10_INT = np.array([10**k for k in range(MAX_DIGITS + 1)], dtype=_U)


def decimal_table(data: bytes, width: int) -> NDArray[np.float64] | None:
    """Parse ``data`` (rows of ``width`` cells, no final newline) into an ``(n, width)`` table.

    Empty cells are NaN. None when any cell is not a plain decimal of at most
    :data:`MAX_DIGITS` digits, any row does not have ``width`` cells, or any byte is not one
    of ``0-9 + - . ,`` and newline (module doc): nothing is guessed.
    """
    if not data or data.translate(None, _PLAIN_BYTES):
        return None
    buffer = _LEAD + data + _TAIL
    u = np.frombuffer(buffer, dtype=np.uint8)
    size = len(buffer) - len(_TAIL)
    separators = np.flatnonzero((u == _COMMA) | (u == _NEWLINE))
    cells = separators.size + 1
    rows = cells // width
    # width - 1 commas, then a newline, in every row (the data's end closes the last one)
    if cells % width or _count(u, _NEWLINE) != rows - 1:
        return None
    ends = np.append(separators, size)
    if rows > 1 and not bool((u[ends[width - 1 : -1 : width]] == _NEWLINE).all()):
        return None
    starts = np.empty_like(ends)
    starts[0], starts[1:] = len(_LEAD), separators + 1
    length = ends - starts
    first = u[starts]  # an empty cell's first byte is the separator after it
    negative = first == _MINUS
    signed = negative | (first == _PLUS)
    if _count(u, _MINUS) + _count(u, _PLUS) != int(np.count_nonzero(signed)):
        return None  # a sign that is not a cell's first byte
    words = np.ndarray((u.size - _WORD + 1,), dtype=">u8", buffer=buffer, strides=(1,))
    right = length - signed  # digits after the point (all of them without one)
    digits = right.copy()
    points = np.flatnonzero(u == _POINT)
    pointed = np.searchsorted(separators, points)  # the cell each point is in
    if pointed.size > 1 and not bool((np.diff(pointed) > 0).all()):
        return None  # two points in a cell
    right[pointed] = ends[pointed] - 1 - points
    left = points - starts[pointed] - signed[pointed]
    digits[pointed] = left + right[pointed]
    if int(digits.max()) > MAX_DIGITS or bool(((digits == 0) & (length > 0)).any()):
        return None  # too many digits, or a sign or point alone
    mantissa = _digits_value(words, ends, right)
    if mantissa is None:
        return None
    if points.size:
        left_value = _digits_value(words, points, left)
        if left_value is None:
            return None
        mantissa[pointed] += left_value * _POW10_INT[right[pointed]]
    table = mantissa.astype(np.float64)
    if points.size:
        table[pointed] /= _POW10[right[pointed]]
    table[length == 0] = np.nan
    np.negative(table, out=table, where=negative)
    return table.reshape(rows, width)


def _count(u: NDArray[np.uint8], byte: int) -> int:
    """Count ``byte`` in ``u`` (5x faster than ``bytes.count`` here)."""
    return int(np.count_nonzero(u == byte))


def _digits_value(
    words: NDArray[np.uint64], end: NDArray[np.int64], count: NDArray[np.int64]
) -> NDArray[np.uint64] | None:
    """Return the integers the ``count`` (≤ 16) bytes before each ``end`` spell, or None."""
    value = _word_value(words, end, np.minimum(count, _WORD))
    if value is None:
        return None
    long = np.flatnonzero(count > _WORD)
    if long.size:
        high = _word_value(words, end[long] - _WORD, count[long] - _WORD)
        if high is None:
            return None
        value[long] += high * _U(10**_WORD)
    return value


def _word_value(
    words: NDArray[np.uint64], end: NDArray[np.int64], count: NDArray[np.int64]
) -> NDArray[np.uint64] | None:
    """Return the integers of the ``count`` (≤ 8) bytes before each ``end`` (module doc)."""
    mask = _MASKS[count]
    x = words[end - _WORD]
    if x.dtype != mask.dtype:  # a little-endian machine: the same values in native order
        x.byteswap(inplace=True)
        x = x.view(_U)
    x &= mask
    mask &= _ZEROS
    x ^= mask
    np.add(x, _ABOVE_NINE, out=mask)
    mask &= _HIGH_BITS
    if bool(mask.any()):
        return None
    for shift, lanes, scale in _JOINS:  # the temporaries reuse one buffer
        np.right_shift(x, shift, out=mask)
        mask &= lanes
        mask *= scale
        x &= lanes
        x += mask
    return x


_JOINS = (
    (_U(8), _U(0x00FF00FF00FF00FF), _U(10)),
    (_U(16), _U(0x0000FFFF0000FFFF), _U(100)),
    (_U(32), _U(0x00000000FFFFFFFF), _U(10000)),
)
"""SWAR joins: digit pairs, then quads, then the two halves of a word (module doc)."""
