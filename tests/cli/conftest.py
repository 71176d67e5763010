"""Shared fixtures of the CLI tests: simulated recordings on disk and an in-process runner.

Recordings come from :func:`canimucal.analysis.simulated.simulate_plan_recording` (the
simulator with the operator's 0.1° angle-setting errors) and are written once per session.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from canimucal.analysis.simulated import simulate_plan_recording
from canimucal.io.recording_writer import write_recording
from canimucal.model.vocabulary.plans import builtin_plan
from canimucal.sim.truth import Truth
from tests.support.cli_run import CliRun, run_captured
from tests.support.user_dirs import UserDirs

TRUTH_SEED = 20261121
NOISE_SEED = 7


@dataclass(frozen=True)
class Simulated:
    """A recording written to ``path`` and the truth it was simulated from."""

    path: Path
    truth: Truth


def make_truth(kind: str) -> Truth:
    """``level``: no cross-axis terms, no base tilt; ``diag``: no cross-axis terms, base tilt
    within ±1°; ``full``: cross-axis terms up to 1 % and base tilt within ±1°.
    """
    rng = np.random.default_rng(TRUTH_SEED)
    if kind == "level":
        return Truth.random(rng, cross_axis_max=0.0, tilt_max_deg=0.0)
    if kind == "diag":
        return Truth.random(rng, cross_axis_max=0.0)
    if kind == "full":
        return Truth.random(rng, cross_axis_max=0.01)
    raise ValueError(kind)


@pytest.fixture(scope="session")
def simulated(tmp_path_factory: pytest.TempPathFactory) -> Callable[[str, str, float], Simulated]:
    """Factory ``(plan, truth kind, seconds per position) -> Simulated``, cached per session."""
    cache: dict[tuple[str, str, float], Simulated] = {}
    root = tmp_path_factory.mktemp("recordings")

    def make(plan_name: str, kind: str = "diag", seconds: float = 10.0) -> Simulated:
        key = (plan_name, kind, seconds)
        if key not in cache:
            truth = make_truth(kind)
            plan = builtin_plan(plan_name)
            plan = plan.with_total_seconds(seconds * len(plan.positions))
            rec = simulate_plan_recording(truth, plan, seed=NOISE_SEED)
            path = root / f"{plan_name}_{kind}_{seconds:g}.csv"
            write_recording(path, rec, overwrite=False)
            cache[key] = Simulated(path, truth)
        return cache[key]

    return make


@pytest.fixture(autouse=True)
def _own_user_dirs(own_user_dirs: UserDirs) -> UserDirs:
    """The commands read the user's configuration: these tests run with their own."""
    return own_user_dirs


@pytest.fixture
def cli(capsys: pytest.CaptureFixture[str]) -> Callable[[Sequence[str]], CliRun]:
    """Run ``canimucal ARGV`` in-process; return its exit status and captured output."""
    return lambda argv: run_captured(capsys, argv)
