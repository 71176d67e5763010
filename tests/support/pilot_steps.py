"""Pilot steps shared by the TUI tests that drive a whole calibration on the demo source.

Keys are posted with ``App.simulate_key`` and followed by short pauses: ``Pilot.press`` waits
for an idle app, which a live session never is (about 2 s a key).
"""

from __future__ import annotations

from collections.abc import Iterable

from canimucal.procedure.machine import Phase
from canimucal.tui.modals import ConfirmWrite
from canimucal.tui.screens.position import PositionScreen
from canimucal.tui.screens.results import ResultsScreen
from canimucal.tui.screens.verification import VerificationScreen


async def until(pilot, condition, what: str, timeout_s: float = 30.0) -> None:  # type: ignore[no-untyped-def]
    """Pause until ``condition()`` holds; fail naming ``what`` after ``timeout_s``."""
    for _ in range(int(timeout_s / 0.05)):
        if condition():
            return
        await pilot.pause(0.05)
    raise AssertionError(f"timed out waiting for {what}")


async def press(pilot, key: str) -> None:  # type: ignore[no-untyped-def]
    """Post ``key`` and let the app react."""
    pilot.app.simulate_key(key)
    await pilot.pause(0.05)


async def measure_positions(pilot, screen: PositionScreen, indices: Iterable[int]) -> None:  # type: ignore[no-untyped-def]
    """Confirm each pose, accept each average, and ask for the solution."""
    for index in indices:
        await until(pilot, lambda: screen.phase is Phase.INSTRUCT, f"pose {index + 1}")
        assert screen.index == index
        await press(pilot, "enter")
        await until(pilot, lambda: screen.phase is Phase.REVIEW_POSITION, f"average {index}")
        await press(pilot, "a")
    await until(pilot, lambda: screen.phase is Phase.READY_TO_SOLVE, "all positions")
    await press(pilot, "v")


async def write_and_verify(pilot, screen: PositionScreen) -> None:  # type: ignore[no-untyped-def]
    """From the results: write (anyway, if the limits fail), confirm, verify at level."""
    await write(pilot, screen)
    await press(pilot, "enter")
    await until(pilot, lambda: isinstance(pilot.app.screen, VerificationScreen), "the end")


async def write(pilot, screen: PositionScreen) -> None:  # type: ignore[no-untyped-def]
    """From the results: write (anyway, if the limits fail), confirm; stop at the level pose."""
    app = pilot.app
    await until(pilot, lambda: isinstance(app.screen, ResultsScreen), "the results")
    results = app.screen
    assert isinstance(results, ResultsScreen)
    await press(pilot, "w" if results.solved.acceptable else "o")
    await until(pilot, lambda: isinstance(app.screen, ConfirmWrite), "the confirmation")
    await press(pilot, "y")
    await until(
        pilot, lambda: screen.verification and screen.phase is Phase.INSTRUCT, "verification"
    )
