"""A private config and state directory for tests of the shells (CLI, TUI, sessions).

The library never reads the user's configuration (tests/analysis/test_acceptance_limits.py
shows it), so its tests run with whatever the machine has. The shells do read it
(``acceptance.toml``, mounting maps) and write state (backups, saved mounting maps): their
tests get directories of their own, so a developer's files neither change a verdict nor
receive a test's mounting map.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import pytest


@dataclass(frozen=True)
class UserDirs:
    """The test's own ``$XDG_CONFIG_HOME`` and ``$XDG_STATE_HOME`` and canimucal's dirs there."""

    config_home: Path
    state_home: Path

    @property
    def config(self) -> Path:
        """canimucal's config directory (acceptance.toml, mounting/)."""
        return self.config_home / "canimucal"

    def write_acceptance(self, text: str) -> Path:
        """Write ``acceptance.toml`` with ``text``; return its path."""
        path = self.config / "acceptance.toml"
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text, encoding="utf-8")
        return path


@pytest.fixture
def own_user_dirs(
    tmp_path_factory: pytest.TempPathFactory, monkeypatch: pytest.MonkeyPatch
) -> UserDirs:
    """Point ``$XDG_CONFIG_HOME`` and ``$XDG_STATE_HOME`` at fresh empty directories."""
    dirs = UserDirs(tmp_path_factory.mktemp("xdg-config"), tmp_path_factory.mktemp("xdg-state"))
    monkeypatch.setenv("XDG_CONFIG_HOME", str(dirs.config_home))
    monkeypatch.setenv("XDG_STATE_HOME", str(dirs.state_home))
    return dirs
