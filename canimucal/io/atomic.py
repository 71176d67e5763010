"""Atomic file writes and collision-free names (docs/design.md §7: the overwrite rule).

A file is written to a temporary sibling, flushed and fsynced, then moved into place in one
``rename``: a reader sees either the old file or the complete new one, never a partial file.
Without ``overwrite`` the move is a hard link, which the kernel refuses when the target exists,
so even a file created concurrently is never replaced.
"""

from __future__ import annotations

import errno
import logging
import os
import secrets
import stat
from pathlib import Path

from canimucal.errors import InputError

logger = logging.getLogger(__name__)

OVERWRITE = ("overwrite=True",)
"""The option an "exists" error names (the CLI words it ``--overwrite``)."""

_MAX_UNIQUE = 10_000
"""How many ``stem-N`` candidates :func:`unique_path` tries before giving up."""


def write_text_atomic(path: str | os.PathLike[str], text: str, *, overwrite: bool) -> Path:
    """Write ``text`` (UTF-8, LF line ends) to ``path`` atomically and return the path.

    Raises :class:`InputError` when ``path`` exists and ``overwrite`` is false, or when the
    file cannot be written (missing directory, permissions). No temporary file is left behind.
    """
    return write_bytes_atomic(path, text.encode("utf-8"), overwrite=overwrite)


def write_bytes_atomic(path: str | os.PathLike[str], data: bytes, *, overwrite: bool) -> Path:
    """Write ``data`` to ``path`` atomically (see :func:`write_text_atomic`)."""
    target = Path(path)
    refuse_existing(target, overwrite=overwrite)
    tmp = temporary_sibling(target)
    try:
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
        with os.fdopen(fd, "wb") as handle:
            handle.write(data)
            handle.flush()
            os.fsync(handle.fileno())
        move_into_place(tmp, target, overwrite=overwrite)
    except OSError as exc:
        raise InputError(f"cannot write {target}: {_reason(exc)}") from exc
    finally:
        _remove_quietly(tmp)
    logger.debug("wrote %s (%d bytes)", target, len(data))
    return target


def _reason(exc: OSError) -> str:
    """``read-only file system``: the OS's words for the cause, as the user reads them."""
    text = exc.strerror or str(exc)
    return text[:1].lower() + text[1:] if text[:2] != text[:2].upper() else text


def _remove_quietly(path: Path) -> None:
    """Remove a temporary file if it is there; a failure must not hide the first error.

    On a read-only file system even the unlink of a file that was never created fails
    (EROFS before the lookup), and raising it would replace the write's own error.
    """
    try:
        os.unlink(path)
    except FileNotFoundError:
        pass
    except OSError as exc:
        logger.debug("could not remove %s: %s", path, exc)


def make_directory(path: str | os.PathLike[str]) -> Path:
    """Create ``path`` and its parents if missing; :class:`InputError` naming the cause.

    A read-only file system or a directory the user may not write to is a one-line error
    (``cannot create out: read-only file system``), never an internal error.
    """
    directory = Path(path)
    try:
        directory.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"cannot create {directory}: {_reason(exc)}") from exc
    return directory


def refuse_existing(path: Path, *, overwrite: bool) -> None:
    """Raise :class:`InputError` when ``path`` exists and ``overwrite`` is false."""
    if not overwrite and os.path.lexists(path):
        raise InputError(f"{path} exists; use overwrite=True to replace it", options=OVERWRITE)


def read_bytes_nofollow(path: str | os.PathLike[str]) -> bytes:
    """Read a whole file opened with ``O_NOFOLLOW``: a symlink at ``path`` is refused.

    For files the tool appends to or resumes from, so that a link planted there never makes
    it read (and then write) another file. Raises :class:`InputError` on any failure.
    """
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_CLOEXEC)
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise InputError(f"{path} is a symlink; refusing to follow it") from exc
        raise InputError(f"cannot read {path}: {exc.strerror or exc}") from exc
    with os.fdopen(fd, "rb") as handle:
        if not stat.S_ISREG(os.fstat(handle.fileno()).st_mode):
            raise InputError(f"{path} is not a regular file")
        return handle.read()


def temporary_sibling(path: Path) -> Path:
    """Return a fresh hidden name next to ``path`` (same directory, so a rename is atomic)."""
    return path.with_name(f".{path.name}.{secrets.token_hex(6)}.tmp")


def move_into_place(source: Path, target: Path, *, overwrite: bool) -> None:
    """Rename ``source`` to ``target``; without ``overwrite`` never replace an existing file.

    The directory is fsynced afterwards so the new name survives a power cut.
    """
    if overwrite:
        os.replace(source, target)
    else:
        try:
            os.link(source, target)
        except FileExistsError as exc:
            raise InputError(
                f"{target} exists; use overwrite=True to replace it", options=OVERWRITE
            ) from exc
        except OSError:
            # File systems without hard links: a check-then-rename is the best available.
            refuse_existing(target, overwrite=False)
            os.replace(source, target)
        else:
            os.unlink(source)
    _fsync_directory(target.parent)


def _fsync_directory(directory: Path) -> None:
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def unique_path(directory: str | os.PathLike[str], stem: str, suffix: str) -> Path:
    """First free name of ``stem.suffix``, ``stem-1.suffix``, ``stem-2.suffix``, … in ``directory``.

    Used for backups, which are never overwritten. ``suffix`` may be given with or without
    its dot. The name is only free at the time of the call: write it with ``overwrite=False``.
    """
    if not stem or "/" in stem or os.sep in stem:
        raise InputError(f"invalid file stem {stem!r}")
    dot_suffix = suffix if suffix.startswith(".") or not suffix else f".{suffix}"
    base = Path(directory)
    for number in range(_MAX_UNIQUE):
        name = f"{stem}{dot_suffix}" if number == 0 else f"{stem}-{number}{dot_suffix}"
        candidate = base / name
        if not os.path.lexists(candidate):
            return candidate
    raise InputError(f"no free name for {stem}{dot_suffix} in {base}")


def per_node_path(path: str | os.PathLike[str], node: int, several: bool) -> Path:
    """``NAME.node<ID>.EXT`` when there are several nodes, else ``path`` itself."""
    target = Path(path)
    if not several:
        return target
    return target.with_name(f"{target.stem}.node{node}{target.suffix}")
