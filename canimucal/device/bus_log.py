"""Bus logs (docs/design.md §5): python-can's log files, written while recording, read back.

The formats and how a file is told to be one are :mod:`canimucal.device.log_formats`'.
Reading uses :func:`can.LogReader` when the file's name says the format its content shows,
and that format's reader class otherwise.

**Writing** (``record --can-log``): :class:`BusLogWriter` holds one :func:`can.Logger` writer
per file and is a :class:`can.Listener` of the network's notifier, so it sees every frame the
client receives; :class:`LoggingNetwork` (canopen's documented ``send_message`` override)
hands it the frames the tool sends too (NMT, SDO requests), as a candump on the same bus
would show them. Writers are not thread-safe: one lock serialises the notifier thread and
the senders. A file is written as ``NAME.partial.SUFFIX`` and renamed when the log stops, so
the name asked for only ever holds a complete log; a write error stops that file (the rest of
the session goes on) and is reported when the log stops.

**Reading** (``import-log``, any input of ``solve``/``analyze``/``allan``):
:func:`read_log_frames` turns a log into :class:`LogFrames`, plain arrays of every data frame
(25 bytes a frame), or one :class:`~canimucal.errors.InputError` naming the file and what the
format's reader could not parse.
"""

from __future__ import annotations

import array
import contextlib
import logging
import os
import threading
import time
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import can
import canopen
import numpy as np
from numpy.typing import NDArray

from canimucal.device.log_formats import (
    FORMAT_NAMES,
    check_log_target,
    log_format,
    log_suffix,
    partial_log_path,
)
from canimucal.errors import InputError
from canimucal.io.atomic import move_into_place

logger = logging.getLogger(__name__)

DRAIN_TIMEOUT_S = 10.0
"""How long stopping waits for a buffered writer (SQLite) to take what it was handed."""
FRAME_BYTES = 8
"""Data bytes kept per frame: a classic CAN frame's; longer (CAN FD) frames are counted apart."""

READERS: dict[str, Any] = {
    ".asc": can.ASCReader,
    ".blf": can.BLFReader,
    ".csv": can.CSVReader,
    ".db": can.SqliteReader,
    ".log": can.CanutilsLogReader,
    ".mf4": can.MF4Reader,
    ".trc": can.TRCReader,
}
"""python-can's reader of each format, for a log whose name does not say its format."""


# ------------------------------------------------------------------------------- reading


@dataclass(frozen=True)
class LogFrames:
    """Every data frame of a log in file order: identifier, bytes, time and channel.

    ``data`` is ``(n, 8)`` with ``dlc`` bytes valid; ``channel`` indexes ``channels`` (the
    log's own names: ``can0``, ``1``, …; ``""`` when the format has none). Error frames,
    remote frames and CAN FD frames longer than 8 bytes are counted, not kept.
    """

    source: str
    format: str
    can_id: NDArray[np.uint32]
    extended: NDArray[np.bool_]
    dlc: NDArray[np.uint8]
    data: NDArray[np.uint8]
    t: NDArray[np.float64]
    channel: NDArray[np.uint16]
    channels: tuple[str, ...]
    error_frames: int = 0
    remote_frames: int = 0
    long_frames: int = 0

    @property
    def n(self) -> int:
        """Number of data frames kept."""
        return int(self.can_id.shape[0])

    def payload(self, i: int) -> bytes:
        """Return the data bytes of frame ``i``."""
        return bytes(self.data[i, : int(self.dlc[i])])


def open_log_reader(path: str | os.PathLike[str], suffix: str) -> Iterable[can.Message]:
    """python-can's reader for ``path`` in format ``suffix`` (from :func:`log_format`).

    :func:`can.LogReader` when the file name says that format (plugins and gzip included),
    else the format's reader class. :class:`InputError` when the reader cannot start.
    """
    named = log_suffix(path)
    try:
        if named is not None and named[0] == suffix:
            return can.LogReader(path)
        return READERS[suffix](path)
    except ImportError as exc:
        raise InputError(f"{path}: reading {FORMAT_NAMES[suffix]} logs needs {exc.name}") from None
    except Exception as exc:  # the format reader's own failure, whatever its type
        raise InputError(f"{path}: not a readable {FORMAT_NAMES[suffix]} log ({exc})") from None


def read_log_frames(path: str | os.PathLike[str], suffix: str | None = None) -> LogFrames:
    """Read every frame of a log (format from content unless ``suffix`` names it).

    Raises :class:`InputError` when the file is no log, cannot be parsed (the reader's own
    complaint, in one line), or holds no data frame.
    """
    source = str(path)
    kind = suffix or log_format(path)
    if kind is None:
        raise InputError(f"{source}: not a CAN bus log ({', '.join(FORMAT_NAMES)})")
    ids, ext, dlcs, chans = (array.array(c) for c in ("I", "B", "B", "H"))
    times = array.array("d")
    data = bytearray()
    channels: dict[str, int] = {}
    errors = remotes = longs = 0
    reader = open_log_reader(path, kind)
    try:
        for msg in reader:
            if msg.is_error_frame:
                errors += 1
                continue
            if msg.is_remote_frame:
                remotes += 1
                continue
            if len(msg.data) > FRAME_BYTES:
                longs += 1
                continue
            name = "" if msg.channel is None else str(msg.channel)
            chans.append(channels.setdefault(name, len(channels)))
            ids.append(msg.arbitration_id)
            ext.append(msg.is_extended_id)
            dlcs.append(len(msg.data))
            times.append(msg.timestamp)
            data += bytes(msg.data).ljust(FRAME_BYTES, b"\0")
    except Exception as exc:  # the format reader's own failure on a corrupt file
        where = f" after frame {len(ids)}" if len(ids) else ""
        problem = " ".join(str(exc).split()) or type(exc).__name__
        raise InputError(
            f"{source}: not a readable {FORMAT_NAMES[kind]} log{where} ({problem})"
        ) from None
    finally:
        with contextlib.suppress(Exception):
            reader.stop()  # type: ignore[attr-defined]
    if not ids:
        raise InputError(f"{source}: no CAN data frame in this {FORMAT_NAMES[kind]} log")
    frames = LogFrames(
        source,
        kind,
        np.frombuffer(ids, dtype=np.uint32).copy(),
        np.frombuffer(ext, dtype=np.uint8).astype(bool),
        np.frombuffer(dlcs, dtype=np.uint8).copy(),
        np.frombuffer(bytes(data), dtype=np.uint8).reshape(-1, FRAME_BYTES).copy(),
        np.frombuffer(times, dtype=np.float64).copy(),
        np.frombuffer(chans, dtype=np.uint16).copy(),
        tuple(channels),
        errors,
        remotes,
        longs,
    )
    logger.info(
        "%s: %d data frames (%s), %d error and %d remote frames",
        source,
        frames.n,
        FORMAT_NAMES[kind],
        errors,
        remotes,
    )
    return frames


# ------------------------------------------------------------------------------- writing


@dataclass
class _OpenLog:
    target: Path
    partial: Path
    writer: Any
    frames: int = 0
    error: str | None = None


class BusLogWriter(can.Listener):
    """Writes every frame it is given into one or more log files (module doc).

    Opening refuses what :func:`check_log_target` refuses, and a format python-can cannot
    write here (``.mf4`` without asammdf). :meth:`stop` closes every file and renames the
    complete ones into place; it returns one line per file that failed.
    """

    def __init__(self, targets: Sequence[Path], *, overwrite: bool = False) -> None:
        self._lock = threading.Lock()
        self._logs: list[_OpenLog] = []
        self._channel: Any = None
        self._overwrite = overwrite
        self._stopped = False
        try:
            for target in targets:
                self._logs.append(self._open(Path(target)))
        except BaseException:
            self.close()
            raise

    def _open(self, target: Path) -> _OpenLog:
        check_log_target(target, overwrite=self._overwrite)
        partial = partial_log_path(target)
        with contextlib.suppress(FileNotFoundError):
            os.unlink(partial)  # a regular file, checked above
        try:
            writer = can.Logger(partial)
        except ImportError as exc:
            raise InputError(f"{target}: writing this format needs {exc.name}") from None
        except (OSError, ValueError) as exc:
            raise InputError(f"cannot write bus log {target}: {exc}") from None
        logger.info("logging the bus to %s", target)
        return _OpenLog(target, partial, writer)

    @property
    def targets(self) -> list[Path]:
        """The files this writer logs into."""
        return [log.target for log in self._logs]

    @property
    def written(self) -> list[tuple[Path, int]]:
        """Each file and the frames written into it so far."""
        return [(log.target, log.frames) for log in self._logs]

    def on_message_received(self, msg: can.Message) -> None:
        """Log a received frame (the notifier's thread); never raises."""
        with self._lock:
            if self._channel is None and msg.channel is not None:
                self._channel = msg.channel
            for log in self._logs:
                if log.error is None:
                    self._write(log, msg)

    def _write(self, log: _OpenLog, msg: can.Message) -> None:
        try:
            log.writer.on_message_received(msg)
            log.frames += 1
        except Exception as exc:  # a full disk, a closed file: this log stops, the session not
            log.error = " ".join(str(exc).split()) or type(exc).__name__
            logger.error("bus log %s stopped: %s", log.target, log.error)
            with contextlib.suppress(Exception):
                log.writer.stop()

    def name_channel(self, channel: Any) -> None:
        """Name the bus the frames the tool sends are on (the channel the bus was opened on)."""
        with self._lock:
            if self._channel is None:
                self._channel = channel

    def sent(self, can_id: int, data: bytes, remote: bool = False) -> None:
        """Log a frame the tool sent (transmitted: ``is_rx`` false), stamped now."""
        msg = can.Message(
            timestamp=time.time(),
            arbitration_id=can_id,
            is_extended_id=can_id > 0x7FF,
            is_remote_frame=remote,
            data=bytes(data),
            is_rx=False,
            channel=self._channel,
        )
        self.on_message_received(msg)

    def stop(self) -> None:
        """Close every file (:meth:`close`); python-can's listener protocol."""
        self.close()

    def close(self) -> list[str]:
        """Close every file; rename the complete ones. Returns the failures, one line each."""
        with self._lock:
            if self._stopped:
                return []
            self._stopped = True
            failures = []
            for log in self._logs:
                problem = log.error or self._close(log)
                if problem is None:
                    try:
                        move_into_place(log.partial, log.target, overwrite=self._overwrite)
                        logger.info("bus log %s: %d frames", log.target, log.frames)
                        continue
                    except (OSError, InputError) as exc:
                        problem = str(exc)
                failures.append(
                    f"bus log {log.target}: {problem}; what was logged is in {log.partial}"
                )
            return failures

    @staticmethod
    def _close(log: _OpenLog) -> str | None:
        """Stop a writer; a buffered one (SQLite) is first given time to take its queue.

        python-can 4.6's SqliteWriter, stopped with more than 500 frames queued, writes one
        batch and drops the rest; waiting for the queue to empty avoids that.
        """
        buffer = getattr(log.writer, "buffer", None)
        deadline = time.monotonic() + DRAIN_TIMEOUT_S
        while buffer is not None and not buffer.empty() and time.monotonic() < deadline:
            time.sleep(0.01)
        try:
            log.writer.stop()
        except Exception as exc:  # the writer's own failure while flushing
            return " ".join(str(exc).split()) or type(exc).__name__
        return None


class LoggingNetwork(canopen.Network):
    """A canopen network whose frames, received and sent, also go to a :class:`BusLogWriter`.

    The writer is the notifier's last listener (after canopen's own, so nothing it does can
    keep a frame from the client); sent frames reach it through ``send_message``, which
    canopen documents for overriding. Periodic frames (SYNC from ``sync_producer``) leave
    through python-can's broadcast manager and are not logged.
    """

    def __init__(self, bus: can.BusABC, bus_log: BusLogWriter, channel: Any = None) -> None:
        super().__init__(bus)
        self.bus_log = bus_log
        bus_log.name_channel(channel)
        self.listeners.append(bus_log)  # type: ignore[arg-type]  # any can.Listener

    def send_message(self, can_id: int, data: bytes, remote: bool = False) -> None:
        """Send a frame (canopen's) and log it once it has left."""
        super().send_message(can_id, data, remote)
        self.bus_log.sent(can_id, data, remote)
