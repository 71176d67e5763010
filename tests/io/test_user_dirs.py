"""Config and state paths come from platformdirs, at the same places as before on Linux."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

from canimucal.analysis.acceptance import acceptance_config_path
from canimucal.device.transaction import default_backup_dir
from canimucal.io.mounting import mounting_path

pytestmark = pytest.mark.skipif(sys.platform != "linux", reason="the XDG layout is Linux's")


def test_xdg_variables_are_honoured(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "cfg"))
    monkeypatch.setenv("XDG_STATE_HOME", str(tmp_path / "state"))
    assert acceptance_config_path() == tmp_path / "cfg/canimucal/acceptance.toml"
    assert mounting_path(12) == tmp_path / "cfg/canimucal/mounting/12.toml"
    assert default_backup_dir() == tmp_path / "state/canimucal/backups"


@pytest.mark.parametrize("unset", ["", None])
def test_home_defaults_when_unset_or_empty(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, unset: str | None
) -> None:
    monkeypatch.setenv("HOME", str(tmp_path))
    for name in ("XDG_CONFIG_HOME", "XDG_STATE_HOME"):
        if unset is None:
            monkeypatch.delenv(name, raising=False)
        else:
            monkeypatch.setenv(name, unset)
    assert acceptance_config_path() == tmp_path / ".config/canimucal/acceptance.toml"
    assert mounting_path(12) == tmp_path / ".config/canimucal/mounting/12.toml"
    assert default_backup_dir() == tmp_path / ".local/state/canimucal/backups"
