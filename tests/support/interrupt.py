"""Resume tests: interrupt the demo's automatic operator as Ctrl-C would, check what is kept."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import pytest

from canimucal.cli import demo_cmd
from canimucal.cli.main import main
from canimucal.runtime import session as session_mod
from canimucal.runtime.operator import run_automatic
from canimucal.runtime.resume import ResumeState


def interrupt_after(monkeypatch: pytest.MonkeyPatch, positions: int) -> None:
    """Make the demo's automatic operator press Ctrl-C once ``positions`` are accepted."""
    real = run_automatic

    def run_until(session: session_mod.Session, **kwargs: Any) -> Any:
        run_command = session.command

        def interrupting(command: session_mod.SessionCommand) -> Any:
            events = run_command(command)
            accepted = command is session_mod.SessionCommand.ACCEPT
            if accepted and session.procedure.index >= positions:
                raise KeyboardInterrupt
            return events

        monkeypatch.setattr(session, "command", interrupting)
        return real(session, **kwargs)

    monkeypatch.setattr(demo_cmd, "run_automatic", run_until)


def assert_kept(first: ResumeState, record: dict[str, Any], node_id: int) -> None:
    """The finished record holds every position, the interrupted run's ones unchanged."""
    assert len(record["positions"]) == 5
    for index, earlier in first.averages[node_id].items():
        final = record["positions"][index]
        assert final["n"] == earlier.n
        np.testing.assert_allclose(final["mean_accel"], earlier.mean_accel, rtol=1e-9)


def run_interrupted(monkeypatch: pytest.MonkeyPatch, argv: Sequence[str], positions: int) -> None:
    """Run the headless demo ``argv`` and interrupt it once ``positions`` are accepted."""
    with monkeypatch.context() as m:
        interrupt_after(m, positions)
        assert main(list(argv)) == 130  # interrupted, recording kept
