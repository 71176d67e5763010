"""Atomic writes: never a partial file, never an overwrite without overwrite=True."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from canimucal.errors import InputError
from canimucal.io import atomic
from canimucal.io.atomic import unique_path, write_text_atomic


def _names(directory: Path) -> list[str]:
    return sorted(p.name for p in directory.iterdir())


def test_write_creates_file_and_leaves_no_temporary(tmp_path: Path) -> None:
    target = tmp_path / "out.json"
    assert write_text_atomic(target, "héllo\n", overwrite=False) == target
    assert target.read_text(encoding="utf-8") == "héllo\n"
    assert _names(tmp_path) == ["out.json"]


def test_existing_file_is_refused_without_overwrite(tmp_path: Path) -> None:
    target = tmp_path / "out.json"
    target.write_text("old")
    with pytest.raises(InputError, match=r"out\.json exists; use overwrite=True to replace it"):
        write_text_atomic(target, "new", overwrite=False)
    assert target.read_text() == "old"
    assert _names(tmp_path) == ["out.json"]


def test_overwrite_replaces(tmp_path: Path) -> None:
    target = tmp_path / "out.json"
    target.write_text("old")
    write_text_atomic(target, "new", overwrite=True)
    assert target.read_text() == "new"
    assert _names(tmp_path) == ["out.json"]


def test_failure_during_write_keeps_old_file_and_no_temporary(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    target = tmp_path / "out.json"
    target.write_text("old")

    def broken_fsync(fd: int) -> None:
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(atomic.os, "fsync", broken_fsync)
    with pytest.raises(InputError, match="cannot write .*: no space left on device"):
        write_text_atomic(target, "new", overwrite=True)
    assert target.read_text() == "old"
    assert _names(tmp_path) == ["out.json"]


def test_missing_directory_is_an_input_error(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="cannot write"):
        write_text_atomic(tmp_path / "nope" / "out.json", "x", overwrite=False)


def test_file_created_concurrently_is_not_replaced(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The existence check passes, then someone creates the file: the link refuses."""
    target = tmp_path / "out.json"
    real_refuse = atomic.refuse_existing

    def refuse_then_create(path: Path, *, overwrite: bool) -> None:
        real_refuse(path, overwrite=overwrite)
        path.write_text("theirs")

    monkeypatch.setattr(atomic, "refuse_existing", refuse_then_create)
    with pytest.raises(InputError, match="exists"):
        write_text_atomic(target, "mine", overwrite=False)
    assert target.read_text() == "theirs"
    assert _names(tmp_path) == ["out.json"]


def test_permissions_follow_umask(tmp_path: Path) -> None:
    old = os.umask(0o022)
    try:
        target = write_text_atomic(tmp_path / "a.txt", "x", overwrite=False)
    finally:
        os.umask(old)
    assert target.stat().st_mode & 0o777 == 0o644


def test_unique_path_counts_up_and_never_overwrites(tmp_path: Path) -> None:
    first = unique_path(tmp_path, "123-20260101T000000.000Z", ".json")
    assert first.name == "123-20260101T000000.000Z.json"
    write_text_atomic(first, "1", overwrite=False)
    second = unique_path(tmp_path, "123-20260101T000000.000Z", "json")
    assert second.name == "123-20260101T000000.000Z-1.json"
    write_text_atomic(second, "2", overwrite=False)
    assert unique_path(tmp_path, "123-20260101T000000.000Z", ".json").name.endswith("-2.json")
    assert first.read_text() == "1" and second.read_text() == "2"


def test_unique_path_rejects_a_stem_with_a_directory(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="invalid file stem"):
        unique_path(tmp_path, "../evil", ".json")
