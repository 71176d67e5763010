"""Record sample blocks of IMU nodes into recording CSVs (docs/design.md §5), labelled by position.

One :class:`Recorder` drives one or more nodes (one :class:`~canimucal.device.client.ImuClient`
and one :class:`~canimucal.io.recording_writer.RecordingWriter` each) and writes **every** sample it
receives: rows of a static position carry its index and angles (degrees), all others (waiting
for the operator, settling, moving) leave them empty. ``t`` is the CAN receive time, the
``counter`` column the node's sample counter; a lost PDO half stays empty.

Three ways to label:

- :meth:`Recorder.record_pose`: the unit is at the pose now (after ``prepare``, e.g. the
  operator pressed Enter): skip ``settle_s`` worth of samples, then label the next
  ``seconds`` worth. Sample counts, not wall time, so a fast simulated node works too.
- :meth:`Recorder.record_prompted`: a whole plan, :meth:`record_pose` per position with a
  ``prompt(index, position)`` callback that returns when the unit is there. With a
  ``refused`` callback each pose is checked first, as the guided procedure checks it
  (:meth:`Recorder.check_pose`: the accelerometer's direction, and the turn the gyro
  measured since the last recorded position, :meth:`Recorder.check_moves`): a unit not at
  the pose, or a turn that was not made, is refused and prompted again.
- :meth:`Recorder.record_scheduled`: the unit follows the plan by itself from the NMT start
  (``canimucal sim --poses``, the in-process simulated node, a motorised rig): each sample's
  schedule time is its counter distance from the first sample over the output data rate, and
  it is labelled when the schedule holds the same position ``guard_s`` before and after it.
"""

from __future__ import annotations

import logging
import queue
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from canimucal.device.client import ImuClient
from canimucal.device.events import NodeRebooted
from canimucal.device.start_check import refused_start
from canimucal.errors import DeviceError, InputError
from canimucal.io.recording_writer import RecordingWriter
from canimucal.model.positions import Plan, PlannedPosition
from canimucal.model.samples import SampleBlock, concat_blocks
from canimucal.model.sensor import STANDARD_GRAVITY
from canimucal.model.vocabulary.constants import COUNTER_MODULUS, OUTPUT_DATA_RATES_HZ
from canimucal.procedure.config import ProcedureConfig
from canimucal.procedure.movecheck import MoveCheck, MoveTracker
from canimucal.procedure.posecheck import FloorFit, PoseCheck, measured_force
from canimucal.sim.schedule import PoseTrajectory

log = logging.getLogger(__name__)

POLL_S = 0.05
"""How long one wait for a block from one node may take."""
DEFAULT_IDLE_TIMEOUT_S = 5.0
"""A node that sends no sample for this long has stopped: DeviceError."""
WRITE_ROWS = 200
WRITE_INTERVAL_S = 0.5
"""Blocks (20 ms each) are labelled and written in batches of this many rows or seconds:
the per-write overhead is what a slow (emulated) machine cannot afford 50 times a second."""
DEFAULT_GUARD_S = 0.5
RATE_CHECK_S = 2.0
"""The sample rate is measured over the first 2 s of CAN receive times."""
RATE_TOLERANCE = 0.1
"""A measured rate further than 10 % from the claimed one replaces it (with a warning)."""
"""Schedule mode: samples within this (schedule) time of a move are not labelled."""

PosePrompt = Callable[[int, PlannedPosition], None]
"""Called before position ``index``; returns when the unit is at the pose."""
PoseRefused = Callable[[int, str], None]
"""Called with position ``index`` and why, when the unit is not at that pose."""
CHECK_WINDOW_S = 0.5
"""Samples averaged for the pose check (after the settling)."""
POSE_TOLERANCE_DEG = ProcedureConfig.pose_tolerance_deg
FIRST_POSE_TOLERANCE_DEG = ProcedureConfig.first_pose_tolerance_deg
"""The guided procedure's tolerances: the first pose (no floor slope known yet) and the others."""
MOVE_TOLERANCE_DEG = ProcedureConfig.move_tolerance_deg
"""The guided procedure's tolerance of the gyro's move check."""


@dataclass
class NodeTally:
    """What one node's stream delivered: rows written, labelled, and losses (never hidden)."""

    node_id: int
    rows: int = 0
    labelled: int = 0
    lost_samples: int = 0
    lost_accel: int = 0
    lost_gyro: int = 0
    duplicates: int = 0
    late: int = 0
    duplicate_sends: int = 0
    """Duplicates that repeated their sample exactly: the node sent the frame again."""
    reboots: int = 0
    skew_ppm: float | None = None
    """The node's TPDO event timer against its sample clock, ppm (the client's latest
    estimate, :attr:`~canimucal.device.client.ImuClient.skew_ppm`); None: not measured."""
    second_trigger: bool = False
    """The node sent its samples twice (duplicate sends, no clock): no skew is claimed."""

    def add(self, block: SampleBlock) -> None:
        """Add a block's loss counts."""
        self.lost_samples += block.lost_samples
        self.lost_accel += block.lost_accel
        self.lost_gyro += block.lost_gyro
        self.duplicates += block.duplicates
        self.late += block.late
        self.duplicate_sends += block.duplicate_sends


class _Track:
    """One node: its client, writer, unwrapped counter and labelling state."""

    def __init__(self, client: ImuClient, writer: RecordingWriter, rate_hz: float) -> None:
        self.client = client
        self.writer = writer
        self.rate_hz = rate_hz
        self.tally = NodeTally(client.node_id)
        self.seq_last: int | None = None
        self.seq0: int | None = None
        self.last_t = -np.inf
        self.last_data = time.monotonic()
        self.skip = 0
        self.remaining = 0
        self.index = -1
        self.angles_deg = np.full(3, np.nan)
        self.was_operational = False
        self.pending: list[SampleBlock] = []
        self.pending_rows = 0
        self.malformed = 0
        self.last_write = time.monotonic()
        self.check_rate = False
        """Measure the rate (off for simulated nodes on a scaled clock: CAN times lie)."""
        self.rate_measured = False
        self.rate_t0 = 0.0  # CAN time of the first sample, counter and samples since
        self.rate_counter: int | None = None
        self.rate_seq = 0
        self.check_rows: list[NDArray[np.float64]] = []
        self.accel_lsb: float | None = None
        self.floor = FloorFit(STANDARD_GRAVITY)
        self.moves: MoveTracker | None = None
        """The gyro integrated from the last recorded position (prompted plans only)."""
        self.window_gyro: list[NDArray[np.float64]] = []
        """Gyro rows of the position being labelled (its mean starts :attr:`moves`)."""

    def unwrap(self, counter: NDArray[np.int64]) -> NDArray[np.int64]:
        """Unwrapped sequence numbers of a block's 16-bit counters."""
        out = np.empty(counter.shape[0], dtype=np.int64)
        last = self.seq_last
        for i, c in enumerate(counter.tolist()):
            last = c if last is None else last + (c - last) % COUNTER_MODULUS
            out[i] = last
        if out.size:
            self.seq_last = int(out[-1])
            if self.seq0 is None:
                self.seq0 = int(out[0])
        return out

    def write(
        self, block: SampleBlock, labels: NDArray[np.int64], angles: NDArray[np.float64]
    ) -> None:
        """Write a block with per-row position labels (-1 none) and angles (deg, NaN none)."""
        if block.n == 0:
            return
        t = np.maximum.accumulate(np.maximum(block.t, self.last_t))  # CAN receive times
        self.writer.write_rows(
            t=t,
            counter=block.counter,
            position=labels,
            alpha_deg=angles[:, 0],
            beta_deg=angles[:, 1],
            psi_deg=angles[:, 2],
            accel=block.accel,
            gyro=block.gyro,
            temp_c=np.full(block.n, block.temp_c),
        )
        self.last_t = float(t[-1])
        self.tally.rows += block.n
        self.tally.labelled += int(np.count_nonzero(labels >= 0))


Labels = tuple[NDArray[np.int64], NDArray[np.float64]]
Labeller = Callable[[_Track, SampleBlock], Labels]
"""Per-row position labels (-1 none) and angles (n, 3) in degrees (NaN none) of a block."""


class Recorder:
    """Streams from every node and writes each block as it comes (see the module doc)."""

    def __init__(
        self,
        channels: Sequence[tuple[ImuClient, RecordingWriter, float]],
        *,
        idle_timeout_s: float = DEFAULT_IDLE_TIMEOUT_S,
        check_rate: bool = False,
    ) -> None:
        if not channels:
            raise InputError("nothing to record: no node")
        self._tracks = [_Track(client, writer, rate) for client, writer, rate in channels]
        for track in self._tracks:
            track.check_rate = check_rate
        self._idle_timeout_s = idle_timeout_s
        self._started = False

    @property
    def tallies(self) -> list[NodeTally]:
        """Per-node counts so far."""
        return [track.tally for track in self._tracks]

    def start(self) -> None:
        """Start streaming on every node (NMT start to each target node only).

        With ``check_rate`` the first RATE_CHECK_S of samples are written unlabelled while
        the rate is measured (see :func:`_check_rate`).
        """
        for track in self._tracks:
            track.was_operational = track.client.node_state == "OPERATIONAL"
            track.client.start_streaming(rate_hz=track.rate_hz)
            track.last_data = time.monotonic()
        self._started = True
        # the rate is measured before any labelling, so windows are counted at the true rate
        self._pump(
            _unlabelled, lambda: all(t.rate_measured or not t.check_rate for t in self._tracks)
        )

    def stop(self) -> None:
        """Stop streaming (a node found OPERATIONAL stays so) and write what is left."""
        if not self._started:
            return
        self._started = False
        for track in self._tracks:
            _note_skew(track)  # the estimate ends with the stream
            track.client.stop_streaming(keep_operational=track.was_operational)
            self._drain(track, _unlabelled)

    # ------------------------------------------------------------------------ labelling
    def record_pose(self, index: int, position: PlannedPosition, *, settle_s: float = 1.5) -> None:
        """Label the next ``position.seconds`` of samples ``index`` after ``settle_s``."""
        if index < 0:
            raise InputError(f"position index must be ≥ 0, got {index}")
        for track in self._tracks:
            self._drain(track, _unlabelled)  # queued while the operator was busy
            track.skip = int(round(settle_s * track.rate_hz))
            track.remaining = max(int(round(position.seconds * track.rate_hz)), 2)
            track.index = index
            track.angles_deg = np.rad2deg(position.angles)
            track.window_gyro = []
        self._pump(_window, lambda: all(t.remaining == 0 for t in self._tracks))
        for track in self._tracks:
            track.index = -1

    def record_prompted(
        self,
        plan: Plan,
        prompt: PosePrompt,
        *,
        settle_s: float = 1.5,
        first_index: int = 0,
        refused: PoseRefused | None = None,
    ) -> None:
        """Record every position of ``plan``, calling ``prompt`` before each.

        With ``refused``, each pose is checked before it is recorded; a unit not at the
        pose is reported to ``refused`` and ``prompt`` is called again for that position.
        """
        for i, position in enumerate(plan.positions):
            settle = settle_s
            while True:
                prompt(first_index + i, position)
                if refused is None:
                    break
                checks = self.check_pose(position, settle_s=settle_s)
                bad: list[tuple[_Track, PoseCheck | MoveCheck]] = [
                    (t, c) for t, c in zip(self._tracks, checks, strict=True) if not c.passed
                ]
                if not bad:
                    moves = self.check_moves(position)
                    bad = [
                        (t, m)
                        for t, m in zip(self._tracks, moves, strict=True)
                        if m is not None and not m.passed
                    ]
                if not bad:
                    self.learn_floor(position)
                    settle = 0.0  # settled and checked just now
                    break
                why = "; ".join(f"node {t.client.node_id}: {c.message()}" for t, c in bad)
                refused(first_index + i, why)
            self.record_pose(first_index + i, position, settle_s=settle)
            if refused is not None:
                self._start_moves(position)

    def check_pose(self, position: PlannedPosition, *, settle_s: float = 1.5) -> list[PoseCheck]:
        """Check that every node is at ``position``, as the guided procedure does.

        After ``settle_s``, :data:`CHECK_WINDOW_S` of samples (written unlabelled) are
        averaged; the nominal specific force must point within 5° (first pose) or 3° of the
        target's as predicted with the floor slope and bias the accepted poses showed
        (:class:`~canimucal.procedure.posecheck.FloorFit`).
        """
        for track in self._tracks:
            self._drain(track, _unlabelled)
            track.skip = int(round(settle_s * track.rate_hz))
            track.remaining = max(int(round(CHECK_WINDOW_S * track.rate_hz)), 2)
            track.check_rows = []
        self._pump(_checking, lambda: all(t.remaining == 0 for t in self._tracks))
        out = []
        for track in self._tracks:
            if track.accel_lsb is None:
                track.accel_lsb = float(track.client.nominal_lsb()[0])
            rows = np.vstack(track.check_rows)
            mean = np.nanmean(rows, axis=0)
            f = measured_force(mean, track.accel_lsb)
            tolerance = FIRST_POSE_TOLERANCE_DEG if track.floor.empty else POSE_TOLERANCE_DEG
            out.append(track.floor.check(position, f, tolerance))
        return out

    def check_moves(self, position: PlannedPosition) -> list[MoveCheck | None]:
        """Check the gyro's move to ``position`` from the last recorded one, per node.

        The guided procedure's own check (:class:`~canimucal.procedure.movecheck.MoveTracker`,
        15°, or 4σ of the poses' tolerances): the attitude change integrated since that
        position, against the plan's. None
        for a node with nothing to compare yet (the first position).
        """
        return [
            None if t.moves is None else t.moves.check(position, MOVE_TOLERANCE_DEG or 15.0)
            for t in self._tracks
        ]

    def _start_moves(self, position: PlannedPosition) -> None:
        """Integrate each node's gyro from the position just recorded (its mean as the bias)."""
        for track in self._tracks:
            rows = [r for r in track.window_gyro if r.size]
            track.window_gyro = []
            if not rows:
                continue
            gyro = np.vstack(rows)
            finite = gyro[np.all(np.isfinite(gyro), axis=1)]
            if not finite.shape[0]:
                continue
            if track.moves is None:
                gyro_lsb = float(track.client.nominal_lsb()[1])
                track.moves = MoveTracker(track.rate_hz, gyro_lsb)
            track.moves.start(position, finite.mean(axis=0))

    def learn_floor(self, position: PlannedPosition) -> None:
        """Take the last checked pose into each node's floor slope and bias.

        They predict the next positions (:class:`~canimucal.procedure.posecheck.FloorFit`).
        """
        for track in self._tracks:
            if track.check_rows and track.accel_lsb is not None:
                mean = np.nanmean(np.vstack(track.check_rows), axis=0)
                track.floor.add(position, measured_force(mean, track.accel_lsb))

    def record_scheduled(
        self,
        plan: Plan,
        *,
        transient_s: float,
        guard_s: float = DEFAULT_GUARD_S,
        first_index: int = 0,
    ) -> None:
        """Record a plan the unit follows by itself from the NMT start (module doc)."""
        schedule = ScheduleLabels(plan, transient_s=transient_s, guard_s=guard_s)

        def labeller(track: _Track, block: SampleBlock) -> Labels:
            seq = track.unwrap(block.counter)
            labels = schedule.labels((seq - (track.seq0 or 0)) / track.rate_hz)
            rows = np.where(
                (labels >= 0)[:, None], schedule.angles_deg[np.maximum(labels, 0)], np.nan
            )
            return np.where(labels >= 0, labels + first_index, -1), rows

        def done() -> bool:
            return all(
                t.seq_last is not None
                and (t.seq_last - (t.seq0 or 0)) / t.rate_hz > schedule.end_s + guard_s
                for t in self._tracks
            )

        self._pump(labeller, done)

    # ------------------------------------------------------------------------- the loop
    def _pump(self, labeller: Labeller, done: Callable[[], bool]) -> None:
        """Take blocks from every node and write them, in batches, until ``done()``."""
        while not done():
            for track in self._tracks:
                self._device_events(track, labeller)  # a reboot first resumes streaming
                block = track.client.get_block(POLL_S / len(self._tracks))
                now = time.monotonic()
                if block is not None:
                    track.pending.append(block)
                    track.malformed += block.malformed
                    if block.n:
                        track.last_data = now
                        track.pending_rows += block.n
                if now - track.last_data > self._idle_timeout_s:  # frames that pair nothing too
                    raise DeviceError(self._stalled(track))
                if track.pending_rows >= WRITE_ROWS or now - track.last_write > WRITE_INTERVAL_S:
                    self._flush(track, labeller)
        for track in self._tracks:
            self._flush(track, labeller)

    def _stalled(self, track: _Track) -> str:
        """Say that a node gave no sample, and why (a refused start, frames of a bad mapping)."""
        refused = refused_start(track.client)
        if refused is not None:
            return refused
        message = f"node {track.client.node_id} sent no sample for {self._idle_timeout_s:g} s"
        if track.malformed:
            message += (
                f"; {track.malformed} frames did not match the node's PDO mapping (wrong "
                "length): check 0x1A00-0x1A02"
            )
        return message

    def _device_events(self, track: _Track, labeller: Labeller) -> None:
        """React to what the node reported: a reboot resumes streaming (see ``_rebooted``)."""
        while True:
            try:
                event = track.client.events.get_nowait()
            except queue.Empty:
                return
            if isinstance(event, NodeRebooted):
                self._rebooted(track, labeller)
            else:
                log.warning("node %d reported %s", track.client.node_id, event)

    def _rebooted(self, track: _Track, labeller: Labeller) -> None:
        """Write what came before the boot-up, restart the counters and resume streaming.

        The node's counter starts again after a reboot: unwrapping restarts, so the fall
        back is not taken for a ~65,000-sample jump. A position whose rows were being
        labelled (a window past its settling, or a schedule) is never continued across
        the reboot: the rows so far stay in the file and a DeviceError asks to record that
        position again.
        """
        node_id = track.client.node_id
        self._drain(track, labeller)
        track.tally.reboots += 1
        track.seq_last = None
        track.client.resume_streaming()
        track.last_data = time.monotonic()
        log.warning("node %d rebooted; streaming resumed", node_id)
        labelling = track.index >= 0 and track.skip == 0 and track.remaining > 0
        if labeller is _checking:
            track.check_rows = []  # the check starts again on fresh samples
            track.skip = int(round(CHECK_WINDOW_S * track.rate_hz))
            track.remaining = max(int(round(CHECK_WINDOW_S * track.rate_hz)), 2)
            return
        if labelling or labeller is not _window:
            what = f"position {track.index}" if labeller is _window else "the schedule"
            raise DeviceError(
                f"node {node_id} rebooted while {what} was being recorded: the rows up to "
                f"the reboot are in {track.writer.path}; record {what} again"
            )

    def _drain(self, track: _Track, labeller: Labeller) -> None:
        while (block := track.client.get_block(0.0)) is not None:
            track.pending.append(block)
        self._flush(track, labeller)

    @staticmethod
    def _flush(track: _Track, labeller: Labeller) -> None:
        """Label and write the blocks received since the last flush as one."""
        track.last_write = time.monotonic()
        if not track.pending:
            return
        block = concat_blocks(track.pending)
        track.pending, track.pending_rows = [], 0
        track.tally.add(block)
        _note_skew(track)
        if block.n:
            if track.check_rate:
                _check_rate(track, block)
            labels, angles = labeller(track, block)
            track.write(block, labels, angles)
            if track.moves is not None:
                track.moves.add(block.gyro, block.counter)
            if labeller is _window:
                track.window_gyro.append(np.asarray(block.gyro[labels >= 0], dtype=float))


class ScheduleLabels:
    """Which position a unit that follows ``plan`` by itself is steady at, by schedule time.

    The schedule starts at 0 s (the NMT start) and moves ``transient_s`` between positions
    (:class:`~canimucal.sim.schedule.PoseTrajectory`); a sample at schedule time ``s`` is
    labelled when the schedule holds the same position ``guard_s`` before and after it.
    ``record`` labels a scheduled session so, and ``import-log --follow-schedule`` labels
    its log the same way.
    """

    def __init__(self, plan: Plan, *, transient_s: float, guard_s: float = DEFAULT_GUARD_S):
        self.trajectory = PoseTrajectory()
        self.trajectory.follow(0.0, plan, transient_s)
        self.end_s = float(self.trajectory.end_s or 0.0)
        self.guard_s = guard_s
        self.angles_deg = np.vstack([np.rad2deg(p.angles) for p in plan.positions])

    def labels(self, seconds: NDArray[np.float64]) -> NDArray[np.int64]:
        """Position index of each schedule time (-1: moving, or within the guard of a move)."""
        index = self.trajectory.sample(seconds).index
        steady = (self.trajectory.sample(seconds - self.guard_s).index == index) & (
            self.trajectory.sample(seconds + self.guard_s).index == index
        )
        return np.where(steady & (index >= 0), index, -1)


def _note_skew(track: _Track) -> None:
    """Keep the client's latest skew estimate (a reboot restarts it: the last one stays)."""
    if track.client.second_send_trigger:
        track.tally.second_trigger = True
        track.tally.skew_ppm = None
    skew = track.client.skew_ppm
    if skew is not None and not track.tally.second_trigger:
        track.tally.skew_ppm = skew


def _check_rate(track: _Track, block: SampleBlock) -> None:
    """Measure the sample rate over the first RATE_CHECK_S of CAN times; trust it over 0x2010:03.

    The rate is the counter span over the receive-time span (lost samples still advance the
    counter). When it differs from the claimed rate by more than RATE_TOLERANCE, a warning
    says so, the labelling windows still to come are rescaled and the recording's header is
    corrected when the file is closed. Measured once per track.
    """
    if track.rate_measured:
        return
    counters = block.counter.tolist()
    if track.rate_counter is None:
        track.rate_t0, track.rate_seq, track.rate_counter = float(block.t[0]), 0, int(counters[0])
    for c in counters:
        track.rate_seq += (int(c) - track.rate_counter) % COUNTER_MODULUS
        track.rate_counter = int(c)
    span = float(block.t[-1]) - track.rate_t0
    if span < RATE_CHECK_S:
        return
    track.rate_measured = True
    measured = _snap_rate(track.rate_seq / span)
    claimed = track.rate_hz
    if abs(measured / claimed - 1.0) <= RATE_TOLERANCE:
        return
    log.warning(
        "node %d claims %g Hz (0x2010:03) but its samples arrive at %g Hz: using the measured rate",
        track.client.node_id,
        claimed,
        measured,
    )
    factor = measured / claimed
    track.skip = int(round(track.skip * factor))
    if track.remaining:
        track.remaining = max(int(round(track.remaining * factor)), 2)
    track.rate_hz = measured
    track.writer.correct_header(sample_rate_hz=measured)


def _snap_rate(rate: float) -> float:
    """Return the device rate within 2 % of ``rate``, else ``rate`` itself."""
    for device_rate in OUTPUT_DATA_RATES_HZ:
        if abs(rate - device_rate) <= 0.02 * device_rate:
            return float(device_rate)
    return rate


def _unlabelled(track: _Track, block: SampleBlock) -> Labels:
    track.unwrap(block.counter)
    return np.full(block.n, -1, dtype=np.int64), np.full((block.n, 3), np.nan)


def _window(track: _Track, block: SampleBlock) -> Labels:
    """Skip ``track.skip`` rows, label the next ``track.remaining`` with ``track.index``."""
    track.unwrap(block.counter)
    labels = np.full(block.n, -1, dtype=np.int64)
    first = min(track.skip, block.n)
    count = min(track.remaining, block.n - first)
    labels[first : first + count] = track.index
    track.skip -= first
    track.remaining -= count
    angles = np.where((labels >= 0)[:, None], track.angles_deg, np.nan)
    return labels, angles


def _checking(track: _Track, block: SampleBlock) -> Labels:
    """Keep the accelerometer rows of the pose check (after ``track.skip``); none labelled."""
    first = min(track.skip, block.n)
    count = min(track.remaining, block.n - first)
    if count:
        track.check_rows.append(np.asarray(block.accel[first : first + count], dtype=float))
    track.skip -= first
    track.remaining -= count
    return _unlabelled(track, block)
