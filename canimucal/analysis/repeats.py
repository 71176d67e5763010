"""Repeated samples: a sensor logged faster than it samples (docs/design.md §6, data quality).

A logger that polls a 100 Hz sensor at 400 Hz writes each sample about four times: most rows
repeat the row before in every sensor channel while ``t`` and the counter advance. Taken as
they are, such rows make every σ of a mean too small (by the square root of the repeat
factor) and distort the Allan deviation. They are told apart from a quiet, coarsely quantised
sensor, whose channels also repeat but each on its own: under independence the fraction of
rows where *every* channel repeats is the product of the channels' own fractions; a hold
repeats them all at once, far more often than that product.

:func:`unique_samples` keeps the first row of every run of repeats, sets the header's
``sample_rate_hz`` to the effective rate and says so in one line; n, σ and the Allan
deviation are then those of the unique samples.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from canimucal.io.recording import Recording

log = logging.getLogger(__name__)


MIN_REPEAT_FRACTION = 0.1
"""Rows repeating the previous one in every channel must be at least this fraction."""
INDEPENDENCE_FACTOR = 2.0
"""…and at least this many times the fraction independent channels would give."""


@dataclass(frozen=True)
class HeldSamples:
    """How many of ``rows`` repeat the row before in every sensor channel, and the rates."""

    rows: int
    repeated: int
    rate_hz: float
    effective_hz: float

    @property
    def fraction(self) -> float:
        """Share of the rows that repeat the previous one."""
        return self.repeated / self.rows

    def line(self) -> str:
        """Return the one line the reports print."""
        unique = self.rows - self.repeated
        return (
            f"{100 * self.fraction:.0f} % of samples repeat the previous one: effective rate "
            f"~{self.effective_hz:.3g} Hz (logged at {self.rate_hz:.3g} Hz); σ and Allan use the "
            f"1 of {self.rows / unique:.2g} unique samples"
        )


def _sensor_columns(rec: Recording) -> list[NDArray[np.float64]]:
    """Return the sensors the file has (accel, gyro: those with any finite sample)."""
    return [x for x in (rec.accel, rec.gyro) if np.isfinite(x).any()]


REPEAT_CHUNK_ROWS = 1 << 20
"""Rows compared at a time by :func:`repeated_rows` (its temporaries do not grow with the file)."""


def repeated_rows(rec: Recording) -> tuple[NDArray[np.bool_], HeldSamples | None]:
    """Rows equal to the row before in every sensor channel, and the verdict on them.

    The verdict is None when the repeats are what independent channels give by chance (a
    quiet sensor's quantisation) or too few to matter (:data:`MIN_REPEAT_FRACTION`).
    Compared :data:`REPEAT_CHUNK_ROWS` rows at a time, the channels' equal and finite pairs
    counted as they pass.
    """
    sensors = _sensor_columns(rec)
    n = rec.n_rows
    same = np.zeros(n, dtype=bool)
    if n < 3 or not sensors:
        return same, None
    channels = 3 * len(sensors)
    equal_pairs = np.zeros(channels, dtype=np.int64)
    finite_pairs = np.zeros(channels, dtype=np.int64)
    for start in range(1, n, REPEAT_CHUNK_ROWS):
        stop = min(n, start + REPEAT_CHUNK_ROWS)
        rows = np.ones(stop - start, dtype=bool)
        for k, x in enumerate(sensors):
            now, before = x[start:stop], x[start - 1 : stop - 1]
            equal = now == before  # NaN is never equal: a lost half is no repeat
            rows &= np.all(equal, axis=1)
            both = np.isfinite(now) & np.isfinite(before)
            equal_pairs[3 * k : 3 * k + 3] += np.count_nonzero(equal & both, axis=0)
            finite_pairs[3 * k : 3 * k + 3] += np.count_nonzero(both, axis=0)
        same[start:stop] = rows
    joint = float(np.count_nonzero(same[1:])) / (n - 1)
    seen = finite_pairs > 0
    per_channel = equal_pairs[seen] / finite_pairs[seen]
    independent = float(np.prod(per_channel)) if per_channel.size else 0.0
    if joint < MIN_REPEAT_FRACTION or joint < INDEPENDENCE_FACTOR * independent:
        return same, None
    repeated = int(np.count_nonzero(same))
    rate = rec.sample_rate_hz
    held = HeldSamples(rec.n_rows, repeated, rate, rate * (rec.n_rows - repeated) / rec.n_rows)
    return same, held


def unique_samples(rec: Recording) -> tuple[Recording, HeldSamples | None]:
    """Return ``rec`` without its held repeats (effective rate in the header), and the verdict.

    ``rec`` itself when its repeats are chance (see :func:`repeated_rows`).
    """
    same, held = repeated_rows(rec)
    if held is None:
        return rec, None
    log.info("%s: %s", rec.source or "recording", held.line())
    keep = np.flatnonzero(~same)
    header = dict(rec.header)
    header["sample_rate_hz"] = held.effective_hz
    reduced = replace(rec.take_rows(keep), header=header)
    return reduced, held
