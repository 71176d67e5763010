"""Writers of the recording CSV (docs/design.md §5): a streaming writer and a whole-file writer.

:class:`RecordingWriter` streams into ``OUT.csv.partial`` (flushed per block) and renames it
to ``OUT.csv`` on :meth:`RecordingWriter.close`, which the context manager calls on any
exit, Ctrl-C included. A process killed outright leaves ``OUT.csv.partial`` with every block
written so far; the target name only ever holds a complete file. Kept apart from the reader
(:mod:`canimucal.io.recording`), whose checks every written block passes too.

The ``.partial`` is created with ``O_CREAT|O_EXCL|O_NOFOLLOW``: a symlink or anything else
planted at its name is refused (exit 2), never written through; the file appended to is read
with ``O_NOFOLLOW`` too. A write error (disk full) cuts the ``.partial`` back to its last
complete row, leaves it under its name for resume and never renames it
(:class:`~canimucal.errors.InputError`, exit 2, saying how many rows it keeps).
"""

from __future__ import annotations

import errno
import logging
import math
import os
import stat
from collections.abc import Mapping
from pathlib import Path
from types import TracebackType

import numpy as np
from numpy.typing import ArrayLike

from canimucal.errors import InputError
from canimucal.io.atomic import (
    move_into_place,
    read_bytes_nofollow,
    refuse_existing,
    temporary_sibling,
    write_text_atomic,
)
from canimucal.io.recording import (
    COLUMN_LINE,
    TRIAL_COLUMN_LINE,
    FloatArray,
    HeaderValue,
    Recording,
    angles_by_position,
    block_table,
    check_same_origin,
    check_table,
    format_header,
    format_table,
    normalise_header,
    parse_recording,
)

logger = logging.getLogger(__name__)


def write_recording(path: str | os.PathLike[str], recording: Recording, *, overwrite: bool) -> Path:
    """Write a whole :class:`Recording` atomically (header, column line, rows)."""
    table = _recording_table(recording)
    check_table(table, 1, str(path))  # a Recording built by hand gets the reader's checks
    column_line, rows = COLUMN_LINE, format_table(table)
    if recording.trial is not None:  # the optional trial column (docs/design.md §5)
        column_line = TRIAL_COLUMN_LINE
        trial = np.where(recording.trial < 0, np.nan, recording.trial.astype(float))
        rows = format_table(np.column_stack([table, trial]))
    text = format_header(recording.header) + column_line + "\n" + rows
    return write_text_atomic(path, text, overwrite=overwrite)


def _recording_table(rec: Recording) -> FloatArray:
    position = np.where(rec.position < 0, np.nan, rec.position.astype(float))
    cols = [rec.t, rec.counter, position, rec.alpha_deg, rec.beta_deg, rec.psi_deg]
    return np.column_stack([*cols, rec.accel, rec.gyro, rec.temp_c])


class RecordingWriter:
    """Streaming writer for the recorder (see the module doc for the ``.partial`` design).

    Use :meth:`open` (or ``with RecordingWriter.open(...) as writer``), then
    :meth:`write_rows` per block, then :meth:`close`.
    """

    def __init__(self, path: Path, fd: int, *, overwrite: bool) -> None:
        self.path = path
        self.partial_path = _partial(path)
        self._fd: int | None = fd
        self._overwrite = overwrite
        self._last_t = -math.inf
        self._angles: dict[int, tuple[float, ...]] = {}
        self._good_size = os.lseek(fd, 0, os.SEEK_END)
        self.rows_written = 0
        self.failed: InputError | None = None
        """The write error that stopped this writer (its ``.partial`` is kept, not renamed)."""
        self.discarded = False
        """Whether :meth:`discard` removed the file (nothing was recorded)."""
        self._header: dict[str, HeaderValue] | None = None  # None: appending, header not ours
        self._head_size = 0
        self._header_fix: dict[str, HeaderValue] = {}

    @classmethod
    def open(
        cls,
        path: str | os.PathLike[str],
        header: Mapping[str, HeaderValue],
        *,
        overwrite: bool = False,
        append: bool = False,
    ) -> RecordingWriter:
        """Start ``path.partial``; with ``append`` it starts as a copy of ``path``.

        Raises :class:`InputError` when ``path`` exists (without ``overwrite``/``append``),
        when ``path.partial`` exists (an interrupted recording: keep or remove it; with
        ``overwrite`` a regular file there is replaced, anything else is refused), or when
        appending to a file whose schema, sample rate or device serial differ.
        """
        target = Path(path)
        partial = _partial(target)
        if os.path.lexists(partial):
            if not overwrite:
                raise InputError(f"{partial} exists (an interrupted recording?); move it away")
            _remove_regular(partial)
        if append:
            return cls._open_append(target, partial, header)
        refuse_existing(target, overwrite=overwrite)
        head = format_header(header) + COLUMN_LINE + "\n"
        writer = cls(target, _create_exclusive(partial), overwrite=overwrite)
        writer._write(head)
        writer._header = dict(header)
        writer._head_size = len(head.encode("utf-8"))
        return writer

    @classmethod
    def _open_append(
        cls, target: Path, partial: Path, header: Mapping[str, HeaderValue]
    ) -> RecordingWriter:
        if not os.path.lexists(target):
            raise InputError(f"cannot append: {target} does not exist")
        raw = read_bytes_nofollow(target)
        old = parse_recording(raw, str(target))
        check_same_origin(old.header, normalise_header(header), old.sample_rate_inferred)
        writer = cls(target, _create_exclusive(partial), overwrite=True)
        writer._write_bytes(raw if raw.endswith(b"\n") or not raw else raw + b"\n")
        writer._last_t = float(old.t[-1]) if old.n_rows else -math.inf
        writer._remember_angles(_recording_table(old))
        return writer

    def write_rows(
        self,
        *,
        t: ArrayLike,
        accel: ArrayLike | None = None,
        gyro: ArrayLike | None = None,
        counter: ArrayLike | None = None,
        position: ArrayLike | None = None,
        alpha_deg: ArrayLike | None = None,
        beta_deg: ArrayLike | None = None,
        psi_deg: ArrayLike | None = None,
        temp_c: ArrayLike | None = None,
    ) -> int:
        """Append one block of rows (``None`` = empty column; position < 0 = empty).

        The block is validated as a reader would (t non-decreasing across blocks, angles
        constant per position) before anything is written. Returns the rows written.
        """
        if self.failed is not None:
            raise self.failed
        table = block_table(t, accel, gyro, counter, position, alpha_deg, beta_deg, psi_deg, temp_c)
        if table.shape[0] == 0:
            return 0
        check_table(table, self.rows_written + 1, f"{self.path} (block)")
        if table[0, 0] < self._last_t:
            raise InputError(f"{self.path}: t goes backwards between blocks")
        self._check_angles_against_earlier(table)
        self._write(format_table(table))
        self._last_t = float(table[-1, 0])
        self._remember_angles(table)
        self.rows_written += table.shape[0]
        return int(table.shape[0])

    def _check_angles_against_earlier(self, table: FloatArray) -> None:
        for label, angles in angles_by_position(table).items():
            known = self._angles.get(label)
            if known is not None and known != angles:
                raise InputError(f"{self.path}: angles change within position {label}")

    def _remember_angles(self, table: FloatArray) -> None:
        self._angles.update(angles_by_position(table))

    def _write(self, text: str) -> None:
        self._write_bytes(text.encode("utf-8"))

    def _write_bytes(self, data: bytes) -> None:
        """Write whole rows; on an OS error cut the file back to the last complete row."""
        if self.failed is not None:
            raise self.failed
        if self._fd is None:
            raise InputError(f"{self.path}: writer is closed")
        view = memoryview(data)
        try:
            while view:
                view = view[os.write(self._fd, view) :]
        except OSError as exc:
            raise self._fail(exc) from exc
        self._good_size += len(data)

    def _fail(self, exc: OSError) -> InputError:
        """Cut the ``.partial`` to its last complete row, close it and say what is kept."""
        fd, self._fd = self._fd, None
        if fd is not None:
            try:
                os.ftruncate(fd, self._good_size)
            except OSError:
                logger.warning("could not cut %s back to its last row", self.partial_path)
            finally:
                os.close(fd)
        what = (
            "disk full" if exc.errno in (errno.ENOSPC, errno.EDQUOT) else f"{exc.strerror or exc}:"
        )
        self.failed = InputError(
            f"{what} writing {self.path}; {self.rows_written} rows kept in {self.partial_path}"
        )
        return self.failed

    def correct_header(self, **values: HeaderValue) -> None:
        """Replace header values (e.g. a measured ``sample_rate_hz``) when the file is closed.

        Appending, the header is the existing file's and is left alone (a warning says so).
        """
        if self._header is None:
            logger.warning("%s: header kept as it was (appending): %s", self.path, values)
            return
        self._header_fix.update(values)

    def _rewrite_header(self) -> None:
        """Copy the ``.partial`` under the corrected header, then swap it in (streamed)."""
        assert self._header is not None
        head = format_header({**self._header, **self._header_fix}) + COLUMN_LINE + "\n"
        tmp = temporary_sibling(self.partial_path)
        src = os.open(self.partial_path, os.O_RDONLY | os.O_NOFOLLOW | os.O_CLOEXEC)
        try:
            dst = _create_exclusive(tmp)
            try:
                os.write(dst, head.encode("utf-8"))
                os.lseek(src, self._head_size, os.SEEK_SET)
                while chunk := os.read(src, 1 << 20):
                    view = memoryview(chunk)
                    while view:
                        view = view[os.write(dst, view) :]
                os.fsync(dst)
            finally:
                os.close(dst)
            os.replace(tmp, self.partial_path)
        finally:
            os.close(src)
            if os.path.lexists(tmp):
                os.unlink(tmp)

    def discard(self) -> bool:
        """Remove the ``.partial`` of a new file that holds no row yet; True if removed.

        For a recording that never started (the device refused to stream): no header-only
        file is left behind. An appended file, or one with rows, is left to :meth:`close`.
        """
        if self._fd is None or self.rows_written or self._header is None:
            return False
        fd, self._fd = self._fd, None
        os.close(fd)
        self.discarded = True
        try:
            os.unlink(self.partial_path)
        except OSError as exc:
            logger.warning("could not remove %s: %s", self.partial_path, exc)
        return True

    def close(self) -> Path:
        """Fsync and rename ``path.partial`` to ``path``; idempotent.

        After a write error (:attr:`failed`) nothing is renamed: the ``.partial`` stays;
        after :meth:`discard` there is no file at all.
        """
        fd, self._fd = self._fd, None
        if fd is None:
            return self.partial_path if self.failed is not None else self.path
        try:
            os.fsync(fd)
        except OSError as exc:
            self._fd = fd
            raise self._fail(exc) from exc
        os.close(fd)
        if self._header_fix:
            try:
                self._rewrite_header()
            except OSError as exc:
                raise InputError(
                    f"cannot correct the header of {self.partial_path}: {exc.strerror or exc}; "
                    f"{self.rows_written} rows kept in it"
                ) from exc
        try:
            move_into_place(self.partial_path, self.path, overwrite=self._overwrite)
        except OSError as exc:
            raise InputError(f"cannot write {self.path}: {exc.strerror or exc}") from exc
        logger.info("wrote %s (%d new rows)", self.path, self.rows_written)
        return self.path

    def __enter__(self) -> RecordingWriter:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()


def _partial(path: Path) -> Path:
    return path.with_name(path.name + ".partial")


def _remove_regular(path: Path) -> None:
    """Remove a leftover regular file; refuse a symlink or anything else (never followed)."""
    mode = os.lstat(path).st_mode
    if not stat.S_ISREG(mode):
        raise InputError(f"{path} exists and is not a regular file; move it away")
    try:
        os.unlink(path)
    except OSError as exc:
        raise InputError(f"cannot remove {path}: {exc.strerror or exc}") from exc


def _create_exclusive(path: Path) -> int:
    """Create ``path`` for writing; refuse an existing name or a symlink there."""
    flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW | os.O_CLOEXEC
    try:
        return os.open(path, flags, 0o666)
    except FileExistsError as exc:
        raise InputError(f"{path} exists; move it away") from exc
    except OSError as exc:
        raise InputError(f"cannot write {path}: {exc.strerror or exc}") from exc
