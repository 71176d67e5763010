"""The layers look down only (docs/design.md §1): checked in fresh interpreters."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

FOREIGN = ("can", "canopen", "textual")
ABOVE_PROCEDURE = ("canimucal.device", "canimucal.simnode", "canimucal.runtime", "canimucal.tui")


def _every_module_of(package: str) -> str:
    """Code that imports ``package`` and every module in it (an ``__init__`` alone is empty)."""
    return (
        "import importlib, pkgutil\n"
        f"import {package} as package\n"
        "for info in pkgutil.walk_packages(package.__path__, package.__name__ + '.'):\n"
        "    importlib.import_module(info.name)"
    )


def _loaded_after(code: str) -> set[str]:
    """Every module loaded after running ``code`` in a fresh interpreter (full names)."""
    probe = f"import sys, json\n{code}\nprint(json.dumps(sorted(sys.modules)))"
    out = subprocess.run(
        [sys.executable, "-c", probe], capture_output=True, text=True, check=True
    ).stdout
    return set(json.loads(out.strip().splitlines()[-1]))


def _within(loaded: set[str], forbidden: tuple[str, ...]) -> set[str]:
    return {m for m in loaded if any(m == f or m.startswith(f + ".") for f in forbidden)}


@pytest.mark.parametrize(
    ("package", "forbidden"),
    [
        ("canimucal.model", (*FOREIGN, "canimucal.io", "canimucal.sim")),
        ("canimucal.sim", (*FOREIGN, "canimucal.io")),
        ("canimucal.io", (*FOREIGN, "canimucal.analysis", "canimucal.device")),
        ("canimucal.analysis", (*FOREIGN, *ABOVE_PROCEDURE, "canimucal.procedure")),
        ("canimucal.procedure", (*FOREIGN, *ABOVE_PROCEDURE)),
        ("canimucal.device", ("textual", "canimucal.simnode", "canimucal.procedure")),
    ],
)
def test_every_module_of_a_layer_loads_nothing_above_it(
    package: str, forbidden: tuple[str, ...]
) -> None:
    loaded = _loaded_after(_every_module_of(package))
    assert any(m.startswith(package + ".") for m in loaded)  # the modules themselves ran
    assert not _within(loaded, forbidden), _within(loaded, forbidden)


def test_the_probe_sees_a_forbidden_import() -> None:
    """The check above can fail: a layer that loads textual is caught."""
    loaded = _loaded_after(_every_module_of("canimucal.tui"))
    assert _within(loaded, ("textual",))


def test_the_cli_help_loads_no_textual() -> None:
    code = (
        "import contextlib, io\n"
        "from canimucal.cli.main import main\n"
        "with contextlib.redirect_stdout(io.StringIO()):\n"
        "    try:\n        main(['--help'])\n"
        "    except SystemExit:\n        pass"
    )
    assert not _within(_loaded_after(code), ("textual",))


def test_python_dash_m_runs_the_entry_point() -> None:
    result = subprocess.run(
        [sys.executable, "-m", "canimucal", "--version"], capture_output=True, text=True
    )
    assert result.returncode == 0
    assert result.stdout.startswith("canimucal ")
