"""The reader's compact columns and chunked whole-file checks (issue 23).

Values that fit float32 exactly are kept as float32 and read back exactly; one value that
does not, in any block, makes its column float64 without changing the earlier rows; the
repeats and held-sample checks give the same counts whatever their chunk size.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import canimucal.analysis.repeats as repeats_module
import canimucal.io.recording as recording_module
from canimucal.analysis.repeats import repeated_rows
from canimucal.io.recording import (
    COLUMN_LINE,
    count_duplicates_columns,
    read_recording_csv,
    recording_from_columns,
)

HEADER = "# schema: canimucal.recording/1\n# sample_rate_hz: 200\n"


def _rows(n: int, temp: str = "25", angle: str = "22.5") -> list[str]:
    rng = np.random.default_rng(5)
    counts = rng.integers(-2048, 2048, size=(n, 6))
    return [
        f"{0.005 * i:.6f},{i % 65536},{i // 1000},{angle},0,0,"
        + ",".join(map(str, counts[i]))
        + f",{temp}"
        for i in range(n)
    ]


def _write(path: Path, rows: list[str]) -> Path:
    path.write_text(HEADER + COLUMN_LINE + "\n" + "\n".join(rows) + "\n", encoding="utf-8")
    return path


def test_exact_values_are_kept_as_float32(tmp_path: Path) -> None:
    rows = _rows(3000)
    rec = read_recording_csv(_write(tmp_path / "r.csv", rows))
    assert rec.t.dtype == np.float64 and rec.position.dtype == np.int64
    for name in ("counter", "alpha_deg", "accel", "gyro", "temp_c"):
        assert getattr(rec, name).dtype == np.float32, name
    table = np.array([[float(c) for c in row.split(",")] for row in rows])
    assert np.array_equal(rec.accel, table[:, 6:9]) and np.array_equal(rec.gyro, table[:, 9:12])
    assert np.array_equal(rec.counter, table[:, 1]) and np.all(rec.alpha_deg == 22.5)


def test_a_value_float32_cannot_hold_widens_its_column_only(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(recording_module, "CHUNK_BYTES", 4096)  # many blocks
    rows = _rows(3000)
    last = rows[-1].rsplit(",", 1)[0]
    rows[-1] = last + ",25.1"  # the last block's temperature is no float32
    rec = read_recording_csv(_write(tmp_path / "r.csv", rows))
    assert rec.temp_c.dtype == np.float64 and rec.accel.dtype == np.float32
    assert rec.temp_c[-1] == 25.1 and np.all(rec.temp_c[:-1] == 25.0)


def test_columns_built_in_memory_read_back_exactly() -> None:
    t = np.arange(5) * 0.005
    accel = np.array([[0.1, 2.0, 3.0]] * 5)  # 0.1 is no float32
    rec = recording_from_columns({"sample_rate_hz": 200.0}, t=t, accel=accel)
    assert rec.accel.dtype == np.float64 and np.array_equal(rec.accel, accel)


@pytest.mark.parametrize("chunk", [7, 1000, 40_000])
def test_repeat_counts_do_not_depend_on_the_chunk(
    chunk: int, monkeypatch: pytest.MonkeyPatch
) -> None:
    rng = np.random.default_rng(11)
    n = 20_000
    counter = (np.arange(n) % 65536).astype(float)
    values = rng.integers(0, 3, size=(n, 3)).astype(float)
    for i in rng.choice(np.arange(40, n), size=60, replace=False):  # re-sent frames
        back = int(rng.integers(1, 40))
        counter[i] = counter[i - back]
        if rng.random() < 0.5:
            values[i] = values[i - back]
    counter[rng.choice(n, size=50, replace=False)] = np.nan
    t = np.arange(n) * 0.005
    whole = count_duplicates_columns(t, counter, [values])
    monkeypatch.setattr(recording_module, "DUPLICATE_CHUNK_ROWS", chunk)
    assert count_duplicates_columns(t, counter, [values]) == whole
    assert whole[0] >= 60 and whole[1] > 0


@pytest.mark.parametrize("chunk", [5, 333, 10_000])
def test_held_samples_do_not_depend_on_the_chunk(
    chunk: int, monkeypatch: pytest.MonkeyPatch
) -> None:
    rng = np.random.default_rng(3)
    n = 4000
    accel = np.repeat(rng.integers(-50, 50, size=(n // 2, 3)), 2, axis=0).astype(float)
    gyro = np.repeat(rng.integers(-50, 50, size=(n // 2, 3)), 2, axis=0).astype(float)
    gyro[::97] = np.nan  # lost halves are never repeats
    rec = recording_from_columns(
        {"sample_rate_hz": 200.0}, t=np.arange(n) * 0.005, accel=accel, gyro=gyro
    )
    same, held = repeated_rows(rec)
    monkeypatch.setattr(repeats_module, "REPEAT_CHUNK_ROWS", chunk)
    same_chunked, held_chunked = repeated_rows(rec)
    assert np.array_equal(same, same_chunked) and held == held_chunked
    assert held is not None and held.repeated == int(same.sum())
