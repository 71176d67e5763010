"""The site and operator last given to the TUI, offered again the next time it asks.

A small JSON file in the user's state directory (the shell passes its path,
``user_dirs.state_dir() / "last-site.json"``; docs/design.md §5). A missing or unreadable
file is no error: the question then starts empty. Nothing here is a default value: the
operator confirms or changes what is offered before the first position.
"""

from __future__ import annotations

import json
import logging
import math
from dataclasses import asdict, dataclass
from pathlib import Path

from canimucal.errors import InputError
from canimucal.io.atomic import make_directory, write_text_atomic

logger = logging.getLogger(__name__)

LAST_SITE_FILE = "last-site.json"


@dataclass(frozen=True)
class LastSite:
    """What the site question asks: operator, site name, latitude and height, or g."""

    operator: str = ""
    site_name: str = ""
    latitude_deg: float | None = None
    height_m: float | None = None
    g: float | None = None


def _number(value: object) -> float | None:
    if isinstance(value, bool) or not isinstance(value, int | float):
        return None
    return float(value) if math.isfinite(value) else None


def read_last_site(path: Path | None) -> LastSite:
    """Return the values saved at ``path`` (empty ones when there is no usable file)."""
    if path is None:
        return LastSite()
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        if path.exists():
            logger.warning("last site values not read from %s: %s", path, exc)
        return LastSite()
    if not isinstance(data, dict):
        return LastSite()
    text = {k: v for k in ("operator", "site_name") if isinstance(v := data.get(k), str)}
    return LastSite(
        operator=text.get("operator", "")[:200],
        site_name=text.get("site_name", "")[:200],
        latitude_deg=_number(data.get("latitude_deg")),
        height_m=_number(data.get("height_m")),
        g=_number(data.get("g")),
    )


def save_last_site(path: Path | None, last: LastSite) -> None:
    """Save ``last`` at ``path`` for the next session (a failure is logged, not raised)."""
    if path is None:
        return
    try:
        make_directory(path.parent)
        write_text_atomic(path, json.dumps(asdict(last), indent=2) + "\n", overwrite=True)
    except InputError as exc:  # remembering is a convenience: the session goes on
        logger.warning("last site values not saved to %s: %s", path, exc)
