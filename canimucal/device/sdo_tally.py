"""Counting SDO answers against requests: a second device with one node-id answers twice.

docs/design.md §9 ("One device per node-id"). Every SDO request other than an abort gets
exactly one answer from one server. :class:`SdoAnswerTally` counts the requests this client
sends (it wraps the canopen ``SdoClient``'s ``send_request``), the requests other clients
send to the node (seen on the bus), and every answer on 0x580 + id; the surplus of answers
over requests is what a second answerer adds.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Callable

from canopen.sdo.client import SdoClient

CLIENT_ABORT = 0x80
"""Command specifier of an SDO abort (top three bits): no answer expected."""


def _expects_answer(data: bytes | bytearray) -> bool:
    return bool(data) and data[0] & 0xE0 != CLIENT_ABORT


class SdoAnswerTally:
    """Requests expecting an answer (ours and others') against answers received."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self.requests = 0
        self.answers = 0
        self._foreign: deque[tuple[float, bytes]] = deque(maxlen=256)

    def attach(self, sdo: SdoClient) -> None:
        """Count every request ``sdo`` sends.

        Counted before it leaves (its answer may come back before ``send_request``
        returns); a send that fails is taken back.
        """
        send: Callable[[bytes | bytearray], None] = sdo.send_request

        def counted(request: bytes | bytearray) -> None:
            expected = _expects_answer(request)
            if expected:
                self._bump("requests")
            try:
                send(request)
            except BaseException:
                if expected:
                    self._bump("requests", -1)
                raise

        sdo.send_request = counted  # type: ignore[method-assign]

    def _bump(self, name: str, by: int = 1) -> None:
        with self._lock:
            setattr(self, name, getattr(self, name) + by)

    def on_foreign_request(self, data: bytes | bytearray) -> None:
        """Another client's request to the node (its answer is counted as well)."""
        if _expects_answer(data):
            with self._lock:
                self.requests += 1
                self._foreign.append((time.monotonic(), bytes(data[1:4])))

    def on_response(self, can_id: int, data: bytearray, timestamp: float) -> None:
        """Count an answer on 0x580 + id (canopen's receive thread)."""
        self._bump("answers")

    def foreign_since(self, since: float, key: bytes) -> int:
        """Count requests by other clients for object ``key`` (index LE16, sub) since ``since``."""
        with self._lock:
            return sum(t >= since and k == key for t, k in self._foreign)

    @property
    def surplus(self) -> int:
        """Answers beyond one per request (negative while answers are outstanding or lost)."""
        with self._lock:
            return self.answers - self.requests
