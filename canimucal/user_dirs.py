"""Where the tool keeps the user's configuration and its own state, through platformdirs.

On Linux: ``$XDG_CONFIG_HOME/canimucal`` (else ``~/.config/canimucal``) holds
``acceptance.toml`` and ``mounting/<serial>.toml``; ``$XDG_STATE_HOME/canimucal`` (else
``~/.local/state/canimucal``) holds ``backups/``. Other systems get their own conventions
(docs/design.md §5). Computing a path reads nothing: the library never reads the user's
configuration on its own, the shells do and pass it in (docs/design.md §1).
"""

from __future__ import annotations

from pathlib import Path

from platformdirs import user_config_path, user_state_path

APP_NAME = "canimucal"


def config_dir() -> Path:
    """Return the user's configuration directory of canimucal (it may not exist)."""
    return user_config_path(APP_NAME, appauthor=False)


def state_dir() -> Path:
    """Return the directory of canimucal's own state: backups (it may not exist)."""
    return user_state_path(APP_NAME, appauthor=False)
