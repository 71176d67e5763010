"""The store as the commit point of a calibration write (docs/design.md §9).

Up to the store the transaction can undo what it wrote: RAM is rolled back and flash was
never written. Once the 'save' request (0x1010) is on its way, flash may hold the new set,
so nothing rolls RAM back any more (that would leave RAM and flash holding different sets
and a message saying "restored" while the next power cycle loads the new one). From just
before the request until the read-back after it, SIGINT, SIGTERM and SIGHUP are held; a
signal that came meanwhile is raised afterwards with a note saying what the device holds.

After the store answered, serial (0x1018:04), valid and CRC are read back. A boot-up, a
heartbeat gap or an NMT state change since the writes began (:class:`NodeWatch`), or a
read-back that differs, fails the transaction (:class:`StoreNotVerifiedError`, exit 3) with
what the node holds now: after a restart RAM holds what flash held, so the read-back tells
both. A store the node refused (SDO abort) or that never left is not a commit: RAM is rolled
back. A store that does not answer in time is neither (:class:`StoreNotConfirmedError`).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Mapping
from pathlib import Path

from canimucal.device import od
from canimucal.device.client import ImuClient
from canimucal.device.node_watch import NodeWatch
from canimucal.errors import DeviceError, SdoAbort, StoreTimeoutError
from canimucal.signals import deferred_signals

logger = logging.getLogger(__name__)

ObjectKey = tuple[int, int]
VALID_KEY: ObjectKey = (od.CAL_INFO, od.CAL_VALID_SUB)
CRC_KEY: ObjectKey = (od.CAL_INFO, od.CAL_CRC_SUB)
SERIAL_KEY: ObjectKey = (od.IDENTITY, 4)


class StoreNotConfirmedError(DeviceError):
    """The store got no answer in time; nothing rolled back (exit 3, docs/design.md §9)."""

    title = "Store not confirmed"


class StoreNotVerifiedError(DeviceError):
    """The store answered, but the node restarted or read back otherwise (exit 3)."""

    title = "Store not verified"


def commit_store(
    client: ImuClient,
    store_sub: int,
    written: Mapping[ObjectKey, bytes],
    previous: Mapping[ObjectKey, bytes],
    *,
    serial: int,
    backup_path: Path,
    timeout_s: float,
    watch: NodeWatch,
    roll_back: Callable[[], None],
    held: deferred_signals,
    on_committed: Callable[[], None] = lambda: None,
) -> None:
    """Store with 0x1010:``store_sub`` and read serial, valid and CRC back (the module doc).

    ``written``/``previous``: the calibration objects' bytes as written and as they were
    (the backup); ``roll_back`` restores ``previous`` in RAM when the store was refused.
    ``held``: the caller's :class:`deferred_signals`, entered before its last check, so no
    signal falls between the verification and the store; it is left here.
    ``on_committed`` runs once the store is read back, signals still held.
    """
    try:
        _store(client, store_sub, timeout_s, watch, roll_back, backup_path)
        _read_back(client, written, previous, serial=serial, watch=watch, backup=backup_path)
        on_committed()
    except DeviceError as exc:
        interrupt = held.interrupt()
        if interrupt is None:
            raise
        interrupt.add_note(str(exc))
        raise interrupt from exc
    finally:
        held.__exit__(None, None, None)
    interrupt = held.interrupt()
    if interrupt is not None:
        interrupt.add_note(
            "the store had begun: it completed and was read back; RAM and flash hold the new "
            f"calibration (backup of the previous: {backup_path})"
        )
        raise interrupt


def _store(
    client: ImuClient,
    sub: int,
    timeout_s: float,
    watch: NodeWatch,
    roll_back: Callable[[], None],
    backup_path: Path,
) -> None:
    """One 'save', its own timeout, never retried; refused or unsent: RAM rolled back."""
    started = time.monotonic()
    try:
        if sub == od.STORE_ALL_SUB:
            client.undo_ram_changes()
        client.store(sub, timeout_s)
    except StoreTimeoutError as exc:
        logger.error("%s", exc)
        raise StoreNotConfirmedError(_timeout_message(client, timeout_s, watch)) from exc
    except DeviceError as exc:  # refused (abort) or never sent: flash was not written
        logger.error("store refused or not sent: %s; rolling back", exc)
        roll_back()
        verb = "refused" if isinstance(exc, SdoAbort) else "failed"
        raise DeviceError(
            f"calibration write {verb} at store: {exc}; previous calibration restored from "
            f"{backup_path}"
        ) from exc
    watch.excuse(time.monotonic() - started)  # a node erasing flash may hold its heartbeat


def _read_back(
    client: ImuClient,
    written: Mapping[ObjectKey, bytes],
    previous: Mapping[ObjectKey, bytes],
    *,
    serial: int,
    watch: NodeWatch,
    backup: Path,
) -> None:
    """Read serial, valid and CRC after the store; StoreNotVerifiedError says what is held."""
    try:
        got = {
            SERIAL_KEY: client.read_raw(*SERIAL_KEY, "u32"),
            VALID_KEY: client.read_raw(*VALID_KEY, "u8"),
            CRC_KEY: client.read_raw(*CRC_KEY, "u32"),
        }
    except DeviceError as exc:
        failed = watch.restarted() or f"the read-back after it failed ({exc})"
        message = _failed(client, failed, written, previous, watch, backup)
        raise StoreNotVerifiedError(message) from exc
    restarted = watch.restarted()
    why = restarted or ""
    if restarted is None:
        wanted = {SERIAL_KEY: od.encode("u32", serial)}
        wanted.update({k: written[k] for k in (VALID_KEY, CRC_KEY)})
        wrong = [od.format_key(*k) for k in wanted if got[k] != wanted[k]]
        if not wrong:
            emergency = watch.emergency()
            if emergency is not None:  # stored and read back: the set stands, the fault is told
                logger.warning("%s while storing; the set was stored and read back", emergency)
            return
        why = f"{', '.join(wrong)} read back otherwise after the store"
    raise StoreNotVerifiedError(_failed(client, why, written, previous, watch, backup))


def _failed(
    client: ImuClient,
    why: str,
    written: Mapping[ObjectKey, bytes],
    previous: Mapping[ObjectKey, bytes],
    watch: NodeWatch,
    backup: Path,
) -> str:
    restarted = watch.restarted() is not None
    held = holdings(client, written, previous)
    if restarted:
        where = f"RAM and flash hold {held} (after a restart RAM holds what flash held)"
    else:
        where = f"RAM holds {held}; what flash holds is known only after a power cycle"
    return (
        f"calibration not confirmed after the store: {why}; {where}; "
        f"backup of the previous calibration: {backup}"
    )


def holdings(
    client: ImuClient, written: Mapping[ObjectKey, bytes], previous: Mapping[ObjectKey, bytes]
) -> str:
    """Say what the node's calibration objects hold now, read afresh."""
    try:
        readout = client.read_calibration_block()
    except DeviceError as exc:
        return f"an unknown set (the node does not answer: {exc})"
    raw = readout.raw
    if all(raw[k] == v for k, v in written.items()):
        return "the new calibration"
    if all(raw[k] == v for k, v in previous.items()):
        return "the previous calibration"
    crc = "CRC ok" if readout.crc_ok else "CRC mismatch"
    if readout.valid == 0:
        return f"valid = 0 ({crc}: nominal values apply)"
    return f"a set that is neither (valid = {readout.valid}, {crc})"


def _timeout_message(client: ImuClient, timeout_s: float, watch: NodeWatch) -> str:
    """Describe what a store timeout leaves: RAM as read now, flash unknown."""
    head = f"store not confirmed in {timeout_s:g} s"
    tail = "what flash holds is known only after a power cycle"
    if watch.restarted() is not None and client.boots != watch.boots:
        return f"{head}; the node rebooted meanwhile and runs what its flash held; {tail}"
    try:
        readout = client.read_calibration_block()
    except DeviceError as exc:
        return f"{head}; the node does not answer ({exc}); {tail}"
    if readout.valid == 1 and readout.crc_ok:
        ram = "RAM holds the new set (valid, CRC ok)"
    else:
        crc = "CRC ok" if readout.crc_ok else "CRC mismatch"
        ram = f"RAM holds valid = {readout.valid}, {crc}"
    return f"{head}; {ram}; {tail}"
