"""Fixtures of the departures suite: the shells run in-process with user dirs of their own."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import pytest

from canimucal.cli.main import main
from tests.support.user_dirs import UserDirs


@dataclass(frozen=True)
class CliRun:
    """Exit status and captured output of one in-process ``canimucal`` run."""

    code: int
    out: str
    err: str


@pytest.fixture
def cli(
    capsys: pytest.CaptureFixture[str], own_user_dirs: UserDirs
) -> Callable[[Sequence[str]], CliRun]:
    """Run ``canimucal ARGV`` in-process (the user's config not read); status and output."""

    def run(argv: Sequence[str]) -> CliRun:
        capsys.readouterr()
        code = main([str(a) for a in argv])
        captured = capsys.readouterr()
        return CliRun(code, captured.out, captured.err)

    return run
