"""TPDO decoding and pairing (docs/design.md §4 PDOs): a sample pairs TPDO1/TPDO2 of a counter.

Frames arrive as raw ``(can_id, data, timestamp)`` tuples handed over by the receive callback;
everything here runs on the consumer thread. Rules:

- A half with no partner within two sample periods is lost (its columns are NaN). "Two
  periods" is measured in the device's own clock — a frame whose counter is two or more ahead
  has arrived — or, when no frame is waiting to be processed, in CAN time.
- Counter gaps (both halves missing) are lost samples; the counter wraps at 65536.
- A second copy of a half is a duplicate, a half arriving after its sample was given up is
  late: both are counted and dropped, never hidden. A duplicate that repeats its sample's
  payload exactly is also a *duplicate send*: the node sent the same frame again.
- Duplicate sends are a second send trigger (an event timer beside data-ready sending), not
  a clock, when they are more than :data:`SECOND_TRIGGER_SHARE` of the samples (no clock
  runs 5 % off) or when the next sample's TPDO1 mostly follows a duplicate send within
  :data:`SECOND_TRIGGER_GAP_PERIODS` of a period. An event timer restarted at every send
  fires only when a data-ready send comes late, so the late sample follows its timer copy
  closely, at whatever share the node's jitter makes (0.4–4.6 % of samples in idle VMs,
  2–18 % in CI's); a timer merely fast against
  the sensor clock sends evenly, a period after the copy as after any frame. Then
  :attr:`SamplePairer.skew_ppm` is None and :attr:`SamplePairer.second_trigger` says why
  (issue 24, case 3).
- Pairing starts at the first TPDO1, so a stream joined mid-sample does not count a loss.
- A TPDO event timer that runs off the sensor clock re-sends a counter (timer fast: both
  halves again, counted as duplicates, never as a loss) or skips one (timer slow: counted
  as a lost sample, which it is for the recording). :attr:`SamplePairer.skew_ppm` estimates
  that skew from TPDO1: counters advanced per event-timer interval, minus one, in ppm.

The thread that feeds a :class:`SamplePairer` lives in :mod:`canimucal.device.stream_consumer`.
"""

from __future__ import annotations

import logging
import struct
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from canimucal.device.pdo_layout import (
    ACCEL_RAW,
    GYRO_RAW,
    SAMPLE_INFO,
    TEMP_SCALE_C,
    MappedField,
    PdoLayout,
    SampleLayout,
    layout_from_mapping,
)
from canimucal.model.samples import SampleBlock
from canimucal.model.vocabulary.constants import COUNTER_MODULUS

__all__ = [
    "MappedField",
    "PdoLayout",
    "SampleLayout",
    "SamplePairer",
    "layout_from_mapping",
]

logger = logging.getLogger(__name__)

STALL_GRACE_S = 1.0
"""When the stream stalls, a pending half is given up after max(2 periods, this) of CAN time.

A starved receive thread looks like a stalled stream: with 0.25 s, the one-hour soak at 8×
on a loaded 2-core host gave up 22 halves whose partners were only delayed (counted as
late, nothing hidden, but lost). While frames flow, the counter rule decides, not this."""
RECENT_WINDOW = 1024
"""How many finalized counters are remembered to tell duplicates from late halves."""
SECOND_TRIGGER_SHARE = 0.05
"""TPDO1 duplicate sends per sample above which they are a second send trigger, not skew."""
SECOND_TRIGGER_MIN_SAMPLES = 200
"""Samples seen before the share is judged (as the skew: 200 intervals)."""
SECOND_TRIGGER_MIN_GAPS = 4
"""Duplicate sends followed by a new sample before their gaps are judged (a fast timer's
copies are a period from the next frame, so even 3 of 4 that soon are no clock;
the reference node in an idle VM repeats only 0.4 % of its samples)."""
SECOND_TRIGGER_GAP_PERIODS = 0.6
"""A new sample's TPDO1 this soon (in periods) after a duplicate send followed a late send:
about midway between the gaps of the two causes, ~0.2 period behind a second trigger's copy
(median 0.9–1.1 ms at 200 Hz in the HIL, idle and loaded) and one period behind a fast
timer's."""


MALFORMED_LOG_EVERY = 1000
"""A stream of malformed frames is logged at its 1st, 10th and every 1000th frame."""


@dataclass
class _Pending:
    seq: int
    accel: tuple[int, int, int] | None = None
    gyro: tuple[int, int, int] | None = None
    t_accel: float = float("nan")
    t_gyro: float = float("nan")
    arrival: float = 0.0
    lost_before: int = 0
    """Counters skipped just before this one (lost samples), counted when it is emitted, so
    a block's counts cover exactly its own rows' span."""


@dataclass
class _Tally:
    lost_accel: int = 0
    lost_gyro: int = 0
    lost_samples: int = 0
    duplicates: int = 0
    late: int = 0
    malformed: int = 0
    duplicate_sends: int = 0


Xyz = tuple[int, int, int]


class SamplePairer:
    """Pairs TPDO1/TPDO2 halves by counter; fed raw frames, emits :class:`SampleBlock`s.

    Not thread-safe: one consumer thread owns it. ``period_s`` is the sample period (1/ODR).
    ``clock`` (e.g. ``time.monotonic``) times the stall rule by when the consumer *received*
    a half instead of its CAN timestamp, so a backlog in the receive path is not a stall.
    """

    def __init__(
        self,
        layout: SampleLayout,
        period_s: float,
        *,
        clock: Callable[[], float] | None = None,
    ) -> None:
        self.layout = layout
        self.clock = clock
        self.period_s = period_s
        self.stall_s = max(2.0 * period_s, STALL_GRACE_S)
        self._accel_pick = layout.picks(layout.accel, ACCEL_RAW)
        self._gyro_pick = layout.picks(layout.gyro, GYRO_RAW)
        self._info_pos = self._info_positions(layout.info)
        self._pending: dict[int, _Pending] = {}
        self._recent: dict[int, tuple[Xyz | None, Xyz | None]] = {}
        self._recent_order: deque[int] = deque()
        self._newest: int | None = None
        self._rows: list[tuple[float, int, tuple[float, ...], tuple[float, ...]]] = []
        self._tally = _Tally()
        self.temp_c = float("nan")
        self.status: int | None = None
        self.frames = 0
        self.malformed = 0
        self._skew_first: tuple[float, int] | None = None  # (CAN time, seq) of a TPDO1
        self._skew_last: tuple[float, int] | None = None
        self._skew_intervals = 0
        self._samples_seen = 0  # counters started since the stream (re)started
        self._accel_resends = 0  # TPDO1 duplicate sends over the same span
        self._resend_t: float | None = None  # CAN time of the last TPDO1 duplicate send
        self._resend_gaps = 0  # duplicate sends followed by a new counter's TPDO1 ...
        self._resend_gaps_short = 0  # ... of which within SECOND_TRIGGER_GAP_PERIODS

    @staticmethod
    def _info_positions(info: PdoLayout | None) -> tuple[int | None, int | None]:
        if info is None:
            return None, None
        return info.position(SAMPLE_INFO, 1), info.position(SAMPLE_INFO, 3)

    def feed(self, can_id: int, data: bytes, timestamp: float) -> None:
        """Decode and pair one received frame (TPDO1, TPDO2 or TPDO3).

        A frame whose length differs from its mapping is dropped and counted in ``malformed``.
        """
        self.frames += 1
        try:
            self._feed(can_id, data, timestamp)
        except (struct.error, IndexError):
            self.malformed += 1
            self._tally.malformed += 1
            if self.malformed in (1, 10) or self.malformed % MALFORMED_LOG_EVERY == 0:
                logger.warning(
                    "dropped a malformed frame 0x%X: %s (%d bytes; %d so far)",
                    can_id,
                    bytes(data).hex(),
                    len(data),
                    self.malformed,
                )

    def _feed(self, can_id: int, data: bytes, timestamp: float) -> None:
        if can_id == self.layout.accel.cob_id:
            v = self.layout.accel.decode(data)
            p = self._accel_pick
            self._half(v[p[3]], True, (v[p[0]], v[p[1]], v[p[2]]), timestamp)
            self._skew_frame(v[p[3]], timestamp)
        elif can_id == self.layout.gyro.cob_id:
            v = self.layout.gyro.decode(data)
            p = self._gyro_pick
            self._half(v[p[3]], False, (v[p[0]], v[p[1]], v[p[2]]), timestamp)
        elif self.layout.info is not None and can_id == self.layout.info.cob_id:
            self._info(data)

    def _info(self, data: bytes) -> None:
        values = self.layout.info.decode(data) if self.layout.info else ()
        temp_pos, status_pos = self._info_pos
        if temp_pos is not None:
            self.temp_c = values[temp_pos] * TEMP_SCALE_C
        if status_pos is not None:
            self.status = int(values[status_pos])

    def _half(self, counter: int, is_accel: bool, xyz: tuple[int, int, int], t: float) -> None:
        if self._newest is None:
            if not is_accel:
                return  # joined mid-sample: start at the first TPDO1
            self._newest = counter - 1
        seq = self._sequence(counter)
        entry = self._pending.get(seq)
        if entry is None:
            if seq <= self._newest:
                self._old_half(seq, is_accel, xyz, t)
                return
            lost = self._advance(seq)
            arrival = t if self.clock is None else self.clock()
            entry = self._pending[seq] = _Pending(seq, arrival=arrival, lost_before=lost)
        first = entry.accel if is_accel else entry.gyro
        if first is not None:
            self._duplicate(is_accel, first == xyz, t)
            return
        if is_accel:
            entry.accel, entry.t_accel = xyz, t
        else:
            entry.gyro, entry.t_gyro = xyz, t
        self._finalize_ready()

    def _skew_frame(self, counter: int, t: float) -> None:
        """Count TPDO1 event-timer ticks: every frame one, plus the frames lost meanwhile.

        By the gap since the last frame: about one period is one tick, whatever the counter
        did (a skipped counter there *is* the skew); a longer gap is as many ticks as
        periods, but no more than the counter advanced (a host stall followed by a burst);
        a burst frame (under half a period) is as many ticks as the counter advanced, and a
        same-counter copy in a burst is a bus duplicate, not a tick.
        """
        if self._newest is None:
            return
        seq = self._sequence(counter)
        if self._skew_last is None:
            self._skew_first = self._skew_last = (t, seq)
            return
        self._resend_gap(seq, t)
        periods = (t - self._skew_last[0]) / self.period_s
        jump = seq - self._skew_last[1]
        if periods < 0.5:
            if jump <= 0:
                return
            ticks = jump
        elif periods <= 1.5:
            ticks = 1
        else:
            ticks = max(1, min(jump, int(round(periods))))
        self._skew_intervals += ticks
        self._skew_last = (t, seq)

    @property
    def skew_ppm(self) -> float | None:
        """Event timer against sensor clock, ppm (+: timer slow, counters skipped; -: fast).

        (counters advanced / event-timer intervals − 1)·10⁶ over the stream so far; None
        before 200 intervals. Its resolution is 10⁶ / intervals.
        """
        if self._skew_first is None or self._skew_last is None or self._skew_intervals < 200:
            return None
        if self.second_trigger:
            return None  # duplicate sends are no clock (module doc)
        advanced = self._skew_last[1] - self._skew_first[1]
        return (advanced / self._skew_intervals - 1.0) * 1e6

    def _sequence(self, counter: int) -> int:
        """Unwrapped sequence number of ``counter`` nearest the newest one seen."""
        newest = self._newest if self._newest is not None else counter
        delta = (counter - newest) % COUNTER_MODULUS
        if delta >= COUNTER_MODULUS // 2:
            delta -= COUNTER_MODULUS
        return newest + delta

    def _old_half(self, seq: int, is_accel: bool, xyz: Xyz, t: float) -> None:
        halves = self._recent.get(seq)
        first = None if halves is None else halves[0 if is_accel else 1]
        if first is not None:
            self._duplicate(is_accel, first == xyz, t)
        else:
            self._tally.late += 1

    def _duplicate(self, is_accel: bool, same_payload: bool, t: float) -> None:
        """Count a second copy of a half; the same payload again is a duplicate send."""
        self._tally.duplicates += 1
        if same_payload:
            self._tally.duplicate_sends += 1
            if is_accel:
                self._accel_resends += 1
                self._resend_t = t

    def _resend_gap(self, seq: int, t: float) -> None:
        """Time a new counter's TPDO1 after the duplicate send before it (module doc)."""
        if self._resend_t is None or self._skew_last is None or seq <= self._skew_last[1]:
            return
        self._resend_gaps += 1
        self._resend_gaps_short += (t - self._resend_t) < SECOND_TRIGGER_GAP_PERIODS * self.period_s
        self._resend_t = None

    @property
    def second_trigger(self) -> bool:
        """Whether the node sends samples twice (module doc).

        TPDO1 duplicate sends above the share, or mostly followed closely by the next sample.
        Judged once :data:`SECOND_TRIGGER_MIN_SAMPLES` samples were seen, the gaps once
        :data:`SECOND_TRIGGER_MIN_GAPS` were timed.
        """
        seen = self._samples_seen
        if seen < SECOND_TRIGGER_MIN_SAMPLES:
            return False
        if self._accel_resends > SECOND_TRIGGER_SHARE * seen:
            return True
        gaps = self._resend_gaps
        return gaps >= SECOND_TRIGGER_MIN_GAPS and self._resend_gaps_short > 0.5 * gaps

    def _advance(self, seq: int) -> int:
        """Start a new counter; return how many were skipped (lost samples, both halves)."""
        assert self._newest is not None
        for missing in range(self._newest + 1, seq):
            self._remember(missing, None, None)
        lost = max(0, seq - self._newest - 1)
        self._samples_seen += seq - self._newest
        self._newest = seq
        return lost

    def _remember(self, seq: int, accel: Xyz | None, gyro: Xyz | None) -> None:
        self._recent[seq] = (accel, gyro)
        self._recent_order.append(seq)
        while len(self._recent_order) > RECENT_WINDOW:
            self._recent.pop(self._recent_order.popleft(), None)

    def _finalize_ready(self, now: float | None = None) -> None:
        """Emit, in counter order, samples that are complete or have waited two periods."""
        newest = self._newest if self._newest is not None else 0
        while self._pending:
            seq = min(self._pending) if len(self._pending) > 1 else next(iter(self._pending))
            entry = self._pending[seq]
            complete = entry.accel is not None and entry.gyro is not None
            expired = seq <= newest - 2 or (now is not None and now - entry.arrival > self.stall_s)
            if not (complete or expired):
                return
            del self._pending[seq]
            self._emit(entry)

    def _emit(self, entry: _Pending) -> None:
        nan3 = (np.nan, np.nan, np.nan)
        self._tally.lost_samples += entry.lost_before
        if entry.accel is None:
            self._tally.lost_accel += 1
        if entry.gyro is None:
            self._tally.lost_gyro += 1
        t = entry.t_gyro if entry.gyro is not None else entry.t_accel
        accel: tuple[float, ...] = entry.accel if entry.accel is not None else nan3
        gyro: tuple[float, ...] = entry.gyro if entry.gyro is not None else nan3
        self._rows.append((t, entry.seq % COUNTER_MODULUS, accel, gyro))
        self._remember(entry.seq, entry.accel, entry.gyro)

    def restart(self) -> None:
        """Restart after a reboot: give up pending halves and pair afresh (counters restart)."""
        self.flush()
        self._newest = None
        self._skew_first = self._skew_last = None
        self._skew_intervals = 0
        self._samples_seen = self._accel_resends = 0
        self._resend_t = None
        self._resend_gaps = self._resend_gaps_short = 0
        self._recent.clear()
        self._recent_order.clear()

    def expire(self, now: float) -> None:
        """Give up halves older than ``stall_s`` at CAN time ``now`` (call when idle)."""
        self._finalize_ready(now)

    def flush(self) -> None:
        """Give up every pending half (end of stream)."""
        for seq in sorted(self._pending):
            self._emit(self._pending.pop(seq))

    @property
    def ready(self) -> int:
        """Finalized samples not yet taken."""
        return len(self._rows)

    def has_news(self) -> bool:
        """Tell whether :meth:`take` would return rows or nonzero counts."""
        return bool(self._rows) or self._tally != _Tally()

    def take(self) -> SampleBlock:
        """Return the samples finalized since the last call, with the counts over the same span."""
        rows, self._rows = self._rows, []
        tally, self._tally = self._tally, _Tally()
        return _block(rows, tally, self.temp_c, self.status)


def _block(
    rows: Sequence[tuple[float, int, tuple[float, ...], tuple[float, ...]]],
    tally: _Tally,
    temp_c: float,
    status: int | None,
) -> SampleBlock:
    n = len(rows)
    t = np.fromiter((r[0] for r in rows), float, n)
    counter = np.fromiter((r[1] for r in rows), np.int64, n)
    accel = np.array([r[2] for r in rows], float).reshape(n, 3)
    gyro = np.array([r[3] for r in rows], float).reshape(n, 3)
    return SampleBlock(
        t,
        counter,
        accel,
        gyro,
        temp_c,
        status,
        tally.lost_accel,
        tally.lost_gyro,
        tally.lost_samples,
        tally.duplicates,
        tally.late,
        tally.malformed,
        tally.duplicate_sends,
    )
