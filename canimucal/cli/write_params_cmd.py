"""`canimucal write-params CAL.json`: the transactional calibration write of docs/design.md §4.

Validation order: the file (schema, keys, finite numbers, invertible K and S, a backup's
``objects``) before connecting; the device's ranges after reading its nominal LSBs but before
writing anything (both exit 2). A serial other than the file's ``device.serial`` is refused
(exit 3, nothing written) unless ``--force``. A backup file (``objects``) is a valid input
and restores the device bit-exactly. ``--dry-run`` prints the planned SDO writes only.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from canimucal.cli.bus_options import add_bus_options, open_from_args
from canimucal.errors import InputError
from canimucal.io.calibration import Calibration, read_calibration
from canimucal.model.sensor import DEFAULT_ACCEL_LSB, DEFAULT_GYRO_LSB

if TYPE_CHECKING:
    from canimucal.device.client import ImuClient
    from canimucal.device.transaction import WriteReport


def add_subparser(subparsers: Any) -> None:
    """Register ``write-params``."""
    p = subparsers.add_parser(
        "write-params",
        help="write a calibration (or restore a backup) into the IMU node, verified",
        description="Write the calibration JSON into the node transactionally: backup, "
        "invalidate, write, read back bit-exactly, CRC, valid, store; roll back on failure.",
    )
    p.add_argument("calibration", help="calibration JSON (solve's output or a backup)")
    p.add_argument("--dry-run", action="store_true", help="print the planned writes only")
    p.add_argument(
        "--no-store",
        action="store_true",
        help="do not store (0x1010 with the sub-index the node names in 0x2011)",
    )
    p.add_argument("--force", action="store_true", help="write even if the device serial differs")
    p.add_argument(
        "--no-check",
        action="store_true",
        help="write a calibration whose acceptance failed (acceptance.passed false)",
    )
    p.add_argument("--backup-dir", metavar="DIR", help="where the backup of the device goes")
    p.add_argument(
        "--store-sub",
        type=int,
        choices=(1, 3, 4),
        default=None,
        help="0x1010 sub-index to store with (default: the one the node names in 0x2011, "
        "else 1; another only where the node names none; 3 with a warning)",
    )
    p.add_argument(
        "--verify-after-restart",
        action="store_true",
        help="after the store, reset the node (NMT reset node), wait for its boot-up and read "
        "valid and CRC back: proves flash holds the set. RISK: the node restarts, stops "
        "sending meanwhile and loses every value it did not store, and the other nodes see it "
        "reboot; for a bench or commissioning, not a vehicle in service",
    )
    p.add_argument(
        "--store-timeout-s",
        type=float,
        default=10.0,
        metavar="S",
        help="how long the store may take to answer; never retried (default 10)",
    )
    add_bus_options(p)
    p.set_defaults(run=run)


def check_file(path: str, *, no_check: bool = False) -> Calibration:
    """Read and check the calibration before connecting (InputError, exit 2).

    A calibration that failed its acceptance limits is refused unless ``no_check``.
    """
    from canimucal.device.calibration_map import backup_objects, block_from_record

    if not Path(path).is_file():
        raise InputError(f"{path}: no such file")
    record = read_calibration(Path(path))
    if record.acceptance is not None and not record.acceptance.passed and not no_check:
        failed = [
            key
            for key, limit in record.acceptance.limits.items()
            if key in record.acceptance.values
            and not _within(key, record.acceptance.values[key], limit)
        ]
        raise InputError(
            f"{path}: acceptance failed ({', '.join(failed) or 'see the file'}); "
            "not written (--no-check to write it anyway)"
        )
    if backup_objects(record) is None:
        block_from_record(record, DEFAULT_ACCEL_LSB, DEFAULT_GYRO_LSB)  # K, S invertible
    return record


def run(args: argparse.Namespace) -> int:
    """Check the file, connect, write (or plan) on every node."""
    from canimucal.device.transaction import write_calibration_transaction

    record = check_file(args.calibration, no_check=args.no_check)
    store_timeout_s = _store_timeout(args.store_timeout_s)
    if args.verify_after_restart and (args.no_store or args.dry_run):
        raise InputError("--verify-after-restart needs a store: not with --no-store or --dry-run")
    done: list[tuple[str, str]] = []  # written, for an interrupt after it (docs/design.md §9)
    try:
        with open_from_args(args) as session:
            for client in session.clients.values():
                result = write_calibration_transaction(
                    client,
                    record,
                    force=args.force,
                    store=not args.no_store,
                    backup_dir=args.backup_dir,
                    dry_run=args.dry_run,
                    store_sub=args.store_sub,
                    store_timeout_s=store_timeout_s,
                    on_done=_collect(done, client.node_id),
                )
                print(report(result, client.node_id), end="")
                if args.verify_after_restart:
                    print(_verify(client, result), flush=True)
    except KeyboardInterrupt as interrupt:
        notes = list(getattr(interrupt, "__notes__", []))
        for note, backup in done:  # written before the signal came: say so, whatever came after
            if not any(backup in n for n in notes):
                interrupt.add_note(note)
        raise
    return 0


def _verify(client: ImuClient, result: WriteReport) -> str:
    """Restart the node and check what it kept (:mod:`canimucal.device.restart_check`)."""
    from canimucal.device.restart_check import verify_after_restart

    check = verify_after_restart(client, result.crc, result.valid)
    valid = "valid" if result.valid else "valid = 0 (as written)"
    return (
        f"node {client.node_id}: verified after a restart: {valid}, CRC 0x{result.crc:08X} "
        f"(boot-up {check.boot_s:.1f} s after NMT reset node)"
    )


def _collect(done: list[tuple[str, str]], node: int) -> Callable[[WriteReport], None]:
    """Return an ``on_done`` keeping each finished node's note and its backup's name."""

    def keep(result: WriteReport) -> None:
        done.append((finished_note(result, node), str(result.backup_path)))

    return keep


def finished_note(result: WriteReport, node: int) -> str:
    """One line saying what a finished transaction left on the node (for an interrupt)."""
    if result.stored:
        held = "written, stored and read back: RAM and flash hold the new calibration"
    else:
        held = "written and verified in RAM, not stored (--no-store)"
    return f"node {node}: the calibration was {held}; backup of the previous: {result.backup_path}"


def _store_timeout(value: float) -> float:
    if not (math.isfinite(value) and value > 0.0):
        raise InputError(f"--store-timeout-s must be a positive number, got {value}")
    return value


def report(result: WriteReport, node: int) -> str:
    """Describe what was written (or would be) and where the backup went."""
    ident = result.identity
    what = "restore of a backup" if result.restore else "calibration"
    lines = [f"node {node} (serial {ident.serial}): {what}, CRC 0x{result.crc:08X}"]
    if result.serial_forced:
        lines.append("warning: written to another serial than the file's (--force)")
    if result.dry_run:
        lines.append(f"dry run: {len(result.writes)} SDO writes planned, nothing written:")
        lines += [f"  {w.key} = {w.value!r} ({w.data.hex()})" for w in result.writes]
        return "\n".join(lines) + "\n"
    lines.append(f"backup of the previous calibration: {result.backup_path}")
    sub = result.store_sub
    stored = f"stored (0x1010:{sub:02X})" if result.stored and sub else "not stored (--no-store)"
    valid = "valid" if result.valid else "left invalid (valid = 0: nominal values apply)"
    lines.append(f"wrote {len(result.writes)} objects, read back bit-exactly, {valid}, {stored}")
    return "\n".join(lines) + "\n"


def _within(key: str, value: float, limit: float) -> bool:
    """Whether ``value`` meets the limit ``key`` (``min_*`` are lower limits)."""
    return value >= limit if key.startswith("min_") else value <= limit
