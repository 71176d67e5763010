"""TPDO decoding and pairing (DESIGN §4 PDOs): a sample is the TPDO1/TPDO2 pair of one counter.

Frames arrive as raw ``(can_id, data, timestamp)`` tuples handed over by the receive callback;
everything here runs on the consumer thread. Rules:

- A half with no partner within two sample periods is lost (its columns are NaN). "Two
  periods" is measured in the device's own clock — a frame whose counter is two or more ahead
  has arrived — or, when no frame is waiting to be processed, in CAN time.
- Counter gaps (both halves missing) are lost samples; the counter wraps at 65536.
- A second copy of a half is a duplicate, a half arriving after its sample was given up is
  late: both are counted and dropped, never hidden.
- Pairing starts at the first TPDO1, so a stream joined mid-sample does not count a loss.
"""

from __future__ import annotations

import logging
import struct
from collections import deque
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

logger = logging.getLogger(__name__)

COUNTER_MODULUS = 65536
STALL_GRACE_S = 0.25
"""When the stream stalls, a pending half is given up after max(2 periods, this) of CAN time."""
RECENT_WINDOW = 1024
"""How many finalized counters are remembered to tell duplicates from late halves."""

ACCEL_RAW = 0x2000
GYRO_RAW = 0x2001
SAMPLE_INFO = 0x2002
SIGNED_OBJECTS = {(ACCEL_RAW, 1), (ACCEL_RAW, 2), (ACCEL_RAW, 3), (GYRO_RAW, 1), (GYRO_RAW, 2)}
SIGNED_OBJECTS |= {(GYRO_RAW, 3), (SAMPLE_INFO, 1)}
TEMP_SCALE_C = 0.01
"""0x2002:01 is in 0.01 °C."""


@dataclass(frozen=True)
class MappedField:
    """One mapped object of a PDO: where it sits in the frame and how to read it."""

    index: int
    sub: int
    bits: int
    offset_bits: int
    signed: bool

    @classmethod
    def from_entry(cls, entry: int, offset_bits: int) -> MappedField:
        """Decode a CiA 301 mapping entry ``index << 16 | sub << 8 | bit length``."""
        index, sub, bits = entry >> 16, (entry >> 8) & 0xFF, entry & 0xFF
        return cls(index, sub, bits, offset_bits, (index, sub) in SIGNED_OBJECTS)


@dataclass(frozen=True)
class PdoLayout:
    """The mapping of one TPDO: its COB-ID and fields, with a fast decoder."""

    cob_id: int
    fields: tuple[MappedField, ...]
    _struct: struct.Struct | None = field(default=None, compare=False, repr=False)

    @classmethod
    def from_entries(cls, cob_id: int, entries: Sequence[int]) -> PdoLayout:
        """Build from the raw 0x1A0x sub-index values (sub 1..n)."""
        fields, offset = [], 0
        for entry in entries:
            mapped = MappedField.from_entry(entry, offset)
            fields.append(mapped)
            offset += mapped.bits
        return cls(cob_id, tuple(fields), _compile(fields))

    @property
    def size_bytes(self) -> int:
        """Bytes the mapped objects occupy."""
        return (sum(f.bits for f in self.fields) + 7) // 8

    def position(self, index: int, sub: int) -> int | None:
        """Position of object ``index:sub`` among the decoded values, or None."""
        for i, mapped in enumerate(self.fields):
            if (mapped.index, mapped.sub) == (index, sub):
                return i
        return None

    def decode(self, data: bytes) -> tuple[int, ...]:
        """Values of the mapped objects, in mapping order (``struct.error`` if too short)."""
        if len(data) < self.size_bytes:
            raise struct.error(f"{len(data)} bytes, mapping needs {self.size_bytes}")
        if self._struct is not None:
            return self._struct.unpack_from(data)
        raw = int.from_bytes(data, "little")
        values = []
        for f in self.fields:
            value = (raw >> f.offset_bits) & ((1 << f.bits) - 1)
            if f.signed and value >> (f.bits - 1):
                value -= 1 << f.bits
            values.append(value)
        return tuple(values)


_STRUCT_CODES = {(8, False): "B", (8, True): "b", (16, False): "H", (16, True): "h"}
_STRUCT_CODES |= {(32, False): "I", (32, True): "i"}


def _compile(fields: Sequence[MappedField]) -> struct.Struct | None:
    """Return a ``struct`` format when every field is a whole 8/16/32-bit integer, else None."""
    codes = [_STRUCT_CODES.get((f.bits, f.signed)) for f in fields]
    if any(code is None for code in codes):
        return None
    return struct.Struct("<" + "".join(code for code in codes if code))


@dataclass(frozen=True)
class SampleLayout:
    """Where accel, gyro, counter and temperature sit in TPDO1/2/3 (read from the node)."""

    accel: PdoLayout
    gyro: PdoLayout
    info: PdoLayout | None

    def __post_init__(self) -> None:
        """Check that the halves carry what pairing needs."""
        needed = [(self.accel, ACCEL_RAW), (self.gyro, GYRO_RAW)]
        for layout, index in needed:
            for sub in (1, 2, 3):
                if layout.position(index, sub) is None:
                    raise ValueError(
                        f"TPDO 0x{layout.cob_id:X} does not map 0x{index:04X}:{sub:02d}"
                    )
            if layout.position(SAMPLE_INFO, 2) is None:
                raise ValueError(f"TPDO 0x{layout.cob_id:X} does not map the counter 0x2002:02")

    def picks(self, layout: PdoLayout, index: int) -> tuple[int, int, int, int]:
        """Positions of x, y, z of ``index`` and of the counter in ``layout``'s values."""
        pos = [layout.position(index, sub) for sub in (1, 2, 3)]
        pos.append(layout.position(SAMPLE_INFO, 2))
        return (pos[0] or 0, pos[1] or 0, pos[2] or 0, pos[3] or 0)


@dataclass(frozen=True)
class SampleBlock:
    """Paired samples in counter order, with the stream's losses over the same span.

    ``t`` is the CAN timestamp of TPDO2 (TPDO1's when TPDO2 was lost); ``accel``/``gyro`` are
    raw counts with NaN rows for a lost half. The counts cover what was finalized into this
    block: ``lost_samples`` counter gaps (both halves missing), ``duplicates`` and ``late``
    halves dropped.
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

    @property
    def n(self) -> int:
        """Number of samples (rows)."""
        return int(self.t.shape[0])


@dataclass
class _Pending:
    seq: int
    accel: tuple[int, int, int] | None = None
    gyro: tuple[int, int, int] | None = None
    t_accel: float = float("nan")
    t_gyro: float = float("nan")
    arrival: float = 0.0


@dataclass
class _Tally:
    lost_accel: int = 0
    lost_gyro: int = 0
    lost_samples: int = 0
    duplicates: int = 0
    late: int = 0


class SamplePairer:
    """Pairs TPDO1/TPDO2 halves by counter; fed raw frames, emits :class:`SampleBlock`s.

    Not thread-safe: one consumer thread owns it. ``period_s`` is the sample period (1/ODR).
    """

    def __init__(self, layout: SampleLayout, period_s: float) -> None:
        self.layout = layout
        self.period_s = period_s
        self.stall_s = max(2.0 * period_s, STALL_GRACE_S)
        self._accel_pick = layout.picks(layout.accel, ACCEL_RAW)
        self._gyro_pick = layout.picks(layout.gyro, GYRO_RAW)
        self._info_pos = self._info_positions(layout.info)
        self._pending: dict[int, _Pending] = {}
        self._recent: dict[int, tuple[bool, bool]] = {}
        self._recent_order: deque[int] = deque()
        self._newest: int | None = None
        self._rows: list[tuple[float, int, tuple[float, ...], tuple[float, ...]]] = []
        self._tally = _Tally()
        self.temp_c = float("nan")
        self.status: int | None = None
        self.frames = 0
        self.malformed = 0

    @staticmethod
    def _info_positions(info: PdoLayout | None) -> tuple[int | None, int | None]:
        if info is None:
            return None, None
        return info.position(SAMPLE_INFO, 1), info.position(SAMPLE_INFO, 3)

    def feed(self, can_id: int, data: bytes, timestamp: float) -> None:
        """Decode and pair one received frame (TPDO1, TPDO2 or TPDO3).

        A frame shorter than its mapping is dropped and counted in ``malformed``.
        """
        self.frames += 1
        try:
            self._feed(can_id, data, timestamp)
        except (struct.error, IndexError):
            self.malformed += 1
            logger.warning("dropped a malformed frame 0x%X: %s", can_id, bytes(data).hex())

    def _feed(self, can_id: int, data: bytes, timestamp: float) -> None:
        if can_id == self.layout.accel.cob_id:
            v = self.layout.accel.decode(data)
            p = self._accel_pick
            self._half(v[p[3]], True, (v[p[0]], v[p[1]], v[p[2]]), timestamp)
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
                self._old_half(seq, is_accel)
                return
            self._advance(seq)
            entry = self._pending[seq] = _Pending(seq, arrival=t)
        if (entry.accel if is_accel else entry.gyro) is not None:
            self._tally.duplicates += 1
            return
        if is_accel:
            entry.accel, entry.t_accel = xyz, t
        else:
            entry.gyro, entry.t_gyro = xyz, t
        self._finalize_ready()

    def _sequence(self, counter: int) -> int:
        """Unwrapped sequence number of ``counter`` nearest the newest one seen."""
        newest = self._newest if self._newest is not None else counter
        delta = (counter - newest) % COUNTER_MODULUS
        if delta >= COUNTER_MODULUS // 2:
            delta -= COUNTER_MODULUS
        return newest + delta

    def _old_half(self, seq: int, is_accel: bool) -> None:
        halves = self._recent.get(seq)
        if halves is not None and halves[0 if is_accel else 1]:
            self._tally.duplicates += 1
        else:
            self._tally.late += 1

    def _advance(self, seq: int) -> None:
        """Start a new counter: the ones skipped are lost samples (both halves)."""
        assert self._newest is not None
        for missing in range(self._newest + 1, seq):
            self._tally.lost_samples += 1
            self._remember(missing, False, False)
        self._newest = seq

    def _remember(self, seq: int, has_accel: bool, has_gyro: bool) -> None:
        self._recent[seq] = (has_accel, has_gyro)
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
        if entry.accel is None:
            self._tally.lost_accel += 1
        if entry.gyro is None:
            self._tally.lost_gyro += 1
        t = entry.t_gyro if entry.gyro is not None else entry.t_accel
        accel: tuple[float, ...] = entry.accel if entry.accel is not None else nan3
        gyro: tuple[float, ...] = entry.gyro if entry.gyro is not None else nan3
        self._rows.append((t, entry.seq % COUNTER_MODULUS, accel, gyro))
        self._remember(entry.seq, entry.accel is not None, entry.gyro is not None)

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
    )


def concat_blocks(blocks: Sequence[SampleBlock]) -> SampleBlock:
    """One block holding ``blocks`` in order (counts summed, latest temperature)."""
    if not blocks:
        return _block([], _Tally(), float("nan"), None)
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
    )


def layout_from_mapping(
    cob_ids: Mapping[int, int], entries: Mapping[int, Sequence[int]]
) -> SampleLayout:
    """Sample layout from TPDO number → COB-ID and TPDO number → mapping entries (1, 2, 3)."""
    info = PdoLayout.from_entries(cob_ids[3], entries[3]) if 3 in entries else None
    return SampleLayout(
        PdoLayout.from_entries(cob_ids[1], entries[1]),
        PdoLayout.from_entries(cob_ids[2], entries[2]),
        info,
    )
