"""One in-process ``canimucal`` run with its output captured (the suites' ``cli`` fixtures)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import pytest

from canimucal.cli.main import main


@dataclass(frozen=True)
class CliRun:
    """Exit status and captured streams of one in-process ``canimucal`` run."""

    code: int
    out: str
    err: str


def run_captured(capsys: pytest.CaptureFixture[str], argv: Sequence[object]) -> CliRun:
    """Run ``canimucal ARGV`` through :func:`~canimucal.cli.main.main`; its status and output."""
    capsys.readouterr()
    code = main([str(a) for a in argv])
    captured = capsys.readouterr()
    return CliRun(code, captured.out, captured.err)
