"""Mounting maps saved per unit: ``mounting/<serial>.toml`` in the user's config directory.

The file holds the vehicle direction of each unit axis (docs/design.md §5)::

    x = "forward"
    y = "down"
    z = "left"

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


def read_mounting(path: Path) -> MountingMap:
    """Read a saved map (:class:`InputError` naming the file when it is not one)."""
    try:
        text = path.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: cannot read the mounting map ({exc})") from None
    document = parse_toml(text, f"{path}: cannot read the mounting map")
    unknown = sorted(set(document) - {"x", "y", "z"})
    if unknown:
        raise InputError(f"{path}: unknown key {unknown[0]!r} (only x, y, z)")
    words = [document.get(axis) for axis in "xyz"]
    if not all(isinstance(w, str) for w in words):
        raise InputError(f"{path}: x, y and z must each name a vehicle direction")
    try:
        return MountingMap(*(str(w) for w in words))
    except InputError as exc:
        raise InputError(f"{path}: {exc}") from None


def load_mounting(serial: int, config: Path | None = None) -> MountingMap | None:
    """Return the map saved for ``serial``, None when there is none."""
    path = mounting_path(serial, config)
    return read_mounting(path) if path.is_file() else None


def save_mounting(
    serial: int,
    mounting: MountingMap,
    *,
    overwrite: bool = False,
    config: Path | None = None,
) -> Path:
    """Save ``mounting`` for ``serial`` atomically; an existing file only with ``overwrite``."""
    path = mounting_path(serial, config)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"cannot create {path.parent}: {exc.strerror or exc}") from None
    text = (
        f"# canimucal: how unit serial {int(serial)} is mounted in the vehicle\n"
        "# (the vehicle direction of each unit axis: forward, back, left, right, up, down)\n"
        f'x = "{mounting.x}"\ny = "{mounting.y}"\nz = "{mounting.z}"\n'
    )
    return write_text_atomic(path, text, overwrite=overwrite)


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
        save_mounting(serial, requested, overwrite=replace, config=config)
        log.info("saved mounting %s for serial %d in %s", requested.text(), serial, path)
        return MountingChoice(requested, f"mounting {requested.text()} saved for serial {serial}")
    return MountingChoice(
        requested,
        f"mounting {requested.text()} for this session; serial {serial} keeps {saved.text()} "
        "(--replace-mount saves the new one)",
    )
