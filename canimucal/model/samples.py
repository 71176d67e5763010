"""Blocks of paired IMU samples: what the CAN client hands over and the procedure consumes.

Pure data (numpy arrays and counts): the client builds blocks from TPDO pairs
(:mod:`canimucal.device.stream`), the procedure and the recorder read them.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray


@dataclass(frozen=True)
class SampleBlock:
    """Paired samples in counter order, with the stream's losses over the same span.

    ``t`` is the CAN timestamp of TPDO2 (TPDO1's when TPDO2 was lost); ``accel``/``gyro`` are
    raw counts with NaN rows for a lost half. The counts cover what was finalized into this
    block: ``lost_samples`` counter gaps (both halves missing), ``duplicates`` and ``late``
    halves dropped, ``malformed`` frames (wrong length) dropped. ``duplicate_sends`` are the
    duplicates that repeat their sample exactly (the node sent the same frame again).
    """

    t: NDArray[np.float64]
    counter: NDArray[np.int64]
    accel: NDArray[np.float64]
    gyro: NDArray[np.float64]
    temp_c: float
    status: int | None
    lost_accel: int
    lost_gyro: int
    lost_samples: int
    duplicates: int
    late: int
    malformed: int = 0
    duplicate_sends: int = 0

    @property
    def suspect(self) -> bool:
        """Whether anything was lost, repeated, late or malformed over this block's span."""
        return bool(
            self.lost_accel + self.lost_gyro + self.lost_samples + self.duplicates + self.late
        ) or bool(self.malformed)

    @property
    def n(self) -> int:
        """Number of samples (rows)."""
        return int(self.t.shape[0])

    @classmethod
    def empty(cls) -> SampleBlock:
        """Return a block of no samples and no losses."""
        return cls(
            np.zeros(0),
            np.zeros(0, np.int64),
            np.zeros((0, 3)),
            np.zeros((0, 3)),
            float("nan"),
            None,
            0,
            0,
            0,
            0,
            0,
        )


def concat_blocks(blocks: Sequence[SampleBlock]) -> SampleBlock:
    """One block holding ``blocks`` in order (counts summed, latest temperature)."""
    if not blocks:
        return SampleBlock.empty()
    return SampleBlock(
        np.concatenate([b.t for b in blocks]),
        np.concatenate([b.counter for b in blocks]),
        np.concatenate([b.accel for b in blocks]),
        np.concatenate([b.gyro for b in blocks]),
        blocks[-1].temp_c,
        blocks[-1].status,
        sum(b.lost_accel for b in blocks),
        sum(b.lost_gyro for b in blocks),
        sum(b.lost_samples for b in blocks),
        sum(b.duplicates for b in blocks),
        sum(b.late for b in blocks),
        sum(b.malformed for b in blocks),
        sum(b.duplicate_sends for b in blocks),
    )
