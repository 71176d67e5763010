"""SIGTERM handled like Ctrl-C, and signals held back while a rollback runs (docs/design.md §9).

:func:`handle_sigterm` makes SIGTERM raise :class:`Terminated`, a ``KeyboardInterrupt``, so
every clean-up written for Ctrl-C (rollback, recorder stop, NMT restore) runs for SIGTERM too;
the entry point maps it to exit status 143 (128 + 15). :class:`deferred_signals` holds
SIGINT and SIGTERM back while a block runs (the rollback of a write transaction, itself
bounded by its SDO timeouts) and tells afterwards which arrived, so no interrupt skips a
rollback or its message.
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Callable
from types import FrameType, TracebackType
from typing import Any

EXIT_INTERRUPTED = 130
"""Exit status after Ctrl-C (128 + SIGINT)."""
EXIT_TERMINATED = 143
"""Exit status after SIGTERM (128 + SIGTERM)."""

_HELD = (signal.SIGINT, signal.SIGTERM)


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised where Ctrl-C would be so that the same clean-up runs."""


def _raise_terminated(signum: int, frame: FrameType | None) -> None:
    raise Terminated


def _in_main_thread() -> bool:
    return threading.current_thread() is threading.main_thread()


def handle_sigterm() -> Callable[[], None]:
    """Make SIGTERM raise :class:`Terminated`; return a function restoring both handlers.

    The returned function puts back the SIGINT and SIGTERM handlers found on entry (undoing
    :func:`ignore_signals` too). Does nothing outside the main thread, where Python cannot
    install signal handlers.
    """
    if not _in_main_thread():
        return lambda: None
    previous = {s: signal.getsignal(s) for s in _HELD}
    signal.signal(signal.SIGTERM, _raise_terminated)

    def restore() -> None:
        for signum, handler in previous.items():
            signal.signal(signum, handler)

    return restore


def ignore_signals() -> None:
    """Ignore SIGINT and SIGTERM from now on (while the entry point reports and exits)."""
    if _in_main_thread():
        for signum in _HELD:
            signal.signal(signum, signal.SIG_IGN)


def interrupt_for(signum: int) -> KeyboardInterrupt:
    """Return the exception a held-back signal raises (:class:`Terminated` for SIGTERM)."""
    return Terminated() if signum == signal.SIGTERM else KeyboardInterrupt()


class deferred_signals:  # noqa: N801  (used as a context manager, like contextlib's)
    """Hold SIGINT and SIGTERM back for the duration of a ``with`` block.

    The signals that arrived are in :attr:`pending` afterwards (:meth:`interrupt` gives the
    exception the first would have raised); the caller raises it once its own message is
    attached. Outside the main thread nothing is held.
    """

    def __init__(self) -> None:
        self.pending: list[int] = []
        self._previous: dict[int, Any] = {}

    def _hold(self, signum: int, frame: FrameType | None) -> None:
        self.pending.append(signum)

    def __enter__(self) -> deferred_signals:
        if _in_main_thread():
            self._previous = {s: signal.signal(s, self._hold) for s in _HELD}
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        for signum, handler in self._previous.items():
            signal.signal(signum, handler)

    def interrupt(self) -> KeyboardInterrupt | None:
        """Return the exception for the first signal held back, or ``None``."""
        return interrupt_for(self.pending[0]) if self.pending else None
