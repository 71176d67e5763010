"""Truth JSON files: syntax errors located, semantics delegated to sim.truth."""

from __future__ import annotations

from pathlib import Path

import pytest

from canimucal.errors import InputError
from canimucal.io.truth import load_truth, read_truth, write_truth


def _write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "truth.json"
    path.write_text(text)
    return path


def test_read_truth_returns_the_object(tmp_path: Path) -> None:
    doc = read_truth(_write(tmp_path, '{"schema": "canimucal.truth/1", "g": 9.8}'))
    assert doc == {"schema": "canimucal.truth/1", "g": 9.8}


@pytest.mark.parametrize(
    ("text", "words"),
    [
        ('{"g": 9.8,\n  "serial": }', "truth.json:2:13: invalid JSON"),
        ('{"g": NaN}', "NaN is not allowed"),
        ('{"g": 1, "g": 2}', "duplicate key 'g'"),
        ("[1]", "top level is not a JSON object"),
        ("", "truth.json:1:1: invalid JSON"),
    ],
)
def test_bad_truth_files(tmp_path: Path, text: str, words: str) -> None:
    with pytest.raises(InputError) as info:
        read_truth(_write(tmp_path, text))
    assert words in str(info.value) and "\n" not in str(info.value)


def test_missing_truth_file(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="cannot read"):
        read_truth(tmp_path / "none.json")


def test_load_truth_validates_with_sim_truth(tmp_path: Path) -> None:
    truth_module = pytest.importorskip("canimucal.sim.truth")
    truth = load_truth(_write(tmp_path, '{"schema": "canimucal.truth/1", "g": 9.8}'))
    assert isinstance(truth, truth_module.Truth)
    with pytest.raises(InputError) as info:
        load_truth(_write(tmp_path, '{"schema": "canimucal.truth/1", "colour": "red"}'))
    assert str(info.value).startswith(str(tmp_path / "truth.json"))
    assert "colour" in str(info.value)


def test_truth_round_trip(tmp_path: Path) -> None:
    truth_module = pytest.importorskip("canimucal.sim.truth")
    truth = truth_module.Truth.from_dict({"g": 9.79, "latitude_deg": 12.5, "serial": 77})
    path = write_truth(tmp_path / "t.json", truth, overwrite=False)
    assert load_truth(path).to_dict() == truth.to_dict()
    assert read_truth(path) == truth.to_dict()
    with pytest.raises(InputError, match="exists; use overwrite=True"):
        write_truth(path, truth, overwrite=False)
    with pytest.raises(InputError, match="non-finite"):
        write_truth(tmp_path / "nan.json", {"g": float("nan")}, overwrite=False)
