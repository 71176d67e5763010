"""Writers of the recording CSV (DESIGN §5): a streaming writer and a whole-file writer.

:class:`RecordingWriter` streams into ``OUT.csv.partial`` (flushed per block) and renames it
to ``OUT.csv`` on :meth:`RecordingWriter.close`, which the context manager calls on any
exit, Ctrl-C included. A process killed outright leaves ``OUT.csv.partial`` with every block
written so far; the target name only ever holds a complete file. Kept apart from the reader
(:mod:`canimucal.io.recording`), whose checks every written block passes too.
"""

from __future__ import annotations

import logging
import math
import os
import shutil
from collections.abc import Mapping
from pathlib import Path
from types import TracebackType
from typing import TextIO

import numpy as np
from numpy.typing import ArrayLike

from canimucal.errors import InputError
from canimucal.io.atomic import move_into_place, refuse_existing, write_text_atomic
from canimucal.io.recording import (
    COLUMN_LINE,
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
    read_recording,
)

logger = logging.getLogger(__name__)


def write_recording(path: str | os.PathLike[str], recording: Recording, *, overwrite: bool) -> Path:
    """Write a whole :class:`Recording` atomically (header, column line, rows)."""
    table = _recording_table(recording)
    check_table(table, 1, str(path))  # a Recording built by hand gets the reader's checks
    text = format_header(recording.header) + COLUMN_LINE + "\n" + format_table(table)
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

    def __init__(self, path: Path, handle: TextIO, *, overwrite: bool) -> None:
        self.path = path
        self.partial_path = _partial(path)
        self._handle: TextIO | None = handle
        self._overwrite = overwrite
        self._last_t = -math.inf
        self._angles: dict[int, tuple[float, ...]] = {}
        self.rows_written = 0

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
        when ``path.partial`` exists (an interrupted recording: keep or remove it), or when
        appending to a file whose schema, sample rate or device serial differ.
        """
        target = Path(path)
        partial = _partial(target)
        if os.path.lexists(partial) and not overwrite:
            raise InputError(f"{partial} exists (an interrupted recording?); move it away")
        if append:
            return cls._open_append(target, partial, header)
        refuse_existing(target, overwrite=overwrite)
        head = format_header(header) + COLUMN_LINE + "\n"
        writer = cls(target, _open_text(partial, append=False), overwrite=overwrite)
        writer._write(head)
        return writer

    @classmethod
    def _open_append(
        cls, target: Path, partial: Path, header: Mapping[str, HeaderValue]
    ) -> RecordingWriter:
        if not target.exists():
            raise InputError(f"cannot append: {target} does not exist")
        old = read_recording(target)
        check_same_origin(old.header, normalise_header(header), old.sample_rate_inferred)
        try:
            shutil.copyfile(target, partial)
        except OSError as exc:
            raise InputError(f"cannot write {partial}: {exc.strerror or exc}") from exc
        writer = cls(target, _open_text(partial, append=True), overwrite=True)
        if not _ends_with_newline(target):
            writer._write("\n")
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
        if self._handle is None:
            raise InputError(f"{self.path}: writer is closed")
        self._handle.write(text)
        self._handle.flush()

    def close(self) -> Path:
        """Flush, fsync and rename ``path.partial`` to ``path``; idempotent."""
        handle, self._handle = self._handle, None
        if handle is None:
            return self.path
        try:
            os.fsync(handle.fileno())
        finally:
            handle.close()
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


def _ends_with_newline(path: Path) -> bool:
    with open(path, "rb") as handle:
        handle.seek(0, os.SEEK_END)
        if handle.tell() == 0:
            return True
        handle.seek(-1, os.SEEK_END)
        return handle.read(1) == b"\n"


def _partial(path: Path) -> Path:
    return path.with_name(path.name + ".partial")


def _open_text(path: Path, *, append: bool) -> TextIO:
    try:
        if append:
            return open(path, "a", encoding="utf-8", newline="\n")
        return open(path, "w", encoding="utf-8", newline="\n")
    except OSError as exc:
        raise InputError(f"cannot write {path}: {exc.strerror or exc}") from exc
