"""The automatic operator: drives a :class:`~canimucal.runtime.session.Session` to the end.

Kept apart from :mod:`canimucal.runtime.session` (the runner itself): this is the headless
demo's stand-in for the person at the TUI, reacting to the procedure's phase.
"""

from __future__ import annotations

import time
from collections.abc import Sequence

from canimucal.errors import DeviceError
from canimucal.procedure import events as ev
from canimucal.procedure.machine import Phase
from canimucal.runtime.session import Session, SessionCommand, WriteOptions

MAX_REFUSALS = 3


def run_automatic(
    session: Session,
    *,
    write_anyway: bool = False,
    max_polls: int = 1_000_000,
    deadline_s: float | None = None,
) -> list[ev.Event]:
    """Drive a session to the end with an automatic operator (the headless demo).

    Skips the warm-up, confirms each pose (moving the simulated nodes), accepts every
    position, solves, writes when the acceptance limits pass (or ``write_anyway``), sets each
    verification pose. Gives up (cancels) after ``MAX_REFUSALS`` refused poses in a row.
    Returns the session's history (every event but the live readouts). With ``deadline_s`` (wall
    seconds) a session that has not finished by then is cancelled and DeviceError raised:
    the sample clock is the procedure's, but a simulated bus that cannot keep up must not
    turn the demo into an endless wait.
    """
    give_up_at = None if deadline_s is None else time.monotonic() + deadline_s
    try:
        session.start()
        for _ in range(max_polls):
            if give_up_at is not None and time.monotonic() > give_up_at:
                proc = session.procedure
                session.command(SessionCommand.CANCEL)
                raise DeviceError(
                    f"the automatic operator gave up after {deadline_s:.0f} s (phase "
                    f"{proc.phase.value}, position {proc.index + 1}): the simulated bus "
                    "cannot keep up at this time scale; lower time_scale",
                    options=("time_scale",),
                )
            _react(session, write_anyway)
            if session.procedure.phase in (Phase.DONE, Phase.CANCELLED):
                break
            session.poll()
            if _refusals_in_a_row(session.history) >= MAX_REFUSALS:
                session.command(SessionCommand.CANCEL)
                break
    finally:
        session.finish()  # what was recorded is kept, even on an error or Ctrl-C
    return session.history


def _refusals_in_a_row(history: Sequence[ev.Event]) -> int:
    count = 0
    for event in reversed(history):
        if isinstance(event, ev.PoseRefused):
            count += 1
        elif isinstance(event, ev.AveragingStarted | ev.PositionAccepted):
            break
    return count


def _react(session: Session, write_anyway: bool) -> list[ev.Event]:
    proc = session.procedure
    phase = proc.phase
    if phase is Phase.WARMUP:
        return session.command(SessionCommand.SKIP_WARMUP)
    if phase is Phase.INSTRUCT:
        return session.confirm_pose()
    if phase is Phase.REVIEW_POSITION:
        return session.command(SessionCommand.ACCEPT)
    if phase is Phase.READY_TO_SOLVE:
        return session.solve()
    if phase is Phase.REVIEW:
        assert proc.solved is not None
        if proc.solved.acceptable or write_anyway:
            return session.write(WriteOptions(override=write_anyway))
        return session.command(SessionCommand.FINISH_WITHOUT_WRITING)
    return []
