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
from canimucal.io.recording import read_recording
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
        rec = read_recording(path)
    assert (rec.duplicate_counters, rec.duplicate_rows) == (4, 3)
    assert "4 rows repeat the previous row's counter, 3 rows are exact copies" in caplog.text


def test_clean_recording_reports_no_duplicates(tmp_path: Path) -> None:
    rec = read_recording(_still(tmp_path / "ok.csv", lambda n: np.zeros((n, 3)), 1.0))
    assert (rec.duplicate_counters, rec.duplicate_rows) == (0, 0)


def test_out_of_memory_while_parsing_is_a_clear_message(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    path = _still(tmp_path / "m.csv", lambda n: np.zeros((n, 3)), 1.0)

    def no_memory(*args: Sequence[object]) -> None:
        raise MemoryError

    monkeypatch.setattr(recording_module, "parse_rows", no_memory)
    with pytest.raises(InputError, match="not enough memory to read"):
        read_recording(path)
    assert main(["analyze", str(path)]) == 2
    assert "not enough memory" in capsys.readouterr().err
