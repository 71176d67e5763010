"""Bad input is a one-line InputError, never an internal error (issue 13, 12 and 13)."""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
import pytest

from canimucal.cli.main import main
from canimucal.errors import InputError
from canimucal.io import recording as recording_module
from canimucal.io.recording import read_recording_csv
from canimucal.io.recording_writer import RecordingWriter
from canimucal.schema import parse_json


def _still(path: Path, accel: Callable[[int], np.ndarray], seconds: float = 60.0) -> Path:
    n = int(200 * seconds)
    rng = np.random.default_rng(5)
    with RecordingWriter.open(path, {"sample_rate_hz": 200.0}) as writer:
        writer.write_rows(
            t=np.arange(n) / 200.0,
            counter=np.arange(n) % 65536,
            accel=accel(n),
            gyro=rng.normal(0.0, 3.0, (n, 3)).round(),
        )
    return path


def test_json_integer_beyond_python_limit_is_input_error() -> None:
    with pytest.raises(InputError, match="integer of 5000 digits"):
        parse_json('{"a": ' + "1" * 5000 + "}", "doc.json")
    assert parse_json('{"a": 12345678901234567890, "b": 1e300}', "doc.json")["b"] == 1e300


def test_json_file_with_huge_integer_exits_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    cal = tmp_path / "cal.json"
    cal.write_text('{"schema": "canimucal.calibration/1", "plan": ' + "9" * 5000 + "}")
    assert main(["write-params", str(cal), "--dry-run"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and "internal" not in err and err.count("\n") == 1


@pytest.mark.parametrize("value", [0.0, 1024.0])
def test_allan_on_constant_data_is_input_error(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], value: float
) -> None:
    path = _still(tmp_path / "c.csv", lambda n: np.full((n, 3), value))
    assert main(["allan", str(path)]) == 2
    err = capsys.readouterr().err
    assert f"accel x is constant ({value:g})" in err and "internal" not in err


def test_allan_still_works_on_noisy_data(tmp_path: Path) -> None:
    rng = np.random.default_rng(9)
    path = _still(tmp_path / "n.csv", lambda n: rng.normal(0, 4.0, (n, 3)).round())
    assert main(["allan", str(path)]) == 0


def test_duplicate_counters_and_rows_are_counted_and_reported(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    path = _still(tmp_path / "d.csv", lambda n: np.arange(3 * n, dtype=float).reshape(n, 3), 1.0)
    lines = path.read_text().splitlines(keepends=True)
    head = sum(1 for line in lines if line.startswith("#")) + 1
    rows = lines[head:]
    doubled = rows[:10] + [rows[9]] * 3 + rows[10:]  # row 9 three more times
    counter_only = rows[20].split(",")
    counter_only[6] = "7777"  # same counter as row 20, other accel: a duplicate counter only
    doubled.insert(24, ",".join(counter_only))
    path.write_text("".join(lines[:head] + doubled))
    with caplog.at_level(logging.WARNING):
        rec = read_recording_csv(path)
    assert (rec.duplicate_counters, rec.duplicate_rows) == (4, 3)
    assert "4 rows repeat an earlier row's counter, 3 rows are exact copies" in caplog.text


def test_clean_recording_reports_no_duplicates(tmp_path: Path) -> None:
    rec = read_recording_csv(_still(tmp_path / "ok.csv", lambda n: np.zeros((n, 3)), 1.0))
    assert (rec.duplicate_counters, rec.duplicate_rows) == (0, 0)


def test_out_of_memory_while_parsing_is_a_clear_message(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    path = _still(tmp_path / "m.csv", lambda n: np.zeros((n, 3)), 1.0)

    def no_memory(*args: Sequence[object]) -> None:
        raise MemoryError

    monkeypatch.setattr(recording_module, "parse_rows", no_memory)
    with pytest.raises(InputError, match="not enough memory to read"):
        read_recording_csv(path)
    assert main(["analyze", str(path)]) == 2
    assert "not enough memory" in capsys.readouterr().err


def test_repeats_further_back_than_the_row_before_are_counted(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    path = _still(tmp_path / "r.csv", lambda n: np.arange(3 * n, dtype=float).reshape(n, 3), 1.0)
    lines = path.read_text().splitlines(keepends=True)
    head = sum(1 for line in lines if line.startswith("#")) + 1
    rows = lines[head:]
    pasted = rows[:60] + rows[40:50] + rows[60:]  # ten rows pasted again, ten rows later
    counter_only = rows[100].split(",")
    counter_only[6] = "7777"  # counter of row 100 again at row 150, other values
    pasted.insert(160, ",".join(counter_only))
    retimed = [f"{i / 200.0!r}," + row.split(",", 1)[1] for i, row in enumerate(pasted)]
    path.write_text("".join(lines[:head] + retimed))  # times go on: the samples came again
    with caplog.at_level(logging.WARNING):
        rec = read_recording_csv(path)
    assert (rec.duplicate_counters, rec.duplicate_rows) == (11, 10)
    assert "11 rows repeat an earlier row's counter, 10 rows are exact copies" in caplog.text


def test_a_wrapped_counter_is_not_a_repeat(tmp_path: Path) -> None:
    # 70,000 samples: the 16-bit counter wraps once, every value recurs 65,536 rows later
    rec = read_recording_csv(_still(tmp_path / "w.csv", lambda n: np.zeros((n, 3)), 350.0))
    assert rec.n_rows == 70_000 and rec.counter[65_536] == rec.counter[0]
    assert (rec.duplicate_counters, rec.duplicate_rows) == (0, 0)


def test_a_file_too_large_for_the_memory_left_is_refused_before_reading(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    path = _still(tmp_path / "big.csv", lambda n: np.zeros((n, 3)), 1.0)
    size = path.stat().st_size
    per_byte = recording_module.STREAMED_MEMORY_PER_FILE_BYTE
    monkeypatch.setattr(recording_module, "available_memory_bytes", lambda: size * (per_byte - 1))

    def never(*args: object) -> None:
        raise AssertionError("the file was parsed")

    monkeypatch.setattr(recording_module, "parse_rows", never)
    with pytest.raises(InputError, match=r"big.csv: not enough memory to read 0 MB \(needs"):
        read_recording_csv(path)
    assert main(["analyze", str(path)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1 and "available" in err


def test_available_memory_sees_the_address_space_limit() -> None:
    import resource

    available = recording_module.available_memory_bytes()
    assert available is not None and available > 0  # Linux: MemAvailable at least
    soft, hard = resource.getrlimit(resource.RLIMIT_AS)
    status = Path("/proc/self/status").read_text()
    vm_kib = int(
        next(line for line in status.splitlines() if line.startswith("VmSize:")).split()[1]
    )
    limit = vm_kib * 1024 + 50 * 2**20  # 50 MiB of address space left
    resource.setrlimit(resource.RLIMIT_AS, (limit, hard))
    try:
        left = recording_module.available_memory_bytes()
    finally:
        resource.setrlimit(resource.RLIMIT_AS, (soft, hard))
    assert left is not None and left <= 60 * 2**20
