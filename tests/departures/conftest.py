"""Fixtures of the departures suite: the shells run in-process with user dirs of their own."""

from __future__ import annotations

from collections.abc import Callable, Sequence

import pytest

from tests.support.cli_run import CliRun, run_captured
from tests.support.user_dirs import UserDirs


@pytest.fixture
def cli(
    capsys: pytest.CaptureFixture[str], own_user_dirs: UserDirs
) -> Callable[[Sequence[str]], CliRun]:
    """Run ``canimucal ARGV`` in-process (the user's config not read); status and output."""
    return lambda argv: run_captured(capsys, argv)
