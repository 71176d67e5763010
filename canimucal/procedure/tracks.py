"""What the procedure keeps per node: sample clock, stillness, the current attempt, rows.

Rows for the recording are handed out in arrival order by :meth:`NodeTrack.take_rows`: rows
outside an averaging attempt at once (no position), rows of an attempt only when it is
decided (accepted: labelled with the position; rejected or redone: no position), so the
recording never labels a rejected attempt and never goes back in time.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from canimucal.model.positions import Pose
from canimucal.model.samples import SampleBlock
from canimucal.model.sensor import STANDARD_GRAVITY
from canimucal.model.static import detect_disturbance
from canimucal.procedure.events import SamplesReceived
from canimucal.procedure.posecheck import FloorFit, measured_force
from canimucal.procedure.stillness import StillnessDetector

Array = NDArray[np.float64]
SPARK_POINTS = 50
"""Points of the sparkline (|f| − g of the latest blocks, one per block)."""
QUANTIZATION_STD = 1.0 / np.sqrt(12.0)
"""Smallest reference std (counts): a one-count quantizer's, so a flat axis scores sanely."""


@dataclass
class LabelledRows:
    """A piece of the recording: rows of one block and their position (-1: none)."""

    block: SampleBlock
    position: int = -1
    angles_deg: tuple[float, float, float] | None = None
    decided: bool = True


@dataclass
class Attempt:
    """Samples of the current averaging attempt (counts) and its losses."""

    accel: list[Array] = field(default_factory=list)
    gyro: list[Array] = field(default_factory=list)
    temps: list[float] = field(default_factory=list)
    samples: int = 0
    lost: int = 0
    chunk_accel: list[Array] = field(default_factory=list)
    chunk_gyro: list[Array] = field(default_factory=list)
    sums: RunningMeans = field(default_factory=lambda: RunningMeans())

    def rows(self) -> tuple[Array, Array]:
        """All accel and gyro rows so far."""
        accel = np.concatenate(self.accel) if self.accel else np.empty((0, 3))
        gyro = np.concatenate(self.gyro) if self.gyro else np.empty((0, 3))
        return accel, gyro


@dataclass
class RunningMeans:
    """Per-axis sums and counts of the finite rows of an attempt.

    Each chunk's motion test then costs O(chunk) however long the attempt has run
    (recomputing the mean over every row made a long attempt quadratic).
    """

    accel_sum: Array = field(default_factory=lambda: np.zeros(3))
    gyro_sum: Array = field(default_factory=lambda: np.zeros(3))
    accel_n: int = 0
    gyro_n: int = 0

    def add(self, accel: Array, gyro: Array) -> None:
        """Add a chunk's finite rows."""
        a = accel[np.all(np.isfinite(accel), axis=1)]
        g = gyro[np.all(np.isfinite(gyro), axis=1)]
        self.accel_sum = self.accel_sum + a.sum(axis=0)
        self.gyro_sum = self.gyro_sum + g.sum(axis=0)
        self.accel_n += a.shape[0]
        self.gyro_n += g.shape[0]

    def accel_mean(self) -> Array | None:
        """Mean of the accel rows so far (None below two rows)."""
        return self.accel_sum / self.accel_n if self.accel_n >= 2 else None

    def gyro_mean(self) -> Array | None:
        """Mean of the gyro rows so far (None below two rows)."""
        return self.gyro_sum / self.gyro_n if self.gyro_n >= 2 else None


def lost_in(block: SampleBlock) -> int:
    """Count the samples of a block that are not whole: counter gaps plus rows missing a half."""
    partial = int(np.sum(~np.all(np.isfinite(np.hstack((block.accel, block.gyro))), axis=1)))
    return int(block.lost_samples) + partial


class NodeTrack:
    """One node's state inside the procedure."""

    def __init__(
        self, node_id: int, sample_rate_hz: float, accel_lsb: float, gyro_lsb: float
    ) -> None:
        self.node_id = node_id
        self.sample_rate_hz = sample_rate_hz
        self.accel_lsb = accel_lsb
        self.gyro_lsb = gyro_lsb
        self.samples = 0
        self.lost_total = 0
        self.stillness = StillnessDetector(sample_rate_hz, accel_lsb)
        self.recent: list[SampleBlock] = []
        self.attempt: Attempt | None = None
        self.reference_std: tuple[Array, Array] | None = None
        self.floor = FloorFit(STANDARD_GRAVITY)
        """Floor slope and bias seen so far (the first accepted position sets the site's g)."""
        self.segments: list[LabelledRows] = []
        self.temp_c = float("nan")
        self.last_live_s = -np.inf
        self.spark: list[float] = []

    @property
    def time_s(self) -> float:
        """Sample time: samples seen (lost ones included) over the output data rate."""
        return self.samples / self.sample_rate_hz

    def advance(self, block: SampleBlock) -> int:
        """Move the sample clock by a block; return by how many samples."""
        step = block.n + int(block.lost_samples)
        self.samples += step
        self.lost_total += lost_in(block)
        if np.isfinite(block.temp_c):
            self.temp_c = float(block.temp_c)
        keep = int(2.0 * self.sample_rate_hz)
        self.recent = _tail(self.recent + [block], keep)
        return step

    def recent_rows(self, seconds: float) -> tuple[Array, Array]:
        """Accel and gyro rows of the latest ``seconds``."""
        n = max(2, round(seconds * self.sample_rate_hz))
        accel = np.concatenate([b.accel for b in self.recent])[-n:]
        gyro = np.concatenate([b.gyro for b in self.recent])[-n:]
        return accel, gyro

    def set_reference(self, seconds: float) -> None:
        """Per-sample std of the latest ``seconds`` (the settle window) for the motion test."""
        accel, gyro = self.recent_rows(seconds)
        std_a = np.nanstd(accel, axis=0, ddof=1)
        std_g = np.nanstd(gyro, axis=0, ddof=1) if np.isfinite(gyro).any() else np.ones(3)
        self.reference_std = (
            np.maximum(np.nan_to_num(std_a, nan=1.0), QUANTIZATION_STD),
            np.maximum(np.nan_to_num(std_g, nan=1.0), QUANTIZATION_STD),
        )

    def add_to_attempt(self, block: SampleBlock, step: int, chunk_n: int, k: float) -> bool:
        """Append a block to the attempt; return False when a full chunk shows motion."""
        attempt = self.attempt
        assert attempt is not None and self.reference_std is not None
        attempt.chunk_accel.append(block.accel)
        attempt.chunk_gyro.append(block.gyro)
        attempt.samples += step
        attempt.lost += lost_in(block)
        attempt.temps.append(float(block.temp_c))
        if sum(c.shape[0] for c in attempt.chunk_accel) < chunk_n:
            return True
        chunk_a = np.concatenate(attempt.chunk_accel)
        chunk_g = np.concatenate(attempt.chunk_gyro)
        attempt.chunk_accel, attempt.chunk_gyro = [], []
        sums = attempt.sums
        n_before = sums.accel_n
        disturbed = detect_disturbance(
            chunk_a,
            chunk_g if np.isfinite(chunk_g).any() else None,
            self.reference_std[0],
            self.reference_std[1],
            reference_mean_accel=sums.accel_mean(),
            reference_mean_gyro=sums.gyro_mean(),
            reference_n=n_before if n_before >= 2 else None,
            k=k,
        )
        attempt.accel.append(chunk_a)
        attempt.gyro.append(chunk_g)
        sums.add(chunk_a, chunk_g)
        return not disturbed

    def finish_attempt(self) -> tuple[Array, Array]:
        """Flush the last partial chunk into the attempt and return all its rows."""
        attempt = self.attempt
        assert attempt is not None
        attempt.accel += attempt.chunk_accel
        attempt.gyro += attempt.chunk_gyro
        attempt.chunk_accel, attempt.chunk_gyro = [], []
        return attempt.rows()

    @property
    def attempt_s(self) -> float:
        """Sample time of the current attempt."""
        return 0.0 if self.attempt is None else self.attempt.samples / self.sample_rate_hz

    def record(self, block: SampleBlock, *, undecided: bool) -> None:
        """Queue a block's rows for the recording (held while its attempt is undecided)."""
        self.segments.append(LabelledRows(block, decided=not undecided))

    def decide(self, position: int, angles_deg: tuple[float, float, float] | None) -> None:
        """Label the undecided rows with ``position`` (-1: rejected attempt)."""
        for seg in self.segments:
            if not seg.decided:
                seg.decided, seg.position, seg.angles_deg = True, position, angles_deg

    def take_rows(self) -> list[LabelledRows]:
        """Decided rows in arrival order, up to the first undecided piece."""
        out = []
        while self.segments and self.segments[0].decided:
            out.append(self.segments.pop(0))
        return out


def live_readout(
    track: NodeTrack, block: SampleBlock, target: Pose, g: float, period_s: float
) -> SamplesReceived | None:
    """Update the sparkline; every ``period_s`` of sample time, the live readout event."""
    if block.n and np.isfinite(block.accel).any():
        f = track.accel_lsb * np.nanmean(block.accel, axis=0)
        track.spark = (track.spark + [float(np.linalg.norm(f) - g)])[-SPARK_POINTS:]
    if track.time_s - track.last_live_s < period_s:
        return None
    track.last_live_s = track.time_s
    accel, gyro = track.recent_rows(period_s)
    mean_a = _nanmean(accel)
    tilt = None
    if np.all(np.isfinite(mean_a)) and np.any(mean_a):
        f = measured_force(mean_a, track.accel_lsb)
        floor = FloorFit(g) if track.floor.empty else track.floor
        tilt = floor.check(target, f, 0.0).tilt_error_deg
    return SamplesReceived(
        track.node_id,
        track.time_s,
        track.accel_lsb * mean_a,
        track.gyro_lsb * _nanmean(gyro),
        track.temp_c,
        tilt,
        track.stillness.moving_std_counts,
        tuple(track.spark),
        track.lost_total,
    )


def _nanmean(rows: Array) -> Array:
    finite = rows[np.all(np.isfinite(rows), axis=1)]
    return finite.mean(axis=0) if finite.shape[0] else np.full(3, np.nan)


def _tail(blocks: list[SampleBlock], keep: int) -> list[SampleBlock]:
    """Return the latest blocks holding at least ``keep`` rows."""
    total = 0
    for i in range(len(blocks) - 1, -1, -1):
        total += blocks[i].n
        if total >= keep:
            return blocks[i:]
    return blocks
