"""Fixtures shared by every test directory: simulated nodes and clients on a virtual bus."""

from pathlib import Path

import pytest

pytest_plugins = ["tests.support.canbus", "tests.support.nodes"]


@pytest.fixture(autouse=True)
def _no_user_config(
    tmp_path_factory: pytest.TempPathFactory, monkeypatch: pytest.MonkeyPatch
) -> Path:
    """Point ``$XDG_CONFIG_HOME`` at an empty directory: no user's acceptance limits apply."""
    config = tmp_path_factory.mktemp("xdg-config")
    monkeypatch.setenv("XDG_CONFIG_HOME", str(config))
    return config
