"""Mounting maps saved per unit: ``mounting/<serial>.toml`` in the user's config directory.

The file holds the vehicle direction of each unit axis and, when known, the vehicle's
wheelbase and track in metres (docs/design.md §5), either part alone or both::

    x = "forward"
    y = "down"
    z = "left"
    wheelbase_m = 3.5
    track_m = 1.8

The directory is :func:`canimucal.user_dirs.config_dir` (on Linux ``$XDG_CONFIG_HOME/canimucal``,
else ``~/.config/canimucal``) unless a caller names another. Files are written
atomically and never replaced unless asked. :func:`choose_mounting` decides which map words a
session's instructions: the one asked for, else the one saved for the unit's serial, else
:data:`~canimucal.model.mounting.DEFAULT_MOUNTING`, and says which in one line.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

from canimucal.errors import InputError
from canimucal.io.atomic import write_text_atomic
from canimucal.model.mounting import DEFAULT_MOUNTING, MountingMap
from canimucal.model.vehicle_size import VehicleSize
from canimucal.schema import parse_toml
from canimucal.user_dirs import config_dir

log = logging.getLogger(__name__)

BODY = "body"
"""``--mount body``: instructions in the unit's own axes (bench use), nothing saved."""


def mounting_dir(config: Path | None = None) -> Path:
    """Return ``mounting/`` in ``config`` (default: the user's canimucal config directory)."""
    return (config_dir() if config is None else config) / "mounting"


def mounting_path(serial: int, config: Path | None = None) -> Path:
    """Return the file of the unit with ``serial``."""
    return mounting_dir(config) / f"{int(serial)}.toml"


AXES = ("x", "y", "z")
SIZE_KEYS = ("wheelbase_m", "track_m")


def read_mounting_file(path: Path) -> tuple[MountingMap | None, VehicleSize | None]:
    """Read a saved file: its map and its vehicle size, each None when the file has none.

    :class:`InputError` naming the file when it is not one (an unknown key, a map with an
    axis missing, a size that is not a length).
    """
    try:
        text = path.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: cannot read the mounting map ({exc})") from None
    document = parse_toml(text, f"{path}: cannot read the mounting map")
    unknown = sorted(set(document) - {*AXES, *SIZE_KEYS})
    if unknown:
        raise InputError(
            f"{path}: unknown key {unknown[0]!r} (only x, y, z, {', '.join(SIZE_KEYS)})"
        )
    mounting = None
    if any(axis in document for axis in AXES):
        words = [document.get(axis) for axis in AXES]
        if not all(isinstance(w, str) for w in words):
            raise InputError(f"{path}: x, y and z must each name a vehicle direction")
        try:
            mounting = MountingMap(*(str(w) for w in words))
        except InputError as exc:
            raise InputError(f"{path}: {exc}") from None
    size = None
    if any(key in document for key in SIZE_KEYS):
        values = [document.get(key) for key in SIZE_KEYS]
        if not all(v is None or isinstance(v, int | float) for v in values):
            raise InputError(f"{path}: wheelbase_m and track_m must be lengths in metres")
        try:
            size = VehicleSize(*(None if v is None else float(v) for v in values))
        except InputError as exc:
            raise InputError(f"{path}: {exc}") from None
    return mounting, size


def read_mounting(path: Path) -> MountingMap | None:
    """Read a saved map (None: the file holds a vehicle size only)."""
    return read_mounting_file(path)[0]


def load_mounting(serial: int, config: Path | None = None) -> MountingMap | None:
    """Return the map saved for ``serial``, None when there is none."""
    path = mounting_path(serial, config)
    return read_mounting(path) if path.is_file() else None


def load_vehicle_size(serial: int, config: Path | None = None) -> VehicleSize | None:
    """Return the vehicle size saved for ``serial``, None when there is none."""
    path = mounting_path(serial, config)
    return read_mounting_file(path)[1] if path.is_file() else None


def save_mounting(
    serial: int,
    mounting: MountingMap | None,
    *,
    overwrite: bool = False,
    config: Path | None = None,
    size: VehicleSize | None = None,
) -> Path:
    """Save ``mounting`` and ``size`` for ``serial`` atomically; either may be None, not both.

    An existing file is replaced only with ``overwrite``.
    """
    if mounting is None and (size is None or not size.known):
        raise InputError("nothing to save: give a mounting map or a vehicle size")
    path = mounting_path(serial, config)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"cannot create {path.parent}: {exc.strerror or exc}") from None
    lines = [
        f"# canimucal: how unit serial {int(serial)} is mounted in the vehicle",
        "# (the vehicle direction of each unit axis: forward, back, left, right, up, down;",
        "# the wheelbase and track in metres word its tilts as heights)",
    ]
    if mounting is not None:
        lines += [f'x = "{mounting.x}"', f'y = "{mounting.y}"', f'z = "{mounting.z}"']
    if size is not None:
        lines += [
            f"{key} = {value!r}"
            for key, value in zip(SIZE_KEYS, (size.wheelbase_m, size.track_m), strict=True)
            if value is not None
        ]
    return write_text_atomic(path, "\n".join(lines) + "\n", overwrite=overwrite)


@dataclass(frozen=True)
class MountingChoice:
    """The map that words the instructions (None: body axes) and one line saying why."""

    mounting: MountingMap | None
    note: str


def choose_mounting(
    serial: int,
    requested: MountingMap | str | None = None,
    *,
    replace: bool = False,
    config: Path | None = None,
) -> MountingChoice:
    """Decide the map of the unit with ``serial`` (module doc).

    ``requested``: a map (used; saved when the serial has none, or with ``replace``), the
    string ``"body"`` (body-axis wording), or None (the saved map, else the default).
    """
    if requested == BODY:
        return MountingChoice(None, "instructions in the unit's own axes (--mount body)")
    if isinstance(requested, str):
        requested = MountingMap.parse(requested)
    saved = load_mounting(serial, config)
    path = mounting_path(serial, config)
    if requested is None:
        if saved is not None:
            return MountingChoice(saved, f"mounting {saved.text()} of serial {serial} ({path})")
        return MountingChoice(
            DEFAULT_MOUNTING,
            f"no mounting map saved for serial {serial}: assuming {DEFAULT_MOUNTING.text()} "
            "(unit flat, +x to the front); set it with --mount",
        )
    if saved == requested:
        return MountingChoice(requested, f"mounting {requested.text()} of serial {serial}")
    if saved is None or replace:
        size = load_vehicle_size(serial, config)
        save_mounting(serial, requested, overwrite=path.exists(), config=config, size=size)
        log.info("saved mounting %s for serial %d in %s", requested.text(), serial, path)
        return MountingChoice(requested, f"mounting {requested.text()} saved for serial {serial}")
    return MountingChoice(
        requested,
        f"mounting {requested.text()} for this session; serial {serial} keeps {saved.text()} "
        "(--replace-mount saves the new one)",
    )


@dataclass(frozen=True)
class SizeChoice:
    """The vehicle size that words the tilts (None: angles only) and one line saying why."""

    size: VehicleSize | None
    note: str


def choose_vehicle_size(
    serial: int,
    requested: VehicleSize | None = None,
    *,
    replace: bool = False,
    config: Path | None = None,
) -> SizeChoice:
    """Decide the wheelbase and track of the vehicle of the unit with ``serial``.

    ``requested`` (``--wheelbase``/``--track``): used, each length left out taken from the
    saved size; saved with the unit's map when the serial has no size yet, or with
    ``replace``. None: the saved size, else none (the tilts are worded as angles).
    """
    path = mounting_path(serial, config)
    saved_map, saved = read_mounting_file(path) if path.is_file() else (None, None)
    if requested is None or not requested.known:
        if saved is None:
            return SizeChoice(None, "")
        return SizeChoice(saved, f"vehicle {saved.text()} of serial {serial} ({path})")
    if saved is not None:
        requested = VehicleSize(
            requested.wheelbase_m if requested.wheelbase_m is not None else saved.wheelbase_m,
            requested.track_m if requested.track_m is not None else saved.track_m,
        )
    if saved == requested:
        return SizeChoice(requested, f"vehicle {requested.text()} of serial {serial}")
    if saved is None or replace:
        save_mounting(serial, saved_map, overwrite=path.exists(), config=config, size=requested)
        log.info("saved vehicle %s for serial %d in %s", requested.text(), serial, path)
        return SizeChoice(requested, f"vehicle {requested.text()} saved for serial {serial}")
    return SizeChoice(
        requested,
        f"vehicle {requested.text()} for this session; serial {serial} keeps {saved.text()} "
        "(--replace-mount saves the new one)",
    )
