"""Interrupting the demo's automatic operator as Ctrl-C would (resume tests)."""

from __future__ import annotations

from typing import Any

import pytest

from canimucal.cli import demo_cmd
from canimucal.procedure import session as session_mod
from canimucal.procedure.automatic_operator import run_automatic


def interrupt_after(monkeypatch: pytest.MonkeyPatch, positions: int) -> None:
    """Make the demo's automatic operator press Ctrl-C once ``positions`` are accepted."""
    real = run_automatic

    def run_until(session: session_mod.Session, **kwargs: Any) -> Any:
        command = session.command

        def interrupting(name: str) -> Any:
            events = command(name)
            if name == "accept" and session.procedure.index >= positions:
                raise KeyboardInterrupt
            return events

        monkeypatch.setattr(session, "command", interrupting)
        return real(session, **kwargs)

    monkeypatch.setattr(demo_cmd, "run_automatic", run_until)
