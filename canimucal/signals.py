"""SIGTERM and SIGHUP handled like Ctrl-C; signals held while a rollback or a store runs.

docs/design.md §9 ("Signals"). :func:`handle_signals` makes SIGTERM raise
:class:`Terminated` and SIGHUP (the terminal or SSH session closed) :class:`HungUp`, both
subclasses of ``KeyboardInterrupt``, so every clean-up written for Ctrl-C (rollback,
recorder stop, NMT restore) runs for them too; the entry point maps them to exit status 143
and 129 (130 for Ctrl-C). Only the first signal raises: later ones are held until the
process exits, so a second Ctrl-C can neither cut a clean-up short nor replace the first
interrupt (and the notes that say what was done) with a bare one. :class:`deferred_signals`
holds all three back while a block runs (the rollback of a write transaction, the store and
its read-back, each bounded by its SDO timeouts) and tells afterwards which arrived.
"""

from __future__ import annotations

import signal
import threading
from types import FrameType, TracebackType
from typing import Any

EXIT_INTERRUPTED = 130
"""Exit status after Ctrl-C (128 + SIGINT)."""
EXIT_TERMINATED = 143
"""Exit status after SIGTERM (128 + SIGTERM)."""
EXIT_HUNG_UP = 129
"""Exit status after SIGHUP (128 + SIGHUP): the controlling terminal went away."""

HELD_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
"""The signals the tool turns into interrupts (and holds back where it must not stop)."""


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised where Ctrl-C would be so that the same clean-up runs."""


class HungUp(Terminated):
    """SIGHUP, raised like SIGTERM (:class:`Terminated`) with its own exit status."""


def interrupt_for(signum: int) -> KeyboardInterrupt:
    """Return the exception ``signum`` raises (:class:`Terminated` for SIGTERM, …)."""
    if signum == signal.SIGHUP:
        return HungUp()
    return Terminated() if signum == signal.SIGTERM else KeyboardInterrupt()


def exit_status(interrupt: KeyboardInterrupt) -> int:
    """Exit status for an interrupt: 129 (SIGHUP), 143 (SIGTERM) or 130 (Ctrl-C)."""
    if isinstance(interrupt, HungUp):
        return EXIT_HUNG_UP
    return EXIT_TERMINATED if isinstance(interrupt, Terminated) else EXIT_INTERRUPTED


def describe(interrupt: KeyboardInterrupt) -> str:
    """Return the word the entry point prints: ``hung up``, ``terminated``, ``interrupted``."""
    if isinstance(interrupt, HungUp):
        return "hung up"
    return "terminated" if isinstance(interrupt, Terminated) else "interrupted"


def _in_main_thread() -> bool:
    return threading.current_thread() is threading.main_thread()


class _FirstRaises:
    """Signal handler: the first signal raises its interrupt, later ones are dropped.

    Once disarmed (the handlers are being put back) every signal is dropped.
    """

    def __init__(self) -> None:
        self.first: int | None = None
        self.armed = True

    def __call__(self, signum: int, frame: FrameType | None) -> None:
        if self.first is not None or not self.armed:
            return
        self.first = signum
        raise interrupt_for(signum)


class SignalHandling:
    """The handlers :func:`handle_signals` installed; calling it puts back the previous ones.

    :attr:`first` is the first signal that arrived (None: none yet).
    """

    def __init__(self, handler: _FirstRaises | None, previous: dict[int, Any]) -> None:
        self._handler = handler
        self._previous = previous

    @property
    def first(self) -> int | None:
        """The first of the three signals received since the handlers were installed."""
        return None if self._handler is None else self._handler.first

    def __call__(self) -> None:
        """Put back the handlers found on entry.

        The handler is disarmed first: a signal while the handlers are being put back (the
        command has ended) is dropped, not raised out of the caller's ``finally`` (measured:
        4 of 100 Ctrl-Cs sent as ``plan``'s output ended died of an uncaught interrupt there).
        """
        if self._handler is not None:
            self._handler.armed = False
        for signum, old in self._previous.items():
            signal.signal(signum, old)


def handle_signals() -> SignalHandling:
    """Turn SIGINT, SIGTERM and SIGHUP into interrupts; return what restores the handlers.

    The first of them raises (``KeyboardInterrupt``, :class:`Terminated`, :class:`HungUp`);
    one ignored on entry stays ignored (``nohup``, a background job); any that follow the
    first are held until the handlers are restored (and then dropped: the
    process is ending with the first one's status). Calling the returned
    :class:`SignalHandling` puts back the handlers found on entry (undoing
    :func:`ignore_signals` too). Does nothing outside the main thread, where Python cannot
    install signal handlers.
    """
    if not _in_main_thread():
        return SignalHandling(None, {})
    previous: dict[int, Any] = {int(s): signal.getsignal(s) for s in HELD_SIGNALS}
    handler = _FirstRaises()
    for signum in _not_ignored():
        signal.signal(signum, handler)
    return SignalHandling(handler, previous)


def _not_ignored() -> list[int]:
    """Return the held signals not ignored on entry.

    ``nohup`` (SIGHUP) or a shell's background job (SIGINT) asked the process to ignore
    them, and it does.
    """
    return [s for s in HELD_SIGNALS if signal.getsignal(s) is not signal.SIG_IGN]


handle_sigterm = handle_signals
"""The former name of :func:`handle_signals` (it handled SIGTERM only)."""


def ignore_signals() -> None:
    """Ignore SIGINT, SIGTERM and SIGHUP from now on (while the entry point reports and exits)."""
    if _in_main_thread():
        for signum in HELD_SIGNALS:
            signal.signal(signum, signal.SIG_IGN)


class deferred_signals:  # noqa: N801  (used as a context manager, like contextlib's)
    """Hold SIGINT, SIGTERM and SIGHUP back for the duration of a ``with`` block.

    The signals that arrived are in :attr:`pending` afterwards (:meth:`interrupt` gives the
    exception the first would have raised); the caller raises it once its own message is
    attached. When one arrived, the hold stays in place after the block (later signals are
    dropped), so no second interrupt can replace the one the caller raises; whoever set the
    handlers up (the entry point, :func:`handle_signals`' restore) puts them back. When
    none arrived, the handlers found on entry are restored. Outside the main thread nothing
    is held.
    """

    def __init__(self) -> None:
        self.pending: list[int] = []
        self._previous: dict[int, Any] = {}

    def _hold(self, signum: int, frame: FrameType | None) -> None:
        self.pending.append(signum)

    def __enter__(self) -> deferred_signals:
        if _in_main_thread():
            self._previous = {s: signal.signal(s, self._hold) for s in _not_ignored()}
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        if self.pending:
            return  # the caller raises the first; later signals must not replace it
        for signum, handler in self._previous.items():
            signal.signal(signum, handler)

    def interrupt(self) -> KeyboardInterrupt | None:
        """Return the exception for the first signal held back, or ``None``."""
        return interrupt_for(self.pending[0]) if self.pending else None
