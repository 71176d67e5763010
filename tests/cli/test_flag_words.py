"""Library errors speak the Python API; the command line words their options as flags.

The library (everything outside ``cli/`` and ``tui/``) never tells a user to pass
``--overwrite`` or ``--format``: a program calling it has no flags. Its errors name the API
argument (``overwrite=True``) and list it in ``options``; the CLI prints the flag instead.
"""

from __future__ import annotations

import ast
import re
from collections.abc import Callable, Sequence
from pathlib import Path

import pytest

import canimucal
from canimucal.errors import InputError, NoDeviceError
from canimucal.flag_words import FLAGS, worded_for_flags
from canimucal.io import atomic
from canimucal.io.atomic import write_text_atomic
from canimucal.io.importers import read_imucal
from tests.support.cli_run import CliRun

PACKAGE = Path(canimucal.__file__).parent
SHELLS = ("cli", "tui")
FLAG = re.compile(r"(?<![\w-])--[a-z]")


def _library_raises() -> list[tuple[Path, ast.Raise]]:
    found = []
    for path in sorted(PACKAGE.rglob("*.py")):
        if path.relative_to(PACKAGE).parts[0] in SHELLS:
            continue
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Raise) and node.exc is not None:
                found.append((path, node))
    return found


def test_no_library_error_names_a_command_line_flag() -> None:
    offenders = [
        f"{path.relative_to(PACKAGE)}:{node.lineno}: {sub.value[:60]!r}"
        for path, node in _library_raises()
        for sub in ast.walk(node.exc)  # type: ignore[arg-type]
        if isinstance(sub, ast.Constant) and isinstance(sub.value, str) and FLAG.search(sub.value)
    ]
    assert offenders == []


def test_every_option_a_library_error_names_has_a_flag() -> None:
    named = set(atomic.OVERWRITE)
    for _path, node in _library_raises():
        for call in ast.walk(node.exc):  # type: ignore[arg-type]
            if isinstance(call, ast.Call):
                for keyword in call.keywords:
                    if keyword.arg == "options" and isinstance(keyword.value, ast.Tuple):
                        named |= {
                            e.value for e in keyword.value.elts if isinstance(e, ast.Constant)
                        }
    assert len(named) > 10  # the scan sees the library's options
    assert sorted(named - set(FLAGS)) == []


def test_an_existing_file_is_refused_in_api_terms(tmp_path: Path) -> None:
    target = tmp_path / "out.json"
    target.write_text("{}")
    with pytest.raises(InputError) as info:
        write_text_atomic(target, "{}", overwrite=False)
    assert str(info.value) == f"{target} exists; use overwrite=True to replace it"
    assert worded_for_flags(info.value) == f"{target} exists; use --overwrite to replace it"


def test_a_missing_sample_rate_names_the_argument(tmp_path: Path) -> None:
    csv = tmp_path / "session.csv"
    csv.write_text("acc_x,acc_y,acc_z,gyr_x,gyr_y,gyr_z\n0,0,1,0,0,0\n")
    with pytest.raises(InputError, match="give sample_rate_hz$"):
        read_imucal(csv, None, None)


def test_a_spelling_inside_a_longer_name_is_left_alone() -> None:
    error = NoDeviceError("prior_k_sigma and prior_k", options=("prior_k", "prior_k_sigma"))
    assert worded_for_flags(error) == "--prior-k-sigma and --prior-k"
    assert worded_for_flags(ValueError("prior_k")) == "prior_k"  # not ours: as it is


def test_the_cli_prints_the_flag(
    cli: Callable[[Sequence[str]], CliRun], simulated: Callable[..., object], tmp_path: Path
) -> None:
    sim = simulated("five")
    out = tmp_path / "cal.json"
    out.write_text("{}")
    run = cli(["solve", str(sim.path), "--json", str(out)])  # type: ignore[attr-defined]
    assert run.code == 2
    assert run.err == f"error: {out} exists; use --overwrite to replace it\n"
    run = cli(["solve", str(sim.path), "--tolerance-deg", "-1"])  # type: ignore[attr-defined]
    assert run.code == 2
    assert run.err == "error: --tolerance-deg must be a finite number >= 0, got -1\n"
