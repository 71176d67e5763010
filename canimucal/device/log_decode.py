"""One IMU node's traffic in a bus log: its SDO answers and its samples (docs/design.md §5).

The samples are paired by the client's own :class:`~canimucal.device.stream.SamplePairer`,
fed the node's frames in log order with their logged times, so a log gives the rows, losses,
duplicates and late halves the client would have counted live on the same frames. A boot-up
(``0x700 + id``, state 0) restarts the pairing as the client's consumer does.

What the node told an SDO client in the log is kept as the values of its objects
(:func:`sdo_transfers`): expedited uploads (the answer names index and sub-index) and
expedited downloads the node confirmed. Segmented transfers (device name, strings) are left
out; the importer needs none of them.
"""

from __future__ import annotations

import logging
import struct
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from canimucal.device.bus_log import LogFrames
from canimucal.device.events import HEARTBEAT_BASE
from canimucal.device.pdo_layout import ACCEL_RAW, SampleLayout
from canimucal.device.stream import SamplePairer
from canimucal.model.samples import SampleBlock, concat_blocks
from canimucal.model.vocabulary.constants import COUNTER_MODULUS

logger = logging.getLogger(__name__)

SDO_RESPONSE_BASE = 0x580
SDO_REQUEST_BASE = 0x600
"""COB-ID bases of the default SDO channel: server to client, client to server (CiA 301)."""
DEFAULT_TPDO_BASES = (0x180, 0x280)
"""TPDO1 and TPDO2 COB-ID bases of the EDS defaults: a node sending on both is an IMU."""
BOOT_UP = 0x00
"""Heartbeat state byte of a boot-up message."""
MAX_COUNTER_STEP = 1000
"""Consecutive TPDO1 counters further apart than this (a reboot, a log gap) time no rate."""


@dataclass(frozen=True)
class SdoTransfer:
    """One expedited SDO transfer the node completed: the object's value at time ``t``."""

    t: float
    index: int
    sub: int
    data: bytes
    upload: bool


def sdo_transfers(frames: LogFrames, node_id: int) -> list[SdoTransfer]:
    """Expedited uploads the node answered and downloads it confirmed, in log order."""
    ids = frames.can_id
    rows = np.flatnonzero(
        ~frames.extended
        & ((ids == SDO_RESPONSE_BASE + node_id) | (ids == SDO_REQUEST_BASE + node_id))
    )
    pending: dict[tuple[int, int], bytes] = {}
    out: list[SdoTransfer] = []
    for i in rows.tolist():
        data = frames.payload(i)
        if len(data) != 8:
            continue
        command, key = data[0], (data[1] | data[2] << 8, data[3])
        expedited = bool(command & 0x02)
        size = 4 - ((command >> 2) & 0x03) if command & 0x01 else 4
        if int(ids[i]) == SDO_REQUEST_BASE + node_id:
            if command & 0xE0 == 0x20 and expedited:  # initiate download, data in the frame
                pending[key] = data[4 : 4 + size]
            continue
        if command & 0xE0 == 0x40 and expedited:  # upload answer, data in the frame
            out.append(SdoTransfer(float(frames.t[i]), key[0], key[1], data[4 : 4 + size], True))
        elif command == 0x60 and key in pending:  # download confirmed
            out.append(SdoTransfer(float(frames.t[i]), key[0], key[1], pending.pop(key), False))
    return out


def values_at(transfers: list[SdoTransfer], t: float) -> dict[tuple[int, int], bytes]:
    """Each object's value at time ``t``: the last transfer before it, else the first after."""
    values: dict[tuple[int, int], bytes] = {}
    for transfer in transfers:
        key = (transfer.index, transfer.sub)
        if transfer.t <= t or key not in values:
            values[key] = transfer.data
    return values


def nodes_seen(frames: LogFrames) -> dict[int, str]:
    """Node ids that show in the log, with how: ``TPDO1/TPDO2`` (the EDS defaults) or heartbeat."""
    standard = frames.can_id[~frames.extended]
    ids = set(np.unique(standard).tolist())
    seen: dict[int, str] = {}
    for node in range(1, 128):
        if all(base + node in ids for base in DEFAULT_TPDO_BASES):
            seen[node] = "TPDO1/TPDO2"
        elif HEARTBEAT_BASE + node in ids:
            seen[node] = "heartbeat"
    return seen


def layout_frames(
    frames: LogFrames, layout: SampleLayout, node_id: int, channel: int | None = None
) -> NDArray[np.intp]:
    """Return the indices of the node's TPDO and heartbeat frames (on ``channel`` when given)."""
    cob_ids = [layout.accel.cob_id, layout.gyro.cob_id]
    if layout.info is not None:
        cob_ids.append(layout.info.cob_id)
    mask = np.zeros(frames.n, dtype=bool)
    for cob in cob_ids:
        mask |= (frames.can_id == cob) & (frames.extended == (cob > 0x7FF))
    mask |= (frames.can_id == HEARTBEAT_BASE + node_id) & ~frames.extended
    if channel is not None:
        mask &= frames.channel == channel
    return np.flatnonzero(mask)


def counter_rate(frames: LogFrames, layout: SampleLayout, rows: NDArray[np.intp]) -> float | None:
    """Return the samples per second of the log's clock: TPDO1 counters over time.

    Sums the counter steps of consecutive TPDO1 frames (1 to :data:`MAX_COUNTER_STEP`, so a
    reboot or a gap in the log adds nothing) over their time; None when nothing is timed.
    """
    accel = layout.accel
    pick = layout.picks(accel, ACCEL_RAW)[3]
    counters, times = [], []
    for i in rows[frames.can_id[rows] == accel.cob_id].tolist():
        try:
            counters.append(accel.decode(frames.payload(i))[pick])
        except struct.error:
            continue  # a malformed frame: the pairing counts it
        times.append(float(frames.t[i]))
    if len(counters) < 2:
        return None
    step = np.mod(np.diff(np.asarray(counters, dtype=np.int64)), COUNTER_MODULUS)
    dt = np.diff(np.asarray(times))
    good = (step >= 1) & (step <= MAX_COUNTER_STEP) & (dt >= 0)
    span = float(dt[good].sum())
    return float(step[good].sum()) / span if span > 0 else None


@dataclass(frozen=True)
class DecodedSamples:
    """The node's paired samples (rows in counter order) and the stream's counts.

    ``temp_c`` is per row: the temperature TPDO3 last carried when the row was paired.
    ``reboots`` counts boot-ups after the first sample (each restarts the pairing).
    """

    block: SampleBlock
    temp_c: NDArray[np.float64]
    frames: int
    reboots: int
    skew_ppm: float | None


def decode_samples(
    frames: LogFrames, layout: SampleLayout, node_id: int, period_s: float, rows: NDArray[np.intp]
) -> DecodedSamples:
    """Pair the node's frames ``rows`` (from :func:`layout_frames`) as the client does."""
    pairer = SamplePairer(layout, period_s)
    info = layout.info.cob_id if layout.info is not None else None
    boot_id = HEARTBEAT_BASE + node_id
    blocks: list[SampleBlock] = []
    reboots, fed = 0, 0
    skew = None
    for i in rows.tolist():
        can_id, data, t = int(frames.can_id[i]), frames.payload(i), float(frames.t[i])
        if can_id == boot_id:
            if data[:1] == bytes([BOOT_UP]) and (pairer.frames or blocks):
                skew = pairer.skew_ppm if pairer.skew_ppm is not None else skew
                pairer.restart()
                reboots += 1
            continue
        if can_id == info and pairer.has_news():
            blocks.append(pairer.take())  # the rows so far carry the previous temperature
        pairer.feed(can_id, data, t)
        fed += 1
    pairer.flush()
    blocks.append(pairer.take())
    block = concat_blocks(blocks)
    temp = np.concatenate([np.full(b.n, b.temp_c) for b in blocks])
    return DecodedSamples(
        block, temp, fed, reboots, pairer.skew_ppm if pairer.skew_ppm is not None else skew
    )


def object_value(values: Mapping[tuple[int, int], bytes], index: int, sub: int) -> int | None:
    """Return an unsigned object's value from its SDO bytes; None when not in ``values``."""
    data = values.get((index, sub))
    return int.from_bytes(data, "little") if data else None
