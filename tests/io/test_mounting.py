"""Mounting maps saved per serial in the user's config directory, and which map a session uses."""

from __future__ import annotations

from pathlib import Path

import pytest

from canimucal.errors import InputError
from canimucal.io.mounting import (
    choose_mounting,
    load_mounting,
    mounting_path,
    save_mounting,
)
from canimucal.model.mounting import DEFAULT_MOUNTING, MountingMap

TURNED = MountingMap.parse("x=left,y=down,z=back")


def test_path_follows_xdg_config_home_else_home(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "cfg"))
    assert mounting_path(1234) == tmp_path / "cfg" / "canimucal" / "mounting" / "1234.toml"
    monkeypatch.setenv("XDG_CONFIG_HOME", "")
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    assert mounting_path(7) == tmp_path / "home" / ".config/canimucal/mounting/7.toml"
    assert mounting_path(7, tmp_path / "mine") == tmp_path / "mine" / "mounting" / "7.toml"


def test_saved_map_loads_back_and_is_never_replaced_unasked(tmp_path: Path) -> None:
    config = tmp_path
    assert load_mounting(42, config) is None
    path = save_mounting(42, TURNED, config=config)
    assert load_mounting(42, config) == TURNED
    with pytest.raises(InputError, match="exists"):
        save_mounting(42, DEFAULT_MOUNTING, config=config)
    assert load_mounting(42, config) == TURNED
    save_mounting(42, DEFAULT_MOUNTING, overwrite=True, config=config)
    assert load_mounting(42, config) == DEFAULT_MOUNTING
    assert sorted(p.name for p in path.parent.iterdir()) == ["42.toml"]  # no temporary left


@pytest.mark.parametrize(
    ("text", "fragment"),
    [
        ('x = "forward"\ny = "left"\nz = "down"\n', "mirror image"),
        ('x = "forward"\ny = "down"\n', "must each name"),
        ('x = "forward"\ny = "down"\nz = "left"\nw = "up"\n', "unknown key 'w'"),
        ("x = forward", "cannot read"),
    ],
)
def test_a_bad_saved_file_is_an_input_error_naming_it(
    tmp_path: Path, text: str, fragment: str
) -> None:
    config = tmp_path
    path = mounting_path(5, config)
    path.parent.mkdir(parents=True)
    path.write_text(text, encoding="utf-8")
    with pytest.raises(InputError, match=fragment) as info:
        load_mounting(5, config)
    assert str(path) in str(info.value)


def test_choice_default_saved_requested_and_body(tmp_path: Path) -> None:
    config = tmp_path
    first = choose_mounting(9, config=config)
    assert first.mounting == DEFAULT_MOUNTING and "no mounting map saved" in first.note
    assert load_mounting(9, config) is None  # the default is said, not saved

    chosen = choose_mounting(9, "x=left,y=down,z=back", config=config)
    assert chosen.mounting == TURNED and "saved" in chosen.note
    assert choose_mounting(9, config=config).mounting == TURNED  # loaded by serial next time
    assert choose_mounting(10, config=config).mounting == DEFAULT_MOUNTING  # another unit

    other = choose_mounting(9, DEFAULT_MOUNTING, config=config)
    assert other.mounting == DEFAULT_MOUNTING and "keeps" in other.note
    assert load_mounting(9, config) == TURNED
    choose_mounting(9, DEFAULT_MOUNTING, replace=True, config=config)
    assert load_mounting(9, config) == DEFAULT_MOUNTING

    body = choose_mounting(9, "body", config=config)
    assert body.mounting is None and "own axes" in body.note
