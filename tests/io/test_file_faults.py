"""File faults: planted symlinks are never followed, a full disk loses nothing written."""

from __future__ import annotations

import errno
import os
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from canimucal.errors import InputError
from canimucal.io import recording_writer
from canimucal.io.recording import read_recording_csv
from canimucal.io.recording_writer import RecordingWriter

HEADER = {"sample_rate_hz": 200.0}


def _rows(start: int, n: int) -> dict[str, np.ndarray]:
    t = (start + np.arange(n)) / 200.0
    rng = np.random.default_rng(start)
    return {
        "t": t,
        "counter": (start + np.arange(n)) % 65536,
        "accel": rng.integers(-2048, 2048, (n, 3)).astype(float),
        "gyro": rng.integers(-100, 100, (n, 3)).astype(float),
    }


def test_symlink_planted_at_partial_is_refused_with_overwrite(tmp_path: Path) -> None:
    victim = tmp_path / "victim.txt"
    victim.write_text("precious\n")
    target = tmp_path / "out.csv"
    os.symlink(victim, tmp_path / "out.csv.partial")
    with pytest.raises(InputError, match="not a regular file"):
        RecordingWriter.open(target, HEADER, overwrite=True)
    assert victim.read_text() == "precious\n"
    assert os.path.islink(tmp_path / "out.csv.partial") and not target.exists()


def test_dangling_symlink_and_directory_at_partial_are_refused(tmp_path: Path) -> None:
    target = tmp_path / "out.csv"
    os.symlink(tmp_path / "nowhere", tmp_path / "out.csv.partial")
    with pytest.raises(InputError, match="not a regular file"):
        RecordingWriter.open(target, HEADER, overwrite=True)
    assert not (tmp_path / "nowhere").exists()
    os.unlink(tmp_path / "out.csv.partial")
    (tmp_path / "out.csv.partial").mkdir()
    with pytest.raises(InputError, match="not a regular file"):
        RecordingWriter.open(target, HEADER, overwrite=True)


def test_a_regular_leftover_is_replaced_with_overwrite(tmp_path: Path) -> None:
    target = tmp_path / "out.csv"
    (tmp_path / "out.csv.partial").write_text("junk\n")
    with RecordingWriter.open(target, HEADER, overwrite=True) as writer:
        writer.write_rows(**_rows(0, 10))
    assert read_recording_csv(target).n_rows == 10


def test_append_refuses_a_symlinked_recording(tmp_path: Path) -> None:
    real = tmp_path / "real.csv"
    with RecordingWriter.open(real, HEADER) as writer:
        writer.write_rows(**_rows(0, 10))
    before = real.read_bytes()
    link = tmp_path / "link.csv"
    os.symlink(real, link)
    with pytest.raises(InputError, match="symlink"):
        RecordingWriter.open(link, HEADER, append=True)
    assert real.read_bytes() == before and not (tmp_path / "link.csv.partial").exists()


def full_disk_after(budget: int) -> Callable[[int, bytes], int]:
    """An ``os.write`` that fills the ``.partial`` file's disk after ``budget`` bytes.

    Like a real full disk: the write that crosses the limit is short, the next raises ENOSPC.
    """
    real_write = os.write
    left = [budget]

    def write(fd: int, data: bytes) -> int:
        if not os.readlink(f"/proc/self/fd/{fd}").endswith(".partial"):
            return real_write(fd, data)
        if left[0] <= 0:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        n = real_write(fd, bytes(data[: left[0]]))
        left[0] -= n
        return n

    return write


def test_disk_full_keeps_the_partial_cut_at_its_last_complete_row(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    target = tmp_path / "out.csv"
    writer = RecordingWriter.open(target, HEADER)
    head_size = writer.partial_path.stat().st_size
    writer.write_rows(**_rows(0, 100))
    complete = writer.partial_path.read_bytes()
    monkeypatch.setattr(recording_writer.os, "write", full_disk_after(2000))
    with pytest.raises(InputError) as raised:
        writer.write_rows(**_rows(100, 100))
    assert str(raised.value) == (f"disk full writing {target}; 100 rows kept in {target}.partial")
    assert len(complete) > head_size and writer.partial_path.read_bytes() == complete
    with pytest.raises(InputError, match="disk full"):  # later blocks: the same error
        writer.write_rows(**_rows(200, 10))
    assert writer.close() == writer.partial_path  # never renamed
    assert not target.exists()
    monkeypatch.undo()
    assert read_recording_csv(writer.partial_path).n_rows == 100


def test_disk_full_inside_the_context_manager_renames_nothing(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    target = tmp_path / "out.csv"
    monkeypatch.setattr(recording_writer.os, "write", full_disk_after(5000))
    with pytest.raises(InputError, match=r"disk full writing .*out.csv; \d+ rows kept"):
        with RecordingWriter.open(target, HEADER) as writer:
            for start in range(0, 1000, 50):
                writer.write_rows(**_rows(start, 50))
    monkeypatch.undo()
    assert not target.exists()
    kept = read_recording_csv(writer.partial_path)
    assert kept.n_rows == writer.rows_written > 0
    np.testing.assert_array_equal(kept.counter, np.arange(kept.n_rows))


def test_utf8_bom_is_skipped(tmp_path: Path) -> None:
    target = tmp_path / "out.csv"
    with RecordingWriter.open(target, HEADER) as writer:
        writer.write_rows(**_rows(0, 5))
    bom = tmp_path / "bom.csv"
    bom.write_bytes(b"\xef\xbb\xbf" + target.read_bytes())
    assert read_recording_csv(bom).n_rows == 5
