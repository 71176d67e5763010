"""Buses for fault tests: a bus that fails on send, and a synchronous in-process link.

:class:`FaultyBus` wraps the client's bus and raises :class:`can.CanOperationError` on
demand (bus-off, full transmit queue): the interface-level faults of issue 6 that python-can's
virtual bus cannot produce. :func:`loopback_pair` gives two ends that deliver each frame to
the other side before ``send`` returns, so an SDO round trip costs microseconds and a
thousand faulted transactions run in well under a minute.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Any

import can


class FaultyBus(can.BusABC):
    """A client-side wrapper of a python-can bus whose ``send`` fails on demand.

    ``fail_sends(n)`` makes the next ``n`` sends raise :class:`can.CanOperationError` (as a
    bus-off or a full transmit buffer does); ``n=-1`` fails every send until ``heal()``.
    """

    def __init__(self, inner: can.BusABC) -> None:
        self._inner = inner
        self._fail = 0
        self._after = 0
        self.failed_sends = 0
        self.channel_info = f"faulty({inner.channel_info})"
        super().__init__(channel="faulty")

    def fail_sends(self, n: int, *, after: int = 0) -> None:
        """Fail ``n`` sends (-1: all, until :meth:`heal`) once ``after`` more have passed."""
        self._fail, self._after = n, after

    def heal(self) -> None:
        """Stop failing sends."""
        self._fail = self._after = 0

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        """Send through the wrapped bus, or raise while a failure is armed."""
        if self._after > 0:
            self._after -= 1
        elif self._fail:
            self._fail -= 1 if self._fail > 0 else 0
            self.failed_sends += 1
            raise can.CanOperationError("injected: transmit failed (bus-off)")
        self._inner.send(msg, timeout)

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        return self._inner.recv(timeout), False

    def shutdown(self) -> None:
        """Shut down the wrapped bus too."""
        super().shutdown()
        self._inner.shutdown()


class LoopbackBus(can.BusABC):
    """One end of a synchronous in-process link: ``send`` calls the peer's receivers now.

    ``receivers`` is the list of :class:`can.Listener` to call (bind it to a canopen
    network's ``listeners`` after ``connect()``); ``recv`` never returns a frame, so the
    notifier thread idles. Frames from any thread are delivered on that thread.
    """

    def __init__(self) -> None:
        self.peer: LoopbackBus | None = None
        self.receivers: list[Any] = []  # can.Listener or plain callables, as can.Notifier
        self.taps: list[Callable[[can.Message], None]] = []
        self._closed = threading.Event()
        self.channel_info = "loopback"
        super().__init__(channel="loopback")

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        """Deliver ``msg`` to the peer's receivers before returning."""
        msg.timestamp = time.time()
        for tap in self.taps:
            tap(msg)
        if self.peer is not None:
            for listener in list(self.peer.receivers):
                if isinstance(listener, can.Listener):
                    listener.on_message_received(msg)
                else:
                    listener(msg)

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        self._closed.wait(0.05 if timeout is None else min(timeout, 0.05))
        return None, False

    def shutdown(self) -> None:
        """Stop periodic tasks and wake the notifier."""
        self._closed.set()
        super().shutdown()


def loopback_pair() -> tuple[LoopbackBus, LoopbackBus]:
    """Two connected :class:`LoopbackBus` ends."""
    a, b = LoopbackBus(), LoopbackBus()
    a.peer, b.peer = b, a
    return a, b
