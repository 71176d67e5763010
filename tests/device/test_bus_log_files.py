"""Bus log files: formats told by content, and the writer ``record --can-log`` uses.

The logs here are written by python-can's own writers; what is read back is read by its own
readers, so these tests hold the tool to python-can's formats, not to a copy of them.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import can
import pytest

from canimucal.device.bus_log import BusLogWriter, read_log_frames
from canimucal.device.log_formats import FORMAT_NAMES, check_log_target, log_format
from canimucal.errors import InputError

WRITTEN = (".asc", ".blf", ".csv", ".db", ".log", ".trc")
"""The formats python-can writes without extra packages."""


def frames(n: int, channel: str | int | None = "can0") -> list[can.Message]:
    return [
        can.Message(
            timestamp=1_700_000_000.0 + 0.005 * i,
            arbitration_id=0x190 + (i % 2) * 0x100,
            data=bytes([i & 0xFF, i >> 8 & 0xFF, 2, 3, 4, 5, i & 0xFF, 0]),
            is_extended_id=False,
            channel=channel,
        )
        for i in range(n)
    ]


def write_log(path: Path, messages: list[can.Message]) -> Path:
    with can.Logger(path) as writer:
        for msg in messages:
            writer.on_message_received(msg)
    return path


@pytest.mark.parametrize("suffix", WRITTEN)
def test_a_log_is_told_by_its_content(tmp_path: Path, suffix: str) -> None:
    log = write_log(tmp_path / f"x{suffix}", frames(20))
    assert log_format(log) == suffix
    renamed = tmp_path / "capture.bin"
    shutil.copyfile(log, renamed)
    assert log_format(renamed) == suffix
    read = read_log_frames(renamed)
    assert read.n == 20 and read.format == suffix
    assert [read.payload(i) for i in range(3)] == [bytes(m.data) for m in frames(3)]


def test_other_files_are_no_logs(tmp_path: Path) -> None:
    recording = tmp_path / "rec.csv"
    recording.write_text("# schema: canimucal.recording/1\nt,counter\n")
    imucal = tmp_path / "imucal.csv"
    imucal.write_text("n_samples,gyr_x,gyr_y,gyr_z,acc_x,acc_y,acc_z\n0,0,0,0,0,0,9.8\n")
    imutk = tmp_path / "acc.mat"
    imutk.write_text("0.01 32768 32768 34816\n")
    for path in (recording, imucal, imutk):
        assert log_format(path) is None
        with pytest.raises(InputError, match="not a CAN bus log"):
            read_log_frames(path)


def test_the_writer_renames_complete_logs_and_drains_sqlite(tmp_path: Path) -> None:
    """Frames handed over faster than SQLite takes them are all in the file once closed
    (python-can 4.6's SqliteWriter drops all but one batch of 500 when stopped with a queue)."""
    targets = [tmp_path / f"bus{suffix}" for suffix in WRITTEN]
    writer = BusLogWriter(targets)
    sent = frames(3000)
    for msg in sent:
        writer.on_message_received(msg)
    assert not any(t.exists() for t in targets)  # only the .partial files so far
    assert all((tmp_path / f"bus.partial{suffix}").exists() for suffix in WRITTEN)
    assert writer.close() == []
    for target in targets:
        assert read_log_frames(target).n == len(sent), target.suffix
    assert not list(tmp_path.glob("*.partial*"))


def test_a_write_error_stops_that_log_only(tmp_path: Path) -> None:
    """A channel BLF cannot number (16 bits) stops the BLF; the candump log goes on."""
    blf, candump = tmp_path / "bus.blf", tmp_path / "bus.log"
    writer = BusLogWriter([blf, candump])
    for msg in frames(10, channel="can70000"):
        writer.on_message_received(msg)
    failures = writer.close()
    assert len(failures) == 1 and "bus.blf" in failures[0] and "bus.partial.blf" in failures[0]
    assert not blf.exists() and (tmp_path / "bus.partial.blf").exists()
    assert read_log_frames(candump).n == 10


def test_targets_are_checked_before_anything_is_opened(tmp_path: Path) -> None:
    existing = tmp_path / "old.asc"
    existing.write_text("keep")
    stale = tmp_path / "new.partial.trc"
    stale.write_text("an interrupted log")
    for target, words in (
        (tmp_path / "x.txt", "named by its format"),
        (tmp_path / "x.db.gz", "no compressed python-can SQLite"),
        (existing, "exists; use overwrite=True"),
        (tmp_path / "new.trc", "interrupted log"),
    ):
        with pytest.raises(InputError, match=words):
            check_log_target(target, overwrite=False)
    check_log_target(existing, overwrite=True)
    check_log_target(tmp_path / "x.asc.gz", overwrite=False)
    assert set(FORMAT_NAMES) >= set(WRITTEN)
    assert existing.read_text() == "keep"
