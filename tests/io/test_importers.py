"""Importers: imu_tk ASCII pairs, imucal CSV + section JSON, format detection."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from canimucal.errors import InputError
from canimucal.io.importers import detect_format, read_imucal, read_imutk
from canimucal.io.recording import recording_from_columns
from canimucal.io.recording_writer import write_recording
from canimucal.runtime.inputs import read_recording

DATA = Path(__file__).resolve().parents[3] / "shared" / "data"


def _imutk(path: Path, t: np.ndarray, xyz: np.ndarray) -> Path:
    np.savetxt(path, np.column_stack([t, xyz]), fmt="%.7e")
    return path


def test_imutk_pair_becomes_a_recording(tmp_path: Path) -> None:
    t = 0.02 + np.arange(500) / 100.0
    acc = np.full((500, 3), 32768.0) + np.arange(3)
    gyr = np.full((500, 3), 32000.0)
    a = _imutk(tmp_path / "acc.mat", t, acc)
    g = _imutk(tmp_path / "gyr.mat", t, gyr)
    assert detect_format(a) == "imutk"
    rec = read_imutk(a, g)
    assert rec.sample_rate_hz == 100.0
    assert rec.header["offset_binary"] is True
    assert rec.header["accel_units"] == "counts"
    assert np.array_equal(rec.accel, acc) and np.array_equal(rec.gyro, gyr)
    assert np.all(rec.position == -1)


def test_imutk_mismatched_files_are_refused(tmp_path: Path) -> None:
    t = np.arange(10) / 100.0
    a = _imutk(tmp_path / "acc.mat", t, np.zeros((10, 3)))
    short = _imutk(tmp_path / "short.mat", t[:9], np.zeros((9, 3)))
    shifted = _imutk(tmp_path / "shift.mat", t + 0.5, np.zeros((10, 3)))
    with pytest.raises(InputError, match="rows"):
        read_imutk(a, short)
    with pytest.raises(InputError, match="times"):
        read_imutk(a, shifted)


def _imucal(tmp_path: Path) -> tuple[Path, Path]:
    n = 300
    csv = tmp_path / "session.csv"
    rows = [",".join(("n_samples", "gyr_x", "gyr_y", "gyr_z", "acc_x", "acc_y", "acc_z"))]
    for k in range(n):
        rows.append(f"{k},0.1,0.2,0.3,{9.8 if k < 150 else -9.8},0.0,0.1")
    csv.write_text("\n".join(rows) + "\n")
    sections = tmp_path / "session_list.json"
    sections.write_text(
        json.dumps(
            {"x_p": {"start": 10, "end": 100}, "x_a": {"start": 160, "end": 250},
             "x_rot": {"start": 100, "end": 160}}
        )
    )  # fmt: skip
    return csv, sections


def test_imucal_sections_label_static_positions(tmp_path: Path) -> None:
    csv, sections = _imucal(tmp_path)
    assert detect_format(csv) == "imucal"
    rec = read_imucal(csv, sections, 102.4)
    assert rec.header["gyro_lsb"] == pytest.approx(np.pi / 180.0)
    assert rec.header["accel_units"] == "m/s^2"
    assert sorted(set(rec.position.tolist())) == [-1, 0, 1]
    assert np.sum(rec.position == 0) == 90
    assert rec.accel[20, 0] == pytest.approx(9.8)
    assert rec.gyro[0, 2] == pytest.approx(0.3)


def test_imucal_rotation_sections_become_known_turns(tmp_path: Path) -> None:
    csv, sections = _imucal(tmp_path)
    rec = read_imucal(csv, sections, 102.4)
    assert len(rec.turns) == 1
    turn = rec.turns[0]
    assert (turn.label, turn.start, turn.stop, turn.axis) == ("x_rot", 100, 160, 0)
    assert turn.angle_deg == -360.0
    assert np.all(rec.position[turn.start : turn.stop] == -1)


def test_imucal_needs_a_sample_rate(tmp_path: Path) -> None:
    csv, sections = _imucal(tmp_path)
    with pytest.raises(InputError, match="give sample_rate_hz"):
        read_imucal(csv, sections, None)


def test_bad_section_json_is_refused(tmp_path: Path) -> None:
    csv, sections = _imucal(tmp_path)
    sections.write_text('{"x_p": {"start": 10}}')
    with pytest.raises(InputError, match="end"):
        read_imucal(csv, sections, 100.0)


def test_recording_is_detected_and_unknown_text_refused(tmp_path: Path) -> None:
    rec = recording_from_columns(
        {"sample_rate_hz": 100.0}, t=np.arange(5) / 100.0, accel=np.zeros((5, 3))
    )
    path = write_recording(tmp_path / "r.csv", rec, overwrite=False)
    assert detect_format(path) == "recording"
    assert read_recording(path).n_rows == 5
    other = tmp_path / "other.txt"
    other.write_text("hello world\n")
    with pytest.raises(InputError, match="unknown format"):
        detect_format(other)


BOM = b"\xef\xbb\xbf"


def _with_bom(path: Path) -> Path:
    """Put a UTF-8 byte-order mark before the file's text, as Windows editors do."""
    bommed = path.with_name("bom-" + path.name)
    bommed.write_bytes(BOM + path.read_bytes())
    return bommed


def test_a_byte_order_mark_is_read_in_every_format(tmp_path: Path) -> None:
    """Detected and read as without it: recording, imu_tk pair, imucal CSV and sections."""
    rec = recording_from_columns(
        {"sample_rate_hz": 100.0}, t=np.arange(5) / 100.0, accel=np.arange(15.0).reshape(5, 3)
    )
    recording = _with_bom(write_recording(tmp_path / "r.csv", rec, overwrite=False))
    assert detect_format(recording) == "recording"
    assert np.array_equal(read_recording(recording).accel, rec.accel)

    t = 0.02 + np.arange(50) / 100.0
    acc = _with_bom(_imutk(tmp_path / "acc.mat", t, np.full((50, 3), 32768.0)))
    gyr = _with_bom(_imutk(tmp_path / "gyr.mat", t, np.full((50, 3), 32000.0)))
    assert detect_format(acc) == "imutk"
    both = read_recording(acc, second=gyr)
    assert both.n_rows == 50 and np.all(both.gyro == 32000.0) and both.t[0] == pytest.approx(0.02)

    csv, sections = _imucal(tmp_path)
    plain = read_imucal(csv, sections, 102.4)
    csv, sections = _with_bom(csv), _with_bom(sections)
    assert detect_format(csv) == "imucal"
    bommed = read_recording(csv, second=sections, sample_rate_hz=102.4)
    assert np.array_equal(bommed.accel, plain.accel)
    assert np.array_equal(bommed.position, plain.position) and bommed.turns == plain.turns


needs_data = pytest.mark.skipif(not DATA.is_dir(), reason=f"shared data absent at {DATA}")


@needs_data
def test_real_imutk_set_loads() -> None:
    rec = read_recording(DATA / "imutk_xsens_acc.mat", second=DATA / "imutk_xsens_gyro.mat")
    assert rec.sample_rate_hz == 100.0
    assert rec.n_rows > 50_000
    assert 30_000 < float(np.median(rec.accel[:, 0])) < 36_000


@needs_data
def test_real_imucal_set_loads() -> None:
    rec = read_recording(
        DATA / "imucal_example_ferraris_session.csv",
        second=DATA / "imucal_example_ferraris_session_list.json",
        sample_rate_hz=102.4,
    )
    assert sorted(set(rec.position.tolist())) == [-1, 0, 1, 2, 3, 4, 5]
    assert [(t.label, t.start, t.stop, t.axis) for t in rec.turns] == [
        ("x_rot", 6770, 7093, 0),
        ("y_rot", 8081, 8405, 1),
        ("z_rot", 9205, 9512, 2),
    ]
    x_p = rec.accel[rec.position == 0].mean(axis=0)
    assert x_p[0] == pytest.approx(9.8, abs=0.6)
