"""Bus log formats (docs/design.md §5): which files are logs, told by name and by content.

The formats are python-can's: candump ``.log``, Vector ``.asc`` and ``.blf``, PEAK ``.trc``,
python-can's ``.csv`` and ``.db`` (SQLite), ASAM ``.mf4`` (needs asammdf), each optionally
gzip-compressed (``.asc.gz``; python-can writes no compressed ``.blf`` or ``.db``).
:func:`log_format` tells a log from its first bytes, whatever its name (a ``.csv`` may be a
recording or a python-can log). Nothing here imports python-can, so the input dispatcher
and the command line's checks stay light; :mod:`canimucal.device.bus_log` reads and writes.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

from canimucal.errors import InputError
from canimucal.io.atomic import refuse_existing

FORMAT_NAMES: dict[str, str] = {
    ".asc": "Vector ASC",
    ".blf": "Vector BLF",
    ".csv": "python-can CSV",
    ".db": "python-can SQLite",
    ".log": "candump",
    ".mf4": "ASAM MDF4",
    ".trc": "PEAK TRC",
}
"""Every log format python-can both writes and reads, by its file suffix (``.txt`` is a
print-out python-can cannot read back, so it is no log here)."""

UNCOMPRESSABLE = (".blf", ".db")
"""Formats python-can does not write gzip-compressed."""

SNIFF_BYTES = 4096
PYTHON_CAN_CSV_HEADER = "timestamp,arbitration_id,extended,remote,error,dlc,data"
_CANDUMP_LINE = re.compile(r"^\(\s*\d+(\.\d+)?\)\s+\S+\s+[0-9A-Fa-f]{1,8}#")
_ASC_HEADER = ("date ", "base ")


def log_suffix(path: str | os.PathLike[str]) -> tuple[str, bool] | None:
    """Return the log format a name says (``.asc``) and whether it is gzip-compressed."""
    suffixes = [s.lower() for s in Path(path).suffixes]
    compressed = bool(suffixes) and suffixes[-1] == ".gz"
    if compressed:
        suffixes = suffixes[:-1]
    if suffixes and suffixes[-1] in FORMAT_NAMES:
        return suffixes[-1], compressed
    return None


def log_format(path: str | os.PathLike[str]) -> str | None:
    """Tell the log format of ``path`` from its first bytes (``.blf``, …); None: no log.

    A gzip file is a log when its name says which (``x.asc.gz``); its content is not opened.
    Raises :class:`InputError` when the file cannot be read.
    """
    try:
        with open(path, "rb") as handle:
            head = handle.read(SNIFF_BYTES)
    except OSError as exc:
        raise InputError(f"cannot read {path}: {exc.strerror or exc}") from None
    if head.startswith(b"\x1f\x8b"):
        named = log_suffix(path)
        return named[0] if named is not None and named[1] else None
    for magic, suffix in ((b"LOGG", ".blf"), (b"SQLite format 3\0", ".db"), (b"MDF     ", ".mf4")):
        if head.startswith(magic):
            return suffix
    text = head.removeprefix(b"\xef\xbb\xbf").decode("utf-8", errors="replace")
    lines = [line.strip() for line in text.splitlines() if line.strip()]
    if not lines:
        return None
    first = lines[0]
    if first.startswith(";$FILEVERSION") or (first.startswith(";") and "$STARTTIME" in text):
        return ".trc"
    if first.lower().startswith(_ASC_HEADER):
        return ".asc"
    if first == PYTHON_CAN_CSV_HEADER:
        return ".csv"
    if _CANDUMP_LINE.match(first):
        return ".log"
    return None


def partial_log_path(target: Path) -> Path:
    """``NAME.partial.asc`` for ``NAME.asc`` (``NAME.partial.asc.gz`` for ``NAME.asc.gz``)."""
    named = log_suffix(target)
    tail = "".join(target.suffixes[-2:] if named is not None and named[1] else target.suffixes[-1:])
    return target.with_name(target.name.removesuffix(tail) + ".partial" + tail)


def check_log_target(target: Path, *, overwrite: bool) -> None:
    """Refuse, before anything is opened, a log file that cannot be written.

    :class:`InputError` for a name whose suffix python-can writes no log for (``.txt`` is a
    print-out, not a log), a compressed ``.blf``/``.db``, an existing file without
    ``overwrite``, or a ``.partial`` file left by an interrupted log.
    """
    named = log_suffix(target)
    if named is None:
        raise InputError(
            f"{target}: a bus log is named by its format: {', '.join(FORMAT_NAMES)} "
            "(optionally .gz)"
        )
    if named[1] and named[0] in UNCOMPRESSABLE:
        raise InputError(f"{target}: python-can writes no compressed {FORMAT_NAMES[named[0]]}")
    refuse_existing(target, overwrite=overwrite)
    partial = partial_log_path(target)
    if os.path.lexists(partial) and not (overwrite and partial.is_file()):
        raise InputError(f"{partial} exists (an interrupted log?); move it away")
