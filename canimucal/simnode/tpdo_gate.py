"""What the simulated node's TPDOs do while a store blocks it (truth ``store_pdo_mode``).

CANopenNode stores inside the 0x1010 SDO handler and may block for seconds while flash is
erased (truth ``store_delay_s``). What the PDO side does meanwhile depends on the firmware's
threads: ``drop`` (the frames of the blocked period are lost), ``queue`` (they wait in the
transmit buffer and go out in one burst when the store ends) or ``continue`` (a PDO thread
of its own sends them on time). The sample clock runs on in every mode: counters advance.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager

log = logging.getLogger(__name__)

QUEUE_LIMIT_FRAMES = 65_536
"""Frames a ``queue`` node holds at most; beyond, they are dropped (a full transmit buffer)."""


class TpdoGate:
    """Passes TPDO frames to ``send(cob_id, data)``, or holds or drops them during a store."""

    def __init__(self, mode: str, send: Callable[[int, bytes], None]) -> None:
        if mode not in ("drop", "queue", "continue"):
            raise ValueError(f"store_pdo_mode must be drop, queue or continue, got {mode!r}")
        self.mode = mode
        self._send = send
        self._lock = threading.Lock()
        self._blocked = False
        self._held: list[tuple[int, bytes]] = []
        self.dropped = 0
        """Frames lost because a store blocked the node (``drop``, or a full queue)."""
        self.queued = 0
        """Frames held during stores and sent late (``queue``)."""

    def send(self, cob_id: int, data: bytes) -> None:
        """Send a frame now, or hold or drop it while a store blocks."""
        with self._lock:
            if self._blocked and self.mode != "continue":
                if self.mode == "queue" and len(self._held) < QUEUE_LIMIT_FRAMES:
                    self._held.append((cob_id, data))
                else:
                    self.dropped += 1
                return
            self._send(cob_id, data)

    @contextmanager
    def blocking(self) -> Iterator[None]:
        """Gate the frames while the store inside runs, then send a ``queue`` burst."""
        with self._lock:
            self._blocked = True
        try:
            yield
        finally:
            with self._lock:  # the burst in order, before any newer frame
                self._blocked = False
                held, self._held = self._held, []
                self.queued += len(held)
                for cob_id, data in held:
                    self._send(cob_id, data)
            if held:
                log.info("sent %d TPDO frames held during the store", len(held))
