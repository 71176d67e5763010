"""The layers look down only (docs/design.md §1): checked in fresh interpreters."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

FOREIGN = ("can", "canopen", "textual")


def _loaded_after(code: str) -> set[str]:
    probe = (
        "import sys, json\n"
        f"{code}\n"
        "print(json.dumps(sorted({m.split('.')[0] for m in sys.modules})))"
    )
    out = subprocess.run(
        [sys.executable, "-c", probe], capture_output=True, text=True, check=True
    ).stdout
    return set(json.loads(out.strip().splitlines()[-1]))


@pytest.mark.parametrize(
    ("code", "forbidden"),
    [
        ("import canimucal.model.frames, canimucal.model.positions", FOREIGN),
        ("import canimucal.sim.averages", FOREIGN),
        ("import canimucal.procedure", ("textual",)),
        (
            "import contextlib, io\n"
            "from canimucal.cli.main import main\n"
            "with contextlib.redirect_stdout(io.StringIO()):\n"
            "    try:\n        main(['--help'])\n"
            "    except SystemExit:\n        pass",
            ("textual",),
        ),
    ],
)
def test_layer_loads_nothing_above_it(code: str, forbidden: tuple[str, ...]) -> None:
    loaded = _loaded_after(code)
    assert not loaded.intersection(forbidden), loaded.intersection(forbidden)


def test_python_dash_m_runs_the_entry_point() -> None:
    result = subprocess.run(
        [sys.executable, "-m", "canimucal", "--version"], capture_output=True, text=True
    )
    assert result.returncode == 0
    assert result.stdout.startswith("canimucal ")
