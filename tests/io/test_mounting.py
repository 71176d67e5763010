"""Mounting maps saved per serial in the user's config directory, and which map a session uses."""

from __future__ import annotations

from pathlib import Path

import pytest

from canimucal.errors import InputError
from canimucal.io.mounting import (
    choose_mounting,
    choose_vehicle_size,
    load_mounting,
    load_vehicle_size,
    mounting_path,
    save_mounting,
)
from canimucal.model.mounting import DEFAULT_MOUNTING, MountingMap
from canimucal.model.vehicle_size import VehicleSize

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


def test_the_vehicle_size_is_saved_beside_the_map_and_kept_when_the_map_changes(
    tmp_path: Path,
) -> None:
    config = tmp_path / "config"
    size = VehicleSize(wheelbase_m=3.5, track_m=1.8)
    first = choose_vehicle_size(9, size, config=config)  # no file yet: saved, alone
    assert first.size == size and "saved for serial 9" in first.note
    assert load_vehicle_size(9, config) == size and load_mounting(9, config) is None
    choose_mounting(9, "x=left,y=down,z=back", config=config)  # the map joins it
    assert load_mounting(9, config) == TURNED and load_vehicle_size(9, config) == size
    assert choose_vehicle_size(9, config=config).size == size  # loaded by serial next time
    wider = choose_vehicle_size(9, VehicleSize(track_m=2.0), config=config)
    assert wider.size == VehicleSize(3.5, 2.0)  # the wheelbase left out: the saved one
    assert "keeps wheelbase 3.5 m, track 1.8 m" in wider.note
    assert load_vehicle_size(9, config) == size  # not replaced without asking
    choose_vehicle_size(9, VehicleSize(track_m=2.0), replace=True, config=config)
    assert load_vehicle_size(9, config) == VehicleSize(3.5, 2.0)
    assert load_mounting(9, config) == TURNED  # the map stays
    path = mounting_path(9, config)
    path.write_text('x = "forward"\ny = "down"\nz = "left"\nwheelbase_m = 350\n')
    with pytest.raises(InputError, match="wheelbase_m must be a length in metres"):
        load_vehicle_size(9, config)
