"""A bus log as a recording (docs/design.md §5 "Bus logs"): what ``import-log`` writes.

From any log python-can reads (:mod:`canimucal.device.bus_log`), one IMU node's recording:

1. **The node**: ``node_id``, else the one node that sends on the EDS default TPDO1 and
   TPDO2 COB-IDs; a node the log does not show is refused, naming those it does.
2. **What the node said** over SDO before its first sample (an answered upload or a
   confirmed download, :func:`~canimucal.device.log_decode.sdo_transfers`): identity, nominal
   LSBs, output data rate, PDO mapping.
3. **The mapping**: ``pdo_map`` (the ``pdo`` objects of a ``read-params --json`` document),
   else the mapping objects the log shows, each missing one at its EDS default.
4. **The rate**: ``sample_rate_hz``, else 0x2010:03 from the log, else the TPDO1 counters
   over the log's time, snapped to a device rate within 2 %. A claim the log's times
   contradict by more than 10 % is kept with a warning (a time-scaled or replayed log).
5. **The samples**: the client's own pairing (:func:`~canimucal.device.log_decode.decode_samples`),
   so lost halves and samples, duplicates and late halves are counted as they are live.
6. **The positions**: the static intervals ``solve`` finds in an unlabelled recording
   (:func:`~canimucal.io.grouping.position_rows`: quiet accelerometer and gyro, so a turn
   about the vertical splits two poses too). Without a plan they are positions 0, 1, …
   without angles (scalar fits only). With ``plan`` they are matched to its positions in
   order, each checked as ``record`` checks a pose (8° for the first, then 3° against the
   floor slope, mounting trim and bias the matched ones showed): a stretch that does not fit
   the next position stays unlabelled, and a position no stretch fits is an error.
   ``pose_check=False`` takes the stretches in order and needs exactly one per position. A
   log of a unit that followed the plan by itself from its NMT start (``sim --poses``, the
   in-process simulated node, a motorised rig) is labelled by that schedule instead
   (``follow_schedule``), sample by sample as ``record`` labels it
   (:class:`~canimucal.runtime.recorder.ScheduleLabels`, counted from the node's first
   sample in the log), so the two recordings label the same samples.
7. **The header**: ``node_id``, ``sample_rate_hz``, ``device_serial`` (0x1018:04),
   ``accel_lsb``/``gyro_lsb`` (0x2010:01/02) when the log shows them, ``plan`` and
   ``tolerance_deg`` with a plan, and whatever ``header`` adds (the site).
"""

from __future__ import annotations

import json
import logging
import os
import struct
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from canimucal.device.bus_log import LogFrames, read_log_frames
from canimucal.device.log_decode import (
    DecodedSamples,
    counter_rate,
    decode_samples,
    layout_frames,
    nodes_seen,
    object_value,
    sdo_transfers,
    values_at,
)
from canimucal.device.objects import IDENTITY, NOMINAL, TPDO_COMM, TPDO_MAP, format_key
from canimucal.device.od import parse_key
from canimucal.device.pdo_layout import SampleLayout, default_value, read_layout
from canimucal.errors import InputError
from canimucal.io.grouping import position_rows
from canimucal.io.recording import HeaderValue, Recording, recording_from_columns
from canimucal.model.positions import Plan
from canimucal.model.sensor import DEFAULT_ACCEL_LSB, STANDARD_GRAVITY
from canimucal.model.vocabulary.constants import COUNTER_MODULUS, OUTPUT_DATA_RATES_HZ
from canimucal.procedure.config import ProcedureConfig
from canimucal.procedure.posecheck import FloorFit, measured_force
from canimucal.runtime.recorder import DEFAULT_GUARD_S, ScheduleLabels

logger = logging.getLogger(__name__)

RATE_SNAP = 0.02
"""A rate timed from the log within 2 % of a device rate (0x2010:03's choices) is that rate."""
RATE_DISAGREE = 0.10
"""A claimed rate further than this from the log's timing is warned about."""
FIRST_POSE_TOLERANCE_DEG = ProcedureConfig.first_pose_tolerance_deg
POSE_TOLERANCE_DEG = ProcedureConfig.pose_tolerance_deg
"""``record``'s and the guided procedure's pose tolerances: the first pose, then the others."""
READ_PARAMS_SCHEMA = "canimucal.read-params/1"
PDO_OBJECTS = (*TPDO_COMM, *TPDO_MAP)
"""The objects of a ``pdo`` block: TPDO communication and mapping parameters."""


@dataclass(frozen=True)
class Stretch:
    """A still stretch of the log: rows ``[start, stop)``, its times and the position given."""

    start: int
    stop: int
    t0: float
    t1: float
    position: int = -1
    why: str = ""
    """Why a stretch was left without a position (the pose check's words)."""


@dataclass(frozen=True)
class LogImport:
    """The recording of one node of a bus log, and what the import found on the way.

    ``sources`` says where each header value and the mapping came from (``"0x1018:04 in the
    log"``, ``"EDS default"``, …). The counts are the client's pairing's over the whole log.
    """

    recording: Recording
    node_id: int
    log_format: str
    frames: int
    node_frames: int
    samples: DecodedSamples
    stretches: tuple[Stretch, ...]
    plan: str | None
    sources: dict[str, str] = field(default_factory=dict)
    channel: str | None = None
    several_channels: bool = False

    @property
    def positions(self) -> int:
        """Number of positions labelled."""
        return sum(1 for s in self.stretches if s.position >= 0)


def import_bus_log(
    path: str | os.PathLike[str],
    *,
    node_id: int | None = None,
    pdo_map: str | os.PathLike[str] | None = None,
    plan: Plan | None = None,
    sample_rate_hz: float | None = None,
    header: Mapping[str, HeaderValue] | None = None,
    channel: str | None = None,
    pose_check: bool = True,
    follow_schedule: bool = False,
    transient_s: float = 1.0,
    guard_s: float = DEFAULT_GUARD_S,
) -> LogImport:
    """Read one node's recording out of a bus log (module doc); InputError on bad input.

    ``follow_schedule`` labels by ``plan``'s schedule with ``transient_s`` moves and
    ``guard_s`` guards (``record --follow-schedule``'s), instead of by stillness.
    """
    if follow_schedule and plan is None:
        raise InputError("following a schedule needs the plan the unit followed")
    frames = read_log_frames(path)
    node = _node(frames, node_id)
    sources: dict[str, str] = {}
    layout = _layout(frames, node, pdo_map, sources)
    channel_index, channel_name = _channel(frames, layout, node, channel)
    rows = layout_frames(frames, layout, node, channel_index)
    if rows.size == 0:
        raise InputError(
            f"{frames.source}: node {node} (0x{node:02X}) is not in this log (no TPDO at "
            f"0x{layout.accel.cob_id:X}/0x{layout.gyro.cob_id:X}, no heartbeat); nodes seen: "
            f"{_listed(frames)}"
        )
    first = _first_sample_time(frames, layout, rows)
    transfers = sdo_transfers(frames, node)
    values = values_at(transfers, first)
    rate = _rate(frames, layout, rows, values, sample_rate_hz, sources)
    samples = decode_samples(frames, layout, node, 1.0 / rate, rows)
    block = samples.block
    if block.n < 2:
        raise InputError(
            f"{frames.source}: node {node} sent {block.n} samples (TPDO1 "
            f"0x{layout.accel.cob_id:X}, TPDO2 0x{layout.gyro.cob_id:X}); nothing to record"
        )
    head = _header(node, rate, values, header or {}, plan, sources)
    t = np.maximum.accumulate(block.t)
    columns = {"t": t, "counter": block.counter, "accel": block.accel, "gyro": block.gyro}
    bare = _with_source(
        recording_from_columns(head, temp_c=samples.temp_c, **columns), frames.source
    )
    if follow_schedule and plan is not None:
        schedule = ScheduleLabels(plan, transient_s=transient_s, guard_s=guard_s)
        stretches = _scheduled(bare, schedule, rate)
        sources["positions"] = f"plan {plan.name}'s schedule from the first sample"
    else:
        stretches = _stretches(bare, plan, pose_check, _accel_lsb(head))
        sources["positions"] = _stillness_words(plan, pose_check)
    position, angles = _labels(block.n, stretches, plan)
    recording = recording_from_columns(
        head,
        temp_c=samples.temp_c,
        position=position,
        alpha_deg=angles[:, 0],
        beta_deg=angles[:, 1],
        psi_deg=angles[:, 2],
        **columns,
    )
    return LogImport(
        _with_source(recording, frames.source),
        node,
        frames.format,
        frames.n,
        samples.frames,
        samples,
        stretches,
        plan.name if plan is not None else None,
        sources,
        channel_name,
        len(frames.channels) > 1,
    )


def _stillness_words(plan: Plan | None, pose_check: bool) -> str:
    if plan is None:
        return "still stretches without angles (no plan)"
    checked = "" if pose_check else " (unchecked)"
    return f"still stretches named after plan {plan.name}'s positions in order{checked}"


def _labels(
    n: int, stretches: tuple[Stretch, ...], plan: Plan | None
) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """Each row's position (-1: none) and angles in degrees (NaN: none, or no plan)."""
    position = np.full(n, -1, dtype=np.int64)
    angles = np.full((n, 3), np.nan)
    for stretch in stretches:
        if stretch.position >= 0:
            position[stretch.start : stretch.stop] = stretch.position
            if plan is not None:
                pose = plan.positions[stretch.position]
                angles[stretch.start : stretch.stop] = np.rad2deg(pose.angles)
    return position, angles


def _with_source(recording: Recording, source: str) -> Recording:
    return replace(recording, source=source)


# -------------------------------------------------------------------------------- the node


def _node(frames: LogFrames, node_id: int | None) -> int:
    """``node_id``, else the one IMU of the log (its presence is checked with its mapping)."""
    if node_id is not None:
        return node_id
    imus = [n for n, how in nodes_seen(frames).items() if how == "TPDO1/TPDO2"]
    if len(imus) != 1:
        raise InputError(
            f"{frames.source}: which node? give its node id; nodes seen: {_listed(frames)}"
        )
    return imus[0]


def _listed(frames: LogFrames) -> str:
    seen = nodes_seen(frames)
    return ", ".join(f"{n} (0x{n:02X}, {how})" for n, how in sorted(seen.items())) or "none"


def _channel(
    frames: LogFrames, layout: SampleLayout, node: int, channel: str | None
) -> tuple[int | None, str | None]:
    """Return the channel the node's TPDOs are on: ``channel`` when given, else the only one."""
    rows = layout_frames(frames, layout, node)
    used = sorted({frames.channels[i] for i in np.unique(frames.channel[rows]).tolist()})
    if channel is not None:
        if channel not in frames.channels:
            raise InputError(
                f"{frames.source}: no channel {channel!r} in this log "
                f"(channels: {', '.join(map(repr, frames.channels))})"
            )
        return frames.channels.index(channel), channel
    if len(used) > 1:
        raise InputError(
            f"{frames.source}: node {node}'s TPDOs are on channels {', '.join(map(repr, used))}; "
            "name the channel"
        )
    return None, (used[0] if used else None)


def _first_sample_time(frames: LogFrames, layout: SampleLayout, rows: NDArray[np.intp]) -> float:
    """Log time of the node's first TPDO1 (its SDO values are taken as they were then)."""
    tpdo1 = rows[frames.can_id[rows] == layout.accel.cob_id]
    return float(frames.t[tpdo1[0]]) if tpdo1.size else float("inf")


# ------------------------------------------------------------------------------- mapping


def _layout(
    frames: LogFrames,
    node: int,
    pdo_map: str | os.PathLike[str] | None,
    sources: dict[str, str],
) -> SampleLayout:
    """Return the mapping: the document's, else the log's (EDS defaults for the rest)."""
    if pdo_map is not None:
        objects = read_pdo_document(pdo_map)
        where = f"{Path(pdo_map).name}"

        def read(index: int, sub: int) -> int:
            try:
                return objects[(index, sub)]
            except KeyError:
                raise InputError(
                    f"{pdo_map}: its 'pdo' block has no {format_key(index, sub)}"
                ) from None

    else:
        logged = {
            key: int.from_bytes(t.data, "little")
            for t in sdo_transfers(frames, node)
            if (key := (t.index, t.sub)) and t.index in PDO_OBJECTS
        }
        used: set[tuple[int, int]] = set()
        defaulted: set[tuple[int, int]] = set()

        def read(index: int, sub: int) -> int:
            if (index, sub) in logged:
                used.add((index, sub))
                return logged[(index, sub)]
            defaulted.add((index, sub))
            return default_value(index, sub, node)

        where = ""
    try:
        layout = read_layout(read)
    except ValueError as exc:
        raise InputError(f"{pdo_map or frames.source}: unusable PDO mapping: {exc}") from None
    if pdo_map is None:
        where = "EDS defaults"
        if used:
            rest = f"; {len(defaulted)} at their EDS defaults" if defaulted else ""
            where = f"the log's SDO uploads ({len(used)} objects{rest})"
    sources["mapping"] = where
    return layout


def read_pdo_document(path: str | os.PathLike[str]) -> dict[tuple[int, int], int]:
    """Read the ``pdo`` objects of a ``read-params --json`` document (``{"0x1800:01": …}``)."""
    try:
        doc = json.loads(Path(path).read_text(encoding="utf-8-sig"))
    except (OSError, ValueError) as exc:
        raise InputError(f"{path}: not a read-params JSON document ({exc})") from None
    if not isinstance(doc, dict) or doc.get("schema") != READ_PARAMS_SCHEMA:
        raise InputError(f"{path}: not a read-params JSON document (schema {READ_PARAMS_SCHEMA})")
    block = doc.get("pdo")
    if not isinstance(block, dict):
        raise InputError(
            f"{path}: no 'pdo' block (a read-params JSON document of this version has one)"
        )
    objects: dict[tuple[int, int], int] = {}
    for key, value in block.items():
        index, sub = parse_key(str(key))
        if index not in PDO_OBJECTS:
            raise InputError(f"{path}: pdo.{key}: not a TPDO communication or mapping object")
        if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= 0xFFFFFFFF:
            raise InputError(f"{path}: pdo.{key}: must be an integer 0..4294967295")
        objects[(index, sub)] = value
    return objects


# ---------------------------------------------------------------------------------- rate


def _rate(
    frames: LogFrames,
    layout: SampleLayout,
    rows: NDArray[np.intp],
    values: Mapping[tuple[int, int], bytes],
    given: float | None,
    sources: dict[str, str],
) -> float:
    if given is not None:
        if not (np.isfinite(given) and given > 0):
            raise InputError(f"sample_rate_hz must be a positive number, got {given}")
        sources["sample_rate_hz"] = "given"
        return float(given)
    timed = counter_rate(frames, layout, rows)
    measured = snap_rate(timed) if timed is not None else None
    claimed = object_value(values, NOMINAL, 3)
    if claimed:
        if measured is not None and abs(measured / claimed - 1.0) > RATE_DISAGREE:
            logger.warning(
                "%s: the node says %d Hz (0x2010:03) but the log's times give %.4g Hz; using %d "
                "Hz (a time-scaled or replayed log?); give the sample rate if the times are right",
                frames.source,
                claimed,
                timed,
                claimed,
            )
        sources["sample_rate_hz"] = "0x2010:03 in the log"
        return float(claimed)
    if measured is None:
        raise InputError(
            f"{frames.source}: the log times no two samples and holds no 0x2010:03; "
            "give the sample rate"
        )
    sources["sample_rate_hz"] = "the log's times"
    return measured


def snap_rate(rate: float) -> float:
    """Return the device rate within :data:`RATE_SNAP` of ``rate``, else ``rate`` itself."""
    for device_rate in OUTPUT_DATA_RATES_HZ:
        if abs(rate - device_rate) <= RATE_SNAP * device_rate:
            return float(device_rate)
    return float(rate)


# -------------------------------------------------------------------------------- header


def _header(
    node: int,
    rate: float,
    values: Mapping[tuple[int, int], bytes],
    extra: Mapping[str, HeaderValue],
    plan: Plan | None,
    sources: dict[str, str],
) -> dict[str, HeaderValue]:
    head: dict[str, HeaderValue] = {"sample_rate_hz": rate, "node_id": node}
    serial = object_value(values, IDENTITY, 4)
    if serial is not None:
        head["device_serial"] = serial
        sources["device_serial"] = "0x1018:04 in the log"
    for key, sub in (("accel_lsb", 1), ("gyro_lsb", 2)):
        data = values.get((NOMINAL, sub))
        if data is not None and len(data) == 4:
            value = float(struct.unpack("<f", data)[0])
            if np.isfinite(value) and value != 0.0:
                head[key] = value
                sources[key] = f"0x2010:{sub:02d} in the log"
    if plan is not None:
        head["plan"] = plan.name
        tolerance = max(p.tolerance for p in plan.positions)
        head["tolerance_deg"] = round(float(np.rad2deg(tolerance)), 10)
        sources["plan"] = "given"
    head.update(extra)
    return head


def _accel_lsb(head: Mapping[str, HeaderValue]) -> float:
    value = head.get("accel_lsb")
    return float(value) if isinstance(value, float) else DEFAULT_ACCEL_LSB


# ----------------------------------------------------------------------------- positions


def _stretches(
    recording: Recording, plan: Plan | None, pose_check: bool, accel_lsb: float
) -> tuple[Stretch, ...]:
    """Find the still stretches and the position each is (module doc, step 6)."""
    found, _ = position_rows(recording)
    t = recording.t - recording.t[0]  # seconds into the samples, for messages
    bare = [Stretch(int(r[0]), int(r[-1]) + 1, float(t[r[0]]), float(t[r[-1]])) for r in found]
    if plan is None:
        return tuple(_given(s, i) for i, s in enumerate(bare))
    wanted = len(plan.positions)
    if not pose_check:
        if len(bare) != wanted:
            raise InputError(
                f"{recording.source}: {len(bare)} still stretches for the {wanted} positions of "
                f"plan {plan.name}" + _list(bare)
            )
        return tuple(_given(s, i) for i, s in enumerate(bare))
    return _matched(recording, bare, plan, accel_lsb)


def _scheduled(recording: Recording, schedule: ScheduleLabels, rate: float) -> tuple[Stretch, ...]:
    """Stretches of the samples the schedule holds steady at a position (module doc)."""
    step = np.mod(np.diff(recording.counter), COUNTER_MODULUS)
    seq = np.concatenate(([0.0], np.cumsum(step)))
    labels = schedule.labels(seq / rate)
    edges = np.flatnonzero(np.diff(labels)) + 1
    t = recording.t - recording.t[0]
    out = []
    for start, stop in zip(
        np.concatenate(([0], edges)), np.concatenate((edges, [labels.size])), strict=True
    ):
        if labels[start] >= 0:
            out.append(
                Stretch(
                    int(start), int(stop), float(t[start]), float(t[stop - 1]), int(labels[start])
                )
            )
    return tuple(out)


def _given(stretch: Stretch, position: int, why: str = "") -> Stretch:
    return Stretch(stretch.start, stretch.stop, stretch.t0, stretch.t1, position, why)


def _matched(
    recording: Recording, bare: list[Stretch], plan: Plan, accel_lsb: float
) -> tuple[Stretch, ...]:
    """Match stretches to ``plan``'s positions in order, each by ``record``'s pose check."""
    out: list[Stretch] = []
    floor = FloorFit(STANDARD_GRAVITY)
    nxt = 0
    last_miss = ""
    for stretch in bare:
        if nxt == len(plan.positions):
            out.append(_given(stretch, -1, "after the plan's last position"))
            continue
        pose = plan.positions[nxt]
        rows = np.asarray(recording.accel[stretch.start : stretch.stop], dtype=np.float64)
        mean = np.nanmean(rows, axis=0)
        f = measured_force(mean, accel_lsb)
        tolerance = FIRST_POSE_TOLERANCE_DEG if floor.empty else POSE_TOLERANCE_DEG
        check = floor.check(pose, f, tolerance)
        if not check.passed:
            last_miss = f"position {nxt}: {check.message()}"
            out.append(_given(stretch, -1, f"not position {nxt}: {check.message()}"))
            continue
        floor.add(pose, f)
        out.append(_given(stretch, nxt))
        nxt += 1
    if nxt < len(plan.positions):
        raise InputError(
            f"{recording.source}: {len(bare)} still stretches fit only {nxt} of the "
            f"{len(plan.positions)} positions of plan {plan.name} in order"
            + (f" (last miss: {last_miss})" if last_miss else "")
            + _list(bare)
        )
    return tuple(out)


def _list(stretches: list[Stretch]) -> str:
    shown = ", ".join(f"{s.t0:.1f}–{s.t1:.1f} s" for s in stretches[:12])
    more = f", … ({len(stretches)} in all)" if len(stretches) > 12 else ""
    return f"; still stretches at {shown}{more}" if stretches else "; no still stretch"
