"""Pilot steps shared by the TUI tests that drive a whole calibration on the demo source.

Keys are posted with ``App.simulate_key`` and followed by short pauses: ``Pilot.press`` waits
for an idle app, which a live session never is (about 2 s a key).
"""

from __future__ import annotations

from collections.abc import Iterable

from canimucal.procedure.machine import Phase
from canimucal.procedure.verification import VERIFICATION_POSES
from canimucal.tui.modals import ConfirmWrite
from canimucal.tui.screens.position import PositionScreen
from canimucal.tui.screens.results import ResultsScreen
from canimucal.tui.screens.verification import VerificationScreen


async def until(pilot, condition, what: str, timeout_s: float = 30.0) -> None:  # type: ignore[no-untyped-def]
    """Pause until ``condition()`` holds; fail naming ``what`` and what the screen said.

    A refused pose, a rejected attempt or a stopped session leaves its reason in the
    position screen's title and notice line: the failure quotes them.
    """
    for _ in range(int(timeout_s / 0.05)):
        if condition():
            return
        await pilot.pause(0.05)
    raise AssertionError(f"timed out waiting for {what}; {screen_state(pilot.app)}")


def screen_state(app) -> str:  # type: ignore[no-untyped-def]
    """The current screen's class, title and notice line, as one line."""
    screen = app.screen
    parts = [type(screen).__name__]
    for name in ("title_w", "notice"):
        widget = getattr(screen, name, None)
        if widget is not None:
            parts.append(" ".join(str(widget.render()).split()))
    return "screen: " + " | ".join(parts)


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
    """From the results: write (anyway, if the limits fail), confirm, set each verification pose."""
    await write(pilot, screen)
    for index in range(VERIFICATION_POSES):

        def instructed(index: int = index) -> bool:
            return screen.verification and screen.index == index and screen.phase is Phase.INSTRUCT

        await until(pilot, instructed, f"verification pose {index + 1}")
        await press(pilot, "enter")
    await until(pilot, lambda: isinstance(pilot.app.screen, VerificationScreen), "the end")


async def write(pilot, screen: PositionScreen) -> None:  # type: ignore[no-untyped-def]
    """From the results: write (anyway, if the limits fail), confirm; stop at verification 1."""
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
