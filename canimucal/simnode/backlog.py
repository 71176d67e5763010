"""How far the listeners of an in-process virtual bus lag behind the simulated node.

python-can's virtual bus has no arbitration and unbounded receive queues: a simulated node
whose clock runs ``time_scale`` times the wall clock can put frames on it faster than the
host can dispatch them, and then every frame behind the backlog — an SDO answer too — waits.
On a real bus a saturated transmit queue holds the device back; here the producer asks
:class:`VirtualBusBacklog` how many frames wait in the *other* ends' receive queues and
pauses while that exceeds :data:`BACKLOG_LIMIT_FRAMES`, so the simulated clock slows instead
of burying the bus (the slip is counted, see ``SampleProducer.clock_slip_s``).

A listener that does not drain at all (a bus opened and never read) must not stop the node:
a queue that stays above the limit without shrinking for :data:`STALLED_AFTER_S` is ignored
until it falls below the limit again.

Other interfaces (SocketCAN, vcan) report 0: their kernel queues are not visible, and a real
or virtual kernel bus paces the sender by itself or drops frames, which the client counts.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from queue import Queue
from typing import Any

import can

BACKLOG_LIMIT_FRAMES = 128
"""Frames waiting in a listener's queue above which the node holds its next batch back.

Dispatching a frame costs the client tens of µs, so 128 frames keep an SDO answer's queueing
delay in milliseconds, far inside the 0.3 s SDO timeout."""
STALLED_AFTER_S = 0.5
"""A queue above the limit that has not shrunk for this long belongs to nobody reading."""


class VirtualBusBacklog:
    """``backlog()`` = most frames waiting in a live peer's receive queue (0: not virtual)."""

    def __init__(self, bus: can.BusABC | None, clock: Callable[[], float] = time.monotonic) -> None:
        channel = getattr(bus, "channel", None) if _is_virtual(bus) else None
        self._peers: list[Queue[Any]] | None = channel if isinstance(channel, list) else None
        self._own: Queue[Any] | None = getattr(bus, "queue", None)
        self._clock = clock
        self._last: dict[int, tuple[int, float]] = {}
        """id(queue) → (size when last seen, when it last shrank or was below the limit)."""

    @property
    def applies(self) -> bool:
        """Whether the bus is a python-can virtual bus (the only kind measured)."""
        return self._peers is not None

    def __call__(self) -> int:
        """Frames waiting in the fullest receive queue of a peer that still drains."""
        if self._peers is None:
            return 0
        now = self._clock()
        worst = 0
        seen: dict[int, tuple[int, float]] = {}
        for peer in list(self._peers):  # python-can appends/removes under its own lock
            if peer is self._own:
                continue
            size = peer.qsize()
            key = id(peer)
            previous = self._last.get(key)
            if size <= BACKLOG_LIMIT_FRAMES or previous is None or size < previous[0]:
                since = now
            else:
                since = previous[1]
            seen[key] = (size, since)
            if now - since < STALLED_AFTER_S:
                worst = max(worst, size)
        self._last = seen
        return worst


def _is_virtual(bus: can.BusABC | None) -> bool:
    try:
        from can.interfaces.virtual import VirtualBus
    except ImportError:  # pragma: no cover - python-can always ships it
        return False
    return isinstance(bus, VirtualBus)
