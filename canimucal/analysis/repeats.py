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


def _sensor_columns(rec: Recording) -> NDArray[np.float64]:
    """Return the sensor channels the file has (accel, gyro: those with any finite sample)."""
    parts = [x for x in (rec.accel, rec.gyro) if np.isfinite(x).any()]
    return np.hstack(parts) if parts else np.empty((rec.n_rows, 0))


def repeated_rows(rec: Recording) -> tuple[NDArray[np.bool_], HeldSamples | None]:
    """Rows equal to the row before in every sensor channel, and the verdict on them.

    The verdict is None when the repeats are what independent channels give by chance (a
    quiet sensor's quantisation) or too few to matter (:data:`MIN_REPEAT_FRACTION`).
    """
    x = _sensor_columns(rec)
    same = np.zeros(rec.n_rows, dtype=bool)
    if rec.n_rows < 3 or x.shape[1] == 0:
        return same, None
    equal = x[1:] == x[:-1]  # NaN is never equal: a lost half is no repeat
    same[1:] = np.all(equal, axis=1)
    joint = float(np.mean(same[1:]))
    both = np.isfinite(x[1:]) & np.isfinite(x[:-1])
    per_channel = [float(np.mean(equal[b, c])) for c, b in enumerate(both.T) if b.any()]
    independent = float(np.prod(per_channel)) if per_channel else 0.0
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
