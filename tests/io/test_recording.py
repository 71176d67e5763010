"""Recording CSV: round trips, strict reading with located errors, the streaming writer."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import canimucal.io.recording as recording_module
from canimucal.errors import InputError
from canimucal.io.recording import (
    COLUMN_LINE,
    Recording,
    read_recording_csv,
    recording_from_columns,
)
from canimucal.io.recording_writer import RecordingWriter, write_recording
from tests.support.recordings import write_bulk_recording

HEADER = (
    "# schema: canimucal.recording/1\n"
    "# sample_rate_hz: 200\n"
    "# device_serial: 42\n"
    "# node_id: 16\n"
    "# g: 9.80665\n"
    "# latitude_deg: 50.45\n"
)
ROWS = [
    "1700000000.000000,0,,,,,10,-2048,5,1,2,3,25.0",
    "1700000000.005000,1,0,0,0,0,11,-2047,4,,,,25.0",
    "1700000000.010000,2,0,0,0,0,12,-2049,6,2,1,3,",
    "1700000000.015000,4,1,22.5,2.5,0,-780,-1890,80,1,2,3,25.5",
    "1700000000.020000,5,1,22.5,2.5,0,,,,1,2,3,25.5",
    "1700000000.025000,6,1,22.5,2.5,0,-781,-1891,81,1,2,3,25.5",
]
SAMPLE = HEADER + COLUMN_LINE + "\n" + "\n".join(ROWS) + "\n"
FIRST_ROW_LINE = 8  # six header lines, the column line, then the rows


def _write(tmp_path: Path, text: str, name: str = "rec.csv") -> Path:
    path = tmp_path / name
    path.write_bytes(text.encode("utf-8"))
    return path


def _same(a: Recording, b: Recording) -> None:
    assert a.header == b.header
    for name in ("t", "counter", "position", "alpha_deg", "beta_deg", "psi_deg", "temp_c"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    np.testing.assert_array_equal(a.accel, b.accel)
    np.testing.assert_array_equal(a.gyro, b.gyro)


def _random_recording(rng: np.random.Generator, n: int) -> Recording:
    position = np.repeat(np.arange(n // 50 + 1), 50)[:n]
    position[::9] = -1
    angles = np.where(position[:, None] >= 0, position[:, None] * [7.5, 1.25, 0.0], np.nan)
    gyro = rng.integers(-40, 40, (n, 3)).astype(float)
    gyro[::13] = np.nan
    accel = rng.integers(-2100, 2100, (n, 3)).astype(float)
    accel[::17] = np.nan
    accel[::17][:, 0] = np.nan
    gyro[::17] = rng.normal(0, 5, (len(gyro[::17]), 3))  # a row keeps at least one half
    temp = 25 + rng.normal(0, 0.1, n)
    temp[::5] = np.nan
    return recording_from_columns(
        {"sample_rate_hz": 200.0, "device_serial": 42, "accel_lsb": 0.0047884033203125},
        t=1.7e9 + np.arange(n) / 200 + rng.uniform(0, 1e-4, n),
        accel=accel,
        gyro=gyro,
        counter=np.arange(n) % 65536,
        position=position,
        alpha_deg=angles[:, 0],
        beta_deg=angles[:, 1],
        psi_deg=angles[:, 2],
        temp_c=temp,
    )


# ------------------------------------------------------------------------------ reading


def test_sample_is_parsed_with_types_and_empties(tmp_path: Path) -> None:
    rec = read_recording_csv(_write(tmp_path, SAMPLE))
    assert rec.header == {
        "schema": "canimucal.recording/1",
        "sample_rate_hz": 200.0,
        "device_serial": 42,
        "node_id": 16,
        "g": 9.80665,
        "latitude_deg": 50.45,
    }
    assert isinstance(rec.header["device_serial"], int)
    assert rec.sample_rate_hz == 200.0 and not rec.sample_rate_inferred
    assert rec.n_rows == 6
    np.testing.assert_array_equal(rec.position, [-1, 0, 0, 1, 1, 1])
    assert rec.position.dtype == np.int64
    np.testing.assert_array_equal(rec.alpha_deg, [np.nan, 0, 0, 22.5, 22.5, 22.5])
    np.testing.assert_array_equal(rec.gyro[1], [np.nan] * 3)
    np.testing.assert_array_equal(rec.accel[4], [np.nan] * 3)
    np.testing.assert_array_equal(rec.temp_c, [25.0, 25.0, np.nan, 25.5, 25.5, 25.5])
    np.testing.assert_array_equal(rec.counter, [0, 1, 2, 4, 5, 6])
    assert rec.t[1] == pytest.approx(1700000000.005, abs=1e-9)


def test_arrays_are_read_only(tmp_path: Path) -> None:
    rec = read_recording_csv(_write(tmp_path, SAMPLE))
    with pytest.raises(ValueError):
        rec.accel[0, 0] = 1.0


def test_crlf_file_reads_the_same(tmp_path: Path) -> None:
    a = read_recording_csv(_write(tmp_path, SAMPLE))
    b = read_recording_csv(_write(tmp_path, SAMPLE.replace("\n", "\r\n"), "crlf.csv"))
    _same(a, b)


def test_missing_last_newline_is_fine(tmp_path: Path) -> None:
    rec = read_recording_csv(_write(tmp_path, SAMPLE.rstrip("\n")))
    assert rec.n_rows == 6


def test_header_and_columns_only_is_an_empty_recording(tmp_path: Path) -> None:
    rec = read_recording_csv(_write(tmp_path, HEADER + COLUMN_LINE + "\n"))
    assert rec.n_rows == 0 and rec.accel.shape == (0, 3)


def test_sample_rate_is_inferred_from_t_and_flagged(tmp_path: Path) -> None:
    text = SAMPLE.replace("# sample_rate_hz: 200\n", "")
    rec = read_recording_csv(_write(tmp_path, text))
    assert rec.sample_rate_inferred
    assert rec.sample_rate_hz == 200.0  # snapped to the device rate


def test_inferred_rate_off_the_device_rates_is_kept(tmp_path: Path) -> None:
    rows = [f"{k / 119.0:.6f},{k},,,,,1,2,3,,,," for k in range(50)]
    text = "# schema: canimucal.recording/1\n" + COLUMN_LINE + "\n" + "\n".join(rows) + "\n"
    rec = read_recording_csv(_write(tmp_path, text))
    assert rec.sample_rate_hz == pytest.approx(119.0, rel=1e-3)


def test_sample_rate_cannot_be_inferred_from_one_row(tmp_path: Path) -> None:
    text = HEADER.replace("# sample_rate_hz: 200\n", "") + COLUMN_LINE + "\n" + ROWS[0] + "\n"
    with pytest.raises(InputError, match="no sample_rate_hz header and t does not give one"):
        read_recording_csv(_write(tmp_path, text))


def _replace_row(index: int, new: str) -> str:
    rows = list(ROWS)
    rows[index] = new
    return HEADER + COLUMN_LINE + "\n" + "\n".join(rows) + "\n"


MALFORMED = [
    # (id, text, line number in the message or None, words the message must contain)
    ("no schema", SAMPLE.replace("# schema: canimucal.recording/1\n", ""), None, "schema"),
    ("schema v2", SAMPLE.replace("recording/1", "recording/2"), 1, "unknown schema"),
    ("unknown key", SAMPLE.replace("# g:", "# gee:"), 5, "unknown header key 'gee'"),
    ("duplicate key", SAMPLE.replace("# g:", "# node_id: 3\n# g:"), 5, "duplicate header key"),
    ("bad rate", SAMPLE.replace("sample_rate_hz: 200", "sample_rate_hz: fast"), 2, "bad value"),
    ("nan rate", SAMPLE.replace("sample_rate_hz: 200", "sample_rate_hz: nan"), 2, "bad value"),
    ("zero rate", SAMPLE.replace("sample_rate_hz: 200", "sample_rate_hz: 0"), 2, "> 0"),
    ("bad node", SAMPLE.replace("node_id: 16", "node_id: 300"), 4, "1..127"),
    ("latitude", SAMPLE.replace("latitude_deg: 50.45", "latitude_deg: 95"), 6, "±90"),
    ("not key value", SAMPLE.replace("# g: 9.80665", "# hello"), 5, "'# key: value'"),
    ("missing column", SAMPLE.replace(",temp_c\n", "\n"), 7, "missing columns temp_c"),
    ("column order", SAMPLE.replace("ax,ay,az", "ay,ax,az"), 7, "column line must be"),
    ("no column line", HEADER, 7, "missing column line"),
    ("short row", _replace_row(2, "1700000000.010000,2,0,0,0,0,12,-2049,6,2,1,3"), 10, "13 cells"),
    ("long row", _replace_row(0, ROWS[0] + ",1"), 8, "13 cells"),
    ("text cell", _replace_row(1, ROWS[1].replace(",11,", ",abc,")), 9, "non-numeric cell"),
    ("nan text", _replace_row(1, ROWS[1].replace(",11,", ",nan,")), 9, "leave unknown"),
    ("NaN text", _replace_row(1, ROWS[1].replace(",11,", ",NaN,")), 9, "leave unknown"),
    ("inf text", _replace_row(1, ROWS[1].replace(",11,", ",-inf,")), 9, "leave unknown"),
    ("overflow", _replace_row(1, ROWS[1].replace(",11,", ",1e999,")), 9, "out of range"),
    ("space", _replace_row(1, ROWS[1].replace(",11,", ", 11,")), 9, "non-numeric"),
    ("backwards", _replace_row(3, ROWS[3].replace("0.015000", "0.001000")), 11, "backwards"),
    ("angles move", _replace_row(5, ROWS[5].replace("22.5,2.5", "22.5,2.6")), 13, "angles change"),
    ("angles part", _replace_row(5, ROWS[5].replace("22.5,2.5", "22.5,")), 13, "partly empty"),
    ("accel part", _replace_row(2, ROWS[2].replace(",12,", ",,")), 10, "accel cells partly"),
    ("no halves", _replace_row(0, "1700000000.000000,0,,,,,,,,,,,"), 8, "neither accel nor"),
    ("empty line", _replace_row(2, ""), 10, "empty line"),
    ("empty t", _replace_row(2, ROWS[2][17:]), 10, "t is empty"),
    ("position -1", _replace_row(2, ROWS[2].replace(",2,0,", ",2,-1,")), 10, "position is not"),
    ("position 0.5", _replace_row(2, ROWS[2].replace(",2,0,", ",2,0.5,")), 10, "position is not"),
    ("counter 1.5", _replace_row(2, ROWS[2].replace(",2,0,", ",1.5,0,")), 10, "counter is not"),
    ("latin-1", SAMPLE.replace("# g: 9.80665", "# accel_units: m/s\xb2"), None, "UTF-8"),
]


@pytest.mark.parametrize(
    ("text", "line", "words"), [m[1:] for m in MALFORMED], ids=[m[0] for m in MALFORMED]
)
def test_malformed_recording_is_a_located_input_error(
    tmp_path: Path, text: str, line: int | None, words: str
) -> None:
    encoding = "latin-1" if "\xb2" in text else "utf-8"
    path = tmp_path / "bad.csv"
    path.write_bytes(text.encode(encoding))
    with pytest.raises(InputError) as info:
        read_recording_csv(path)
    message = str(info.value)
    assert "\n" not in message
    assert message.startswith(str(path))
    assert words in message
    if line is not None:
        assert f":{line}: " in message


@pytest.mark.parametrize("chunk", [64, 97, 1000])
def test_reading_in_small_blocks_gives_the_same_recording(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, chunk: int
) -> None:
    """Blocks cut rows anywhere (64 bytes: a block often holds no complete row)."""
    rec = _random_recording(np.random.default_rng(23), 400)
    path = write_recording(tmp_path / "r.csv", rec, overwrite=False)
    crlf = _write(tmp_path, path.read_text().replace("\n", "\r\n"), "crlf.csv")
    whole = read_recording_csv(path)
    monkeypatch.setattr(recording_module, "CHUNK_BYTES", chunk)
    _same(read_recording_csv(path), whole)
    _same(read_recording_csv(crlf), whole)
    assert read_recording_csv(path).duplicate_rows == whole.duplicate_rows


BLOCKED = [
    # (id, row index, new row, words): each error lies in a later block than the rows it
    # contradicts, so the checks across blocks are what finds it
    ("backwards", 5, ROWS[5].replace("0.025000", "0.001000"), "t goes backwards"),
    ("angles move", 5, ROWS[5].replace("22.5,2.5", "22.5,2.6"), "angles change within position 1"),
    ("text cell", 5, ROWS[5].replace(",-781,", ",x,"), "non-numeric cell"),
    ("short row", 4, ROWS[4][:-5], "13 cells"),
    ("empty line", 4, "", "empty line"),
]


@pytest.mark.parametrize(
    ("index", "row", "words"), [b[1:] for b in BLOCKED], ids=[b[0] for b in BLOCKED]
)
def test_errors_in_later_blocks_keep_their_line_numbers(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, index: int, row: str, words: str
) -> None:
    monkeypatch.setattr(recording_module, "CHUNK_BYTES", 60)  # about one row a block
    path = _write(tmp_path, _replace_row(index, row))
    with pytest.raises(InputError) as info:
        read_recording_csv(path)
    assert str(info.value).startswith(f"{path}:{FIRST_ROW_LINE + index}: ")
    assert words in str(info.value)


def test_missing_file_is_an_input_error(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="cannot read"):
        read_recording_csv(tmp_path / "nope.csv")


# ------------------------------------------------------------------------------ writing


def test_round_trip_write_then_read_is_exact(tmp_path: Path) -> None:
    rec = _random_recording(np.random.default_rng(1), 2000)
    path = write_recording(tmp_path / "out.csv", rec, overwrite=False)
    back = read_recording_csv(path)
    _same(rec, back)
    assert not back.sample_rate_inferred


def test_read_then_write_reproduces_the_file(tmp_path: Path) -> None:
    rec = read_recording_csv(_write(tmp_path, SAMPLE))
    out = write_recording(tmp_path / "again.csv", rec, overwrite=False)
    _same(rec, read_recording_csv(out))
    again = out.read_text().splitlines()
    assert again[-6:][3] == "1700000000.015000,4,1,22.5,2.5,0,-780,-1890,80,1,2,3,25.5"


def test_t_has_at_least_six_decimals_and_stays_exact(tmp_path: Path) -> None:
    t = np.array([0.0, 0.1, 1 / 3, 1.7e9 + 0.123456, 1.7e9 + 1 / 7])
    rec = recording_from_columns({"sample_rate_hz": 200.0}, t=t, accel=np.ones((5, 3)))
    path = write_recording(tmp_path / "t.csv", rec, overwrite=False)
    cells = [line.split(",")[0] for line in path.read_text().splitlines()[3:]]
    assert all(len(cell.split(".")[1]) >= 6 for cell in cells), cells
    np.testing.assert_array_equal(read_recording_csv(path).t, t)


def test_write_refuses_to_overwrite(tmp_path: Path) -> None:
    rec = read_recording_csv(_write(tmp_path, SAMPLE))
    with pytest.raises(InputError, match="exists; use overwrite=True"):
        write_recording(tmp_path / "rec.csv", rec, overwrite=False)
    write_recording(tmp_path / "rec.csv", rec, overwrite=True)


def test_header_is_validated_and_typed_in_memory_too() -> None:
    with pytest.raises(InputError, match="unknown header key 'colour'"):
        recording_from_columns({"colour": "red"}, t=[0.0], accel=np.ones((1, 3)))
    with pytest.raises(InputError, match="bad value 'nan' for header key 'g'"):
        recording_from_columns({"g": float("nan")}, t=[0.0], accel=np.ones((1, 3)))
    rec = recording_from_columns({"sample_rate_hz": 200, "node_id": 16}, t=[0.0], accel=[[1, 2, 3]])
    assert rec.header == {"schema": "canimucal.recording/1", "sample_rate_hz": 200.0, "node_id": 16}
    assert rec.sample_rate_hz == 200.0


# ----------------------------------------------------------------------- streaming writer


def _blocks(rec: Recording, size: int) -> list[dict[str, np.ndarray]]:
    out = []
    for start in range(0, rec.n_rows, size):
        s = slice(start, start + size)
        out.append(
            dict(
                t=rec.t[s],
                accel=rec.accel[s],
                gyro=rec.gyro[s],
                counter=rec.counter[s],
                position=rec.position[s],
                alpha_deg=rec.alpha_deg[s],
                beta_deg=rec.beta_deg[s],
                psi_deg=rec.psi_deg[s],
                temp_c=rec.temp_c[s],
            )
        )
    return out


def test_streaming_writer_equals_whole_file_writer(tmp_path: Path) -> None:
    rec = _random_recording(np.random.default_rng(2), 1000)
    target = tmp_path / "stream.csv"
    with RecordingWriter.open(target, rec.header) as writer:
        for block in _blocks(rec, 64):
            writer.write_rows(**block)
        assert writer.partial_path.exists() and not target.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["stream.csv"]
    whole = write_recording(tmp_path / "whole.csv", rec, overwrite=False)
    assert target.read_bytes() == whole.read_bytes()


def test_interrupted_recording_keeps_what_was_written(tmp_path: Path) -> None:
    rec = _random_recording(np.random.default_rng(3), 300)
    target = tmp_path / "int.csv"
    blocks = _blocks(rec, 100)
    with pytest.raises(KeyboardInterrupt):
        with RecordingWriter.open(target, rec.header) as writer:
            writer.write_rows(**blocks[0])
            writer.write_rows(**blocks[1])
            raise KeyboardInterrupt
    back = read_recording_csv(target)
    assert back.n_rows == 200
    np.testing.assert_array_equal(back.t, rec.t[:200])


def test_killed_recorder_leaves_the_partial_file_readable(tmp_path: Path) -> None:
    rec = _random_recording(np.random.default_rng(4), 200)
    target = tmp_path / "k.csv"
    writer = RecordingWriter.open(target, rec.header)
    writer.write_rows(**_blocks(rec, 150)[0])
    # no close(): as if the process died; blocks are flushed as they are written
    assert not target.exists()
    assert read_recording_csv(writer.partial_path).n_rows == 150
    with pytest.raises(InputError, match="interrupted recording"):
        RecordingWriter.open(target, rec.header)
    writer.close()


def test_writer_refuses_existing_target(tmp_path: Path) -> None:
    target = _write(tmp_path, SAMPLE)
    with pytest.raises(InputError, match="exists; use overwrite=True"):
        RecordingWriter.open(target, {"sample_rate_hz": 200.0})
    assert not (tmp_path / "rec.csv.partial").exists()


def test_writer_validates_blocks(tmp_path: Path) -> None:
    with RecordingWriter.open(tmp_path / "v.csv", {"sample_rate_hz": 200.0}) as writer:
        writer.write_rows(
            t=[1.0, 2.0],
            accel=np.ones((2, 3)),
            position=[0, 0],
            alpha_deg=[1, 1],
            beta_deg=[0, 0],
            psi_deg=[0, 0],
        )
        with pytest.raises(InputError, match="backwards"):
            writer.write_rows(t=[1.5], accel=np.ones((1, 3)))
        with pytest.raises(InputError, match="angles change within position 0"):
            writer.write_rows(
                t=[3.0],
                accel=np.ones((1, 3)),
                position=[0],
                alpha_deg=[2],
                beta_deg=[0],
                psi_deg=[0],
            )
        with pytest.raises(InputError, match="shape"):
            writer.write_rows(t=[3.0], accel=np.ones((2, 3)))
        assert writer.rows_written == 2
    assert read_recording_csv(tmp_path / "v.csv").n_rows == 2


def test_append_adds_a_position(tmp_path: Path) -> None:
    target = _write(tmp_path, SAMPLE)
    header = {"sample_rate_hz": 200, "device_serial": 42}  # int rate: same as 200.0
    with RecordingWriter.open(target, header, append=True) as writer:
        writer.write_rows(
            t=[1700000001.0, 1700000001.005],
            accel=[[1, 2, 3], [1, 2, 4]],
            position=[2, 2],
            alpha_deg=[45, 45],
            beta_deg=[5, 5],
            psi_deg=[0, 0],
        )
    rec = read_recording_csv(target)
    assert rec.n_rows == 8
    np.testing.assert_array_equal(rec.position[-2:], [2, 2])
    assert rec.header["node_id"] == 16  # the file's header is kept


@pytest.mark.parametrize(
    ("header", "words"),
    [
        ({"sample_rate_hz": 100.0, "device_serial": 42}, "cannot append: header 'sample_rate_hz'"),
        ({"sample_rate_hz": 200.0, "device_serial": 43}, "cannot append: header 'device_serial'"),
        ({"sample_rate_hz": 200.0}, "cannot append: header 'device_serial'"),
        ({"sample_rate_hz": 200, "device_serial": 42, "schema": "x"}, "unknown schema 'x'"),
    ],
)
def test_append_refuses_another_origin(tmp_path: Path, header: dict, words: str) -> None:
    target = _write(tmp_path, SAMPLE)
    with pytest.raises(InputError, match=words):
        RecordingWriter.open(target, header, append=True)
    assert target.read_text() == SAMPLE
    assert not (tmp_path / "rec.csv.partial").exists()


def test_append_refuses_changed_angles_and_going_back_in_time(tmp_path: Path) -> None:
    target = _write(tmp_path, SAMPLE)
    header = {"sample_rate_hz": 200.0, "device_serial": 42}
    with RecordingWriter.open(target, header, append=True) as writer:
        with pytest.raises(InputError, match="angles change within position 1"):
            writer.write_rows(
                t=[1700000001.0],
                accel=[[1, 2, 3]],
                position=[1],
                alpha_deg=[45],
                beta_deg=[5],
                psi_deg=[0],
            )
        with pytest.raises(InputError, match="backwards"):
            writer.write_rows(t=[1600000000.0], accel=[[1, 2, 3]])
    assert target.read_text() == SAMPLE


def test_append_to_a_file_without_final_newline(tmp_path: Path) -> None:
    target = _write(tmp_path, SAMPLE.rstrip("\n"))
    header = {"sample_rate_hz": 200.0, "device_serial": 42}
    with RecordingWriter.open(target, header, append=True) as writer:
        writer.write_rows(t=[1700000001.0], accel=[[1, 2, 3]])
    assert read_recording_csv(target).n_rows == 7


def test_append_to_missing_file(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="does not exist"):
        RecordingWriter.open(tmp_path / "none.csv", {"sample_rate_hz": 200.0}, append=True)


# ---------------------------------------------------------------------------- performance


@pytest.mark.slow
def test_reading_one_hour_at_200_hz(tmp_path: Path) -> None:
    """720 000 rows (50 MB) read whole; its speed is measured by benchmarks/read_speed.py."""
    path = write_bulk_recording(tmp_path / "hour.csv", 720_000)
    back = read_recording_csv(path)
    assert back.n_rows == 720_000
    assert np.isnan(back.temp_c).all() and back.position[-1] == 59
    np.testing.assert_array_equal(back.counter[:3], [0, 1, 2])


# ------------------------------------------------------------------- the optional trial column

TRIAL_COLUMN_LINE = COLUMN_LINE + ",trial"


def test_a_trial_column_is_read_and_written_back(tmp_path: Path) -> None:
    trials = ["0", "0", "", "1", "1", "1"]
    rows = [f"{row},{trial}" for row, trial in zip(ROWS, trials, strict=True)]
    path = _write(tmp_path, HEADER + TRIAL_COLUMN_LINE + "\n" + "\n".join(rows) + "\n")
    rec = read_recording_csv(path)
    assert rec.trial is not None
    np.testing.assert_array_equal(rec.trial, [0, 0, -1, 1, 1, 1])
    plain = read_recording_csv(_write(tmp_path, SAMPLE, "plain.csv"))
    assert plain.trial is None
    _same(rec, plain)  # the other columns read as without the trial column
    again = read_recording_csv(write_recording(tmp_path / "again.csv", rec, overwrite=False))
    assert again.trial is not None
    np.testing.assert_array_equal(again.trial, rec.trial)
    assert (tmp_path / "again.csv").read_text().splitlines()[6] == TRIAL_COLUMN_LINE
    _same(again, rec)
    assert (
        write_recording(tmp_path / "p.csv", plain, overwrite=False)
        .read_text()
        .count(TRIAL_COLUMN_LINE)
        == 0
    )


@pytest.mark.parametrize(
    ("cell", "problem"),
    [("-1", "trial is not a non-negative integer"), ("1.5", "trial is not a non-negative integer")],
)
def test_a_bad_trial_cell_is_refused_with_its_line(tmp_path: Path, cell: str, problem: str) -> None:
    rows = [f"{row},0" for row in ROWS]
    rows[3] = f"{ROWS[3]},{cell}"
    path = _write(tmp_path, HEADER + TRIAL_COLUMN_LINE + "\n" + "\n".join(rows) + "\n")
    with pytest.raises(InputError, match=f"rec.csv:{FIRST_ROW_LINE + 3}: {problem}"):
        read_recording_csv(path)


def test_a_row_without_its_trial_cell_is_refused_with_its_line(tmp_path: Path) -> None:
    rows = [f"{row},0" for row in ROWS]
    rows[2] = ROWS[2]
    path = _write(tmp_path, HEADER + TRIAL_COLUMN_LINE + "\n" + "\n".join(rows) + "\n")
    with pytest.raises(
        InputError, match=f"rec.csv:{FIRST_ROW_LINE + 2}: expected 14 cells, got 13"
    ):
        read_recording_csv(path)


def test_trials_from_columns_and_row_subsets_keep_them() -> None:
    t = 1.7e9 + np.arange(6) * 0.005
    rec = recording_from_columns(
        {"sample_rate_hz": 200},
        t=t,
        accel=np.ones((6, 3)),
        trial=[0, 0, 1, 1, -1, 2],
    )
    assert rec.trial is not None
    np.testing.assert_array_equal(rec.trial, [0, 0, 1, 1, -1, 2])
    part = rec.take_rows(np.array([1, 2, 5]))
    assert part.trial is not None
    np.testing.assert_array_equal(part.trial, [0, 1, 2])
    np.testing.assert_array_equal(part.t, t[[1, 2, 5]])
    with pytest.raises(InputError, match="not an integer"):
        recording_from_columns({"sample_rate_hz": 200}, t=t, accel=np.ones((6, 3)), trial=[0.5] * 6)
