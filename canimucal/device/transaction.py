"""The transactional calibration write of docs/design.md §4 ("Writing is transactional").

(1) identity, serial check before anything is written; (2) nominal LSBs, the block, range
checks before writing; (3) backup of the whole current block to a never-overwritten JSON;
(4) clear valid; (5) write the block in CRC order; (6) read every value back, bytes compared
bit-exactly; (7) write the CRC; (8) set valid; (9) verify valid and CRC; (10) store with
0x1010 unless told not to, only after verification, and read serial, valid and CRC back. Any
failure after (4) but before (10): the backup is written back (valid last) and verified; if
that fails too, valid is left 0 if at all possible and :class:`RollbackIncompleteError`
names the backup. Never valid = 1 over a mixed set.

The store is the commit point (:mod:`canimucal.device.commit`): from its request on nothing
is rolled back, signals are held until the read-back after it, and a restart seen between
the first write and that read-back fails the transaction with what the node holds now.
Before anything is written, a second device answering as the node is refused (exit 4,
:mod:`canimucal.device.answerers`); a signal while the backup is written is held, and an
interrupt after it always names the backup.

The store (docs/design.md §9) uses the 0x1010 sub-index the node documents for its
calibration (0x2011, :mod:`canimucal.device.storage_sub`), else 0x1010:01 after the client
undid its own RAM changes; 0x1010:03 only when asked (with a warning: CiA 301 gives sub 3 to
0x6000–0x9FFF). It is sent once with its own timeout: a node
may erase flash inside its SDO handler for seconds, and a retried 'save' stores twice. On a
store timeout nothing is rolled back (RAM holds a verified set; flash is unknown): the block
is read again and :class:`StoreNotConfirmedError` says what RAM holds.
"""

from __future__ import annotations

import logging
import math
import os
from collections.abc import Callable, Mapping
from dataclasses import dataclass, replace
from datetime import UTC, datetime
from pathlib import Path

from canimucal.device import od
from canimucal.device.answerers import describe_answerers, refuse_second_answerer
from canimucal.device.calibration_map import (
    backup_objects,
    backup_raw,
    block_from_record,
    record_from_readout,
)
from canimucal.device.client import (
    DEFAULT_STORE_TIMEOUT_S,
    CalibrationReadout,
    Identity,
    ImuClient,
)
from canimucal.device.commit import StoreNotConfirmedError, StoreNotVerifiedError, commit_store
from canimucal.device.node_watch import NodeWatch
from canimucal.device.storage_sub import choose_store_sub
from canimucal.errors import (
    DeviceError,
    DuplicateNodeError,
    ForeignSdoClientError,
    InputError,
    NodeRebootedError,
    RollbackIncompleteError,
    SdoAbort,
)
from canimucal.io.atomic import unique_path, write_text_atomic
from canimucal.io.calibration import Calibration, calibration_to_json
from canimucal.signals import deferred_signals
from canimucal.user_dirs import state_dir

logger = logging.getLogger(__name__)

__all__ = [
    "PlannedWrite",
    "StoreNotConfirmedError",
    "StoreNotVerifiedError",
    "WriteReport",
    "write_calibration_transaction",
]

ObjectKey = tuple[int, int]
VALID_KEY: ObjectKey = (od.CAL_INFO, od.CAL_VALID_SUB)
CRC_KEY: ObjectKey = (od.CAL_INFO, od.CAL_CRC_SUB)
_BACKUP_ATTEMPTS = 20


@dataclass(frozen=True)
class PlannedWrite:
    """One SDO download of the plan: object, encoding code, value and the exact bytes."""

    index: int
    sub: int
    code: str
    value: float | int
    data: bytes

    @property
    def key(self) -> str:
        """``"0x2100:01"``."""
        return od.format_key(self.index, self.sub)


@dataclass(frozen=True)
class WriteReport:
    """What the transaction did (or, with ``dry_run``, would do)."""

    identity: Identity
    accel_lsb: float
    gyro_lsb: float
    block: od.CalibrationBlock
    crc: int
    writes: tuple[PlannedWrite, ...]
    backup_path: Path | None
    stored: bool
    dry_run: bool
    serial_forced: bool
    restore: bool
    store_sub: int | None = None
    valid: int = 1
    """The valid flag written last: 0 for a backup that was invalid or whose CRC mismatched."""
    trim_object: bool = True
    """Whether the node has the mounting-trim object 0x2122 (the 42-object CRC layout); a
    node without it was written without the trim (docs/design.md §4)."""

    @property
    def trim_written(self) -> bool:
        """Whether a mounting trim was written (the node has 0x2122)."""
        return self.trim_object and self.block.trim


def default_backup_dir() -> Path:
    """Return ``backups/`` in canimucal's state directory (:mod:`canimucal.user_dirs`).

    On Linux ``$XDG_STATE_HOME/canimucal/backups``, else ``~/.local/state/canimucal/backups``.
    """
    return state_dir() / "backups"


def _planned(index: int, sub: int, code: str, value: float | int) -> PlannedWrite:
    return PlannedWrite(index, sub, code, value, od.encode(code, value))


def plan_writes(
    target: Mapping[ObjectKey, float | int],
    crc: int,
    final_valid: int,
    *,
    store: bool,
    store_sub: int = od.STORE_CALIBRATION_SUB,
    raw: Mapping[ObjectKey, bytes] | None = None,
) -> tuple[PlannedWrite, ...]:
    """List the SDO downloads of steps 4–10 in order: valid 0, block, CRC, valid, store.

    ``raw`` gives the exact bytes of objects a backup kept as bytes (a NaN's payload).
    """
    raw = raw or {}
    writes = [_planned(*VALID_KEY, "u8", 0)]
    writes += [
        PlannedWrite(i, s, c, target[(i, s)], raw[(i, s)])
        if (i, s) in raw
        else _planned(i, s, c, target[(i, s)])
        for i, s, c in od.crc_order(od.has_trim(target))
    ]
    writes += [_planned(*CRC_KEY, "u32", crc), _planned(*VALID_KEY, "u8", final_valid)]
    if store:
        writes.append(_planned(od.STORE, store_sub, "u32", od.SAVE_SIGNATURE))
    return tuple(writes)


def _target(
    record: Calibration, accel_lsb: float, gyro_lsb: float, trim: bool
) -> tuple[od.CalibrationBlock, dict[ObjectKey, float | int], int, int, bool]:
    """Block, CRC-set values, CRC, final valid flag; a backup's ``objects`` taken verbatim.

    ``trim``: the node has the mounting-trim object. A node without it (a firmware before
    0x2122) gets the 39-object layout: the calibration's trim is not written (a warning says
    so) and a backup is translated to that layout (:func:`_backup_target`).
    """
    objects = backup_objects(record)
    if objects is None:
        block = block_from_record(record, accel_lsb, gyro_lsb)
        if not trim:
            if record.mounting_trim_deg is not None:
                logger.warning(
                    "the node has no mounting-trim object 0x2122 (a firmware before it, "
                    "39-object CRC): the mounting trim was not written"
                )
            block = replace(block, mounting_trim_rad=None)
        values = block.to_objects()
        return block, values, od.block_crc(values), 1, False
    return _backup_target(objects, trim)


def _backup_target(
    objects: Mapping[ObjectKey, float | int], trim: bool
) -> tuple[od.CalibrationBlock, dict[ObjectKey, float | int], int, int, bool]:
    """Write a backup back verbatim, or translated to the node's CRC layout.

    Taken from a node of the other layout, a backup whose CRC matched its values is written
    with the node's layout and that layout's CRC: a 39-object backup with a zero trim onto a
    node with 0x2122; a 42-object backup onto a node without it only when its trim is zero
    (InputError otherwise: nothing written). A CRC that did not match stays as it was (the
    caller then restores with valid = 0).
    """
    own = od.has_trim(objects)
    values = {(i, s): objects[(i, s)] for i, s, _ in od.crc_order(own)}
    crc, valid = int(objects[CRC_KEY]), int(objects[VALID_KEY])
    if own != trim:
        if own and any(values[k] != 0.0 for k in od.TRIM_KEYS):
            raise InputError(
                "the backup holds a mounting trim (0x2122) this node does not have (a "
                "firmware before it): nothing written"
            )
        consistent = od.block_crc(values) == crc
        if trim:
            values.update(dict.fromkeys(od.TRIM_KEYS, 0.0))
        else:
            values = {k: v for k, v in values.items() if k not in od.TRIM_KEYS}
        if consistent:
            crc = od.block_crc(values)
        logger.warning(
            "backup of a node %s the mounting-trim object written to one %s it: %s",
            "with" if own else "without",
            "without" if own else "with",
            "the trim dropped" if own else "a zero trim added",
        )
    block = od.CalibrationBlock.from_objects(values)
    bad = _non_finite(values)
    if bad and valid == 1:
        logger.warning("backup holds non-finite values in %s: restored with valid = 0", bad)
        valid = 0
    return block, values, crc, valid, True


def _non_finite(values: Mapping[ObjectKey, float | int]) -> str:
    """Name the keys holding NaN or ±inf, comma-separated ("" when none)."""
    return ", ".join(od.format_key(*key) for key, v in values.items() if not math.isfinite(v))


def _check_serial(identity: Identity, record: Calibration, force: bool) -> bool:
    """Step 1: refuse another device's calibration unless forced; True if forced over one."""
    wanted = record.device.serial
    if identity.serial == wanted:
        return False
    if not force:
        raise DeviceError(
            f"device serial {identity.serial} differs from the calibration file's {wanted}; "
            "nothing written (use force=True to write anyway)",
            options=("force=True",),
        )
    logger.warning("writing serial %d's calibration to device %d (forced)", wanted, identity.serial)
    return True


def write_calibration_transaction(
    client: ImuClient,
    record: Calibration,
    *,
    force: bool = False,
    store: bool = True,
    backup_dir: str | os.PathLike[str] | None = None,
    dry_run: bool = False,
    store_sub: int | None = None,
    store_timeout_s: float = DEFAULT_STORE_TIMEOUT_S,
    on_done: Callable[[WriteReport], None] | None = None,
) -> WriteReport:
    """Write ``record`` (a calibration or a backup with ``objects``) to the node, docs/design.md §4.

    Raises :class:`DeviceError` (exit 3) for a serial mismatch (nothing written) or a
    failure that was rolled back, :class:`RollbackIncompleteError` when the rollback failed,
    :class:`StoreNotConfirmedError` when the store did not answer within ``store_timeout_s``,
    :class:`StoreNotVerifiedError` when the node restarted around the store or read back
    otherwise after it, :class:`DuplicateNodeError` (exit 4) when two devices answer as the
    node, :class:`InputError` (exit 2) for values out of the device's ranges (nothing
    written). ``store_sub`` forces the 0x1010 sub-index (see :func:`choose_store_sub`).
    ``on_done`` gets the report once the set is written (and stored), while signals are
    still held: a caller interrupted after that can still say what was done.
    """
    marks = _Marks(client.foreign_sdo_requests, client.extra_sdo_answers)  # from now on abort
    refuse_second_answerer(client, "nothing written")  # one device per node-id (docs/design.md §9)
    identity = client.identity()  # step 1
    forced = _check_serial(identity, record, force)
    accel_lsb, gyro_lsb = client.nominal_lsb()  # step 2
    trim = client.has_trim_object()  # the node's CRC layout (docs/design.md §4)
    block, values, crc, final_valid, restore = _target(record, accel_lsb, gyro_lsb, trim)
    # a backup of what the device held is written back as it was, non-finite values too
    problems = (
        []
        if restore and _non_finite(values)
        else od.block_range_problems(block, accel_lsb, gyro_lsb)
    )
    if problems:
        more = f" (and {len(problems) - 1} more)" if len(problems) > 1 else ""
        raise InputError(f"calibration outside the device's ranges: {problems[0]}{more}")
    if final_valid == 1 and restore and od.block_crc(values) != crc:
        # edited, or taken while another client wrote: never valid = 1 over such a set
        logger.warning(
            "backup's CRC 0x%08X does not match its values (0x%08X): restored with valid = 0, "
            "nominal values apply",
            crc,
            od.block_crc(values),
        )
        final_valid = 0
    sub = choose_store_sub(client, store_sub) if store else None
    writes = plan_writes(
        values,
        crc,
        final_valid,
        store=sub is not None,
        store_sub=sub or 0,
        raw=backup_raw(record),
    )
    report = WriteReport(
        identity,
        accel_lsb,
        gyro_lsb,
        block,
        crc,
        writes,
        None,
        False,
        dry_run,
        forced,
        restore,
        sub,
        final_valid,
        trim,
    )
    if dry_run:
        return report
    watch = NodeWatch.start(client)  # restarts, heartbeat gaps, EMCY from here on
    before = client.read_calibration_block()  # step 3
    _check_alone(client, marks, "nothing written")
    progress = _Progress()
    try:
        with deferred_signals() as held:  # the backup file is named once it exists
            progress.backup = save_backup(before, identity, client.node_id, backup_dir)
        interrupt = held.interrupt()
        if interrupt is not None:
            raise interrupt
        progress.report = replace(report, backup_path=progress.backup, stored=store)
        progress.on_done = on_done
        _run_with_rollback(
            client, writes, before, progress, identity.serial, marks, store_timeout_s, watch
        )
    except KeyboardInterrupt as exc:
        progress.name_backup(exc)
        raise
    assert progress.report is not None
    return progress.report


@dataclass(frozen=True)
class _Marks:
    """Counts taken before the transaction: a change means another client or device spoke."""

    foreign: int
    answers: int


@dataclass
class _Progress:
    """How far the transaction got: an interrupt's notes must say what was done."""

    backup: Path | None = None
    done: str = ""
    """Set once nothing is to be undone: the set is written (and stored, if asked)."""
    report: WriteReport | None = None
    on_done: Callable[[WriteReport], None] | None = None

    def finished(self, done: str) -> None:
        """Record that the set is written (and stored); tell the caller (signals held)."""
        self.done = done
        if self.on_done is not None and self.report is not None:
            self.on_done(self.report)

    def name_backup(self, interrupt: KeyboardInterrupt) -> None:
        """Make sure an interrupt's notes say what was done and name the backup."""
        notes = getattr(interrupt, "__notes__", [])
        if self.backup is None or any(str(self.backup) in note for note in notes):
            return
        done = self.done or "nothing written"
        interrupt.add_note(f"{done}; backup of the previous calibration: {self.backup}")


def save_backup(
    readout: CalibrationReadout,
    identity: Identity,
    node_id: int,
    backup_dir: str | os.PathLike[str] | None,
) -> Path:
    """Step 3: write the current block as ``<serial>-<UTC ms>[-N].json`` (never overwritten)."""
    directory = Path(backup_dir) if backup_dir is not None else default_backup_dir()
    try:
        directory.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        reason = exc.strerror or exc
        raise InputError(f"cannot create backup directory {directory}: {reason}") from exc
    now = datetime.now(UTC)
    stamp = now.strftime("%Y%m%dT%H%M%S.") + f"{now.microsecond // 1000:03d}Z"
    record = record_from_readout(readout, identity, node_id)
    text = calibration_to_json(record)
    for _ in range(_BACKUP_ATTEMPTS):
        path = unique_path(directory, f"{identity.serial}-{stamp}", ".json")
        try:
            write_text_atomic(path, text, overwrite=False)
        except InputError:
            if path.exists():
                continue  # taken between the check and the write: next name
            raise
        logger.info("backup of the device's calibration: %s", path)
        return path
    raise InputError(f"no free backup name in {directory}")


def _run_with_rollback(
    client: ImuClient,
    writes: tuple[PlannedWrite, ...],
    before: CalibrationReadout,
    progress: _Progress,
    serial: int,
    marks: _Marks,
    store_timeout_s: float,
    watch: NodeWatch,
) -> None:
    """Run steps 4–9, rolling back on failure; then step 10, the commit (:func:`commit_store`).

    A request from another SDO client (``client.foreign_sdo_requests`` past its mark), a
    second answerer, a restart (:class:`NodeWatch`) or an interrupting EMCY is a failure
    like any other: the writes may not have landed where they were meant to.
    """
    backup_path = progress.backup
    assert backup_path is not None
    steps = _steps(writes)
    store = steps.pop()[1][0] if steps[-1][0] == "store" else None
    step = "clear valid"
    commit_hold = deferred_signals()
    try:
        for step, batch in steps:
            _check_alone(client, marks)
            _do_step(client, step, batch, watch)
            _check_alone(client, marks)
        commit_hold.__enter__()  # from here a signal waits for the commit's outcome
    except KeyboardInterrupt as exc:  # Ctrl-C, SIGTERM or SIGHUP (canimucal.signals)
        logger.error("interrupted at %s; rolling back", step)
        with deferred_signals():  # a second interrupt must not skip the rollback
            _rollback(client, before, backup_path)
        exc.add_note(f"previous calibration restored from {backup_path}")
        raise
    except DeviceError as exc:
        verb = "refused" if isinstance(exc, SdoAbort) else "failed"
        if isinstance(exc, NodeRebootedError):
            _refuse_other_unit(client, serial, exc)
        logger.error("calibration write %s at %s: %s; rolling back", verb, step, exc)
        with deferred_signals() as held:
            _rollback(client, before, backup_path)
        message = (
            f"calibration write {verb} at {step}: {exc}; previous calibration restored from "
            f"{backup_path}"
        )
        interrupt = held.interrupt()
        if interrupt is not None:
            interrupt.add_note(message)
            raise interrupt from exc
        raise DeviceError(message) from exc
    if store is None:
        try:
            progress.finished("the calibration was written and verified (not stored: --no-store)")
        finally:
            commit_hold.__exit__(None, None, None)
        interrupt = commit_hold.interrupt()
        if interrupt is not None:
            raise interrupt  # the note says it was written (name_backup)
        return

    def committed() -> None:
        progress.finished(
            "the calibration was written, stored and read back: RAM and flash hold the new "
            "calibration"
        )

    commit_store(
        client,
        store.sub,
        _final_bytes(writes),
        before.raw,
        serial=serial,
        backup_path=backup_path,
        timeout_s=store_timeout_s,
        watch=watch,
        roll_back=lambda: _rollback(client, before, backup_path),
        held=commit_hold,
        on_committed=committed,
    )


def _final_bytes(writes: tuple[PlannedWrite, ...]) -> dict[ObjectKey, bytes]:
    """Bytes of every calibration object once the plan has run (the last write of each)."""
    return {(w.index, w.sub): w.data for w in writes if w.index != od.STORE}


def _check_alone(client: ImuClient, marks: _Marks, consequence: str = "") -> None:
    """Raise when another SDO client spoke to the node or a second device answers as it."""
    if client.foreign_sdo_requests != marks.foreign:
        error = ForeignSdoClientError(client.node_id)
        if consequence:
            raise DeviceError(f"{error}; {consequence}") from error
        raise error
    # answers still due at the mark (another client's request just before) came since: the
    # mark is negative by their number, so only a surplus above zero is a second device
    extra = client.extra_sdo_answers - max(marks.answers, 0)
    if extra > 0:
        text = (
            f"{describe_answerers(client.node_id, [None, None])}: {extra} SDO answer(s) more "
            "than requests"
        )
        if consequence:
            raise DuplicateNodeError(f"{text}; {consequence}")
        raise DeviceError(text)


def _refuse_other_unit(client: ImuClient, serial: int, exc: DeviceError) -> None:
    """After a reboot: a different serial is another unit; write nothing more to it."""
    try:
        now = client.identity().serial
    except DeviceError:
        return  # silent: the rollback will find out
    if now != serial:
        raise DeviceError(
            f"{exc}; the node came back as serial {now}, not {serial}: nothing restored "
            "to another unit"
        ) from exc


def _rollback(client: ImuClient, before: CalibrationReadout, backup_path: Path) -> None:
    """Write the backup back; RollbackIncompleteError (valid left 0 if possible) on failure."""
    try:
        restore_readout(client, before)
    except DeviceError as rollback_exc:
        logger.error("rollback failed: %s", rollback_exc)
        if _holds(client, before):
            logger.info("the device still holds the previous calibration, bit for bit")
            return
        _invalidate_best_effort(client)
        raise RollbackIncompleteError(backup_path) from rollback_exc


def _holds(client: ImuClient, before: CalibrationReadout) -> bool:
    """Tell whether the device answers and holds ``before`` exactly (valid and CRC too)."""
    try:
        return client.read_calibration_block().raw == before.raw
    except DeviceError:
        return False


def _steps(writes: tuple[PlannedWrite, ...]) -> list[tuple[str, list[PlannedWrite]]]:
    """Group the plan into named steps; ``verify`` steps read back what precedes them."""
    n_block = next(k for k, w in enumerate(writes) if (w.index, w.sub) == CRC_KEY) - 1
    block = list(writes[1 : 1 + n_block])
    crc, valid = writes[1 + n_block], writes[2 + n_block]
    steps = [
        ("clear valid", [writes[0]]),
        ("write block", block),
        ("verify block", block),
        ("write CRC", [crc]),
        ("set valid", [valid]),
        ("verify valid and CRC", [crc, valid]),
    ]
    if len(writes) > 3 + n_block:
        steps.append(("store", [writes[3 + n_block]]))
    return steps


def _do_step(client: ImuClient, step: str, batch: list[PlannedWrite], watch: NodeWatch) -> None:
    """Run one step; a restart or an interrupting EMCY since the mark fails it."""
    if step.startswith("verify"):
        verify_bytes(client, batch)
        _check_node(watch, step)
        return
    for write in batch:
        _check_node(watch, step)
        client.sdo.download(write.index, write.sub, write.data)
    _check_node(watch, step)


def _check_node(watch: NodeWatch, step: str) -> None:
    """NodeRebootedError when the node restarted, DeviceError for an interrupting EMCY."""
    restarted = watch.restarted()
    if restarted is not None:
        raise NodeRebootedError(f"{restarted} during {step}")
    emergency = watch.emergency()
    if emergency is not None:
        raise DeviceError(f"{emergency} during {step}")


def _check_no_reboot(client: ImuClient, boots: int, step: str) -> None:
    if client.boots != boots:
        raise NodeRebootedError(f"node rebooted during {step}; its unsaved values are gone")


def verify_bytes(client: ImuClient, writes: list[PlannedWrite]) -> None:
    """Read each object back; DeviceError naming the first whose bytes differ."""
    for write in writes:
        got = client.read_raw(write.index, write.sub, write.code)
        if got != write.data:
            raise DeviceError(
                f"{write.key} read back {got.hex()}, wrote {write.data.hex()} (mismatch)"
            )


def restore_readout(client: ImuClient, before: CalibrationReadout) -> None:
    """Write a read-out block back byte for byte (valid 0 first, valid last) and verify."""
    raw = before.raw
    boots = client.boots
    writes = [_planned(*VALID_KEY, "u8", 0)]
    for index, sub, code in od.crc_order(before.trim):
        data = raw[(index, sub)]
        writes.append(PlannedWrite(index, sub, code, od.decode(code, data), data))
    crc_raw, valid_raw = raw[CRC_KEY], raw[VALID_KEY]
    bad = _non_finite(before.objects)
    if bad and valid_raw != od.encode("u8", 0):
        logger.warning("the previous set holds non-finite values in %s: left valid = 0", bad)
        valid_raw = od.encode("u8", 0)
    crc_write = PlannedWrite(*CRC_KEY, "u32", od.decode("u32", crc_raw), crc_raw)
    valid_write = PlannedWrite(*VALID_KEY, "u8", od.decode("u8", valid_raw), valid_raw)
    for write in writes + [crc_write]:
        client.sdo.download(write.index, write.sub, write.data)
    verify_bytes(client, writes[1:] + [crc_write])
    _check_no_reboot(client, boots, "rollback")
    client.sdo.download(valid_write.index, valid_write.sub, valid_write.data)
    verify_bytes(client, [valid_write, crc_write])
    _check_no_reboot(client, boots, "rollback")
    logger.info("previous calibration written back and verified")


def _invalidate_best_effort(client: ImuClient) -> None:
    """Try once more to leave valid = 0; a silent device cannot be helped."""
    try:
        client.sdo.download(*VALID_KEY, od.encode("u8", 0))
    except DeviceError as exc:
        logger.error("could not clear the valid flag either: %s", exc)
