"""Bus load as the tool sees it (docs/design.md §4: "it shows the bus load it sees").

:class:`BusLoadMeter` is a python-can :class:`~can.Listener` on the client's notifier: it
counts every frame received (all identifiers, not only the IMU's) and the bits each one
occupies on the wire, and reports the fraction of the bit rate over the last second.

Bits per classical CAN frame with ``n`` data bytes, worst-case bit stuffing (Davis et al.,
"Controller Area Network (CAN) schedulability analysis", 2007): the ``g + 8n``
bits from SOF to the CRC are stuffed, at most one stuff bit per 4 after the first; the 13
bits of CRC delimiter, ACK, EOF and intermission are not::

    bits = g + 8n + 13 + floor((g + 8n - 1) / 4),   g = 34 (11-bit id), 54 (29-bit id)

i.e. ``47 + 8n`` plus stuffing for an 11-bit identifier (135 bits at n = 8). Remote frames
carry no data (n = 0); CAN FD frames are counted with the same formula at the nominal rate
(an over-estimate). An error frame counts :data:`ERROR_FRAME_BITS`. The estimate is an upper
bound: real frames carry fewer stuff bits. Frames the tool sends itself are not received
back by python-can (no ``receive_own_messages``), so they are not in the count.
"""

from __future__ import annotations

import collections
import threading
import time
from collections.abc import Callable
from typing import Any, NamedTuple

import can

DEFAULT_BITRATE_BPS = 500_000
"""Assumed when the bit rate is not known (said so in :meth:`BusLoad.text`)."""
WINDOW_S = 1.0
ERROR_FRAME_BITS = 23
"""Worst case: 12 bits of superposed error flags, 8 delimiter, 3 intermission."""


def frame_bits(msg: can.Message) -> int:
    """Bits ``msg`` occupies on the wire, worst-case stuffing (see the module doc)."""
    if msg.is_error_frame:
        return ERROR_FRAME_BITS
    if msg.is_remote_frame:
        n = 0
    elif msg.is_fd:
        n = len(msg.data)
    else:
        n = min(msg.dlc, 8)
    stuffed = (54 if msg.is_extended_id else 34) + 8 * n
    return stuffed + 13 + (stuffed - 1) // 4


class BusLoad(NamedTuple):
    """Bus load over ``window_s``: fraction of the bit rate, frames/s, error frames."""

    fraction: float
    frames_per_s: float
    error_frames: int
    """Error frames in the window."""
    error_frames_total: int
    window_s: float
    bitrate_bps: int
    bitrate_assumed: bool

    def text(self) -> str:
        """One line, e.g. ``bus load: 3.2 % of 500 kbit/s (412 frames/s, 0 error frames)``."""
        assumed = " (assumed)" if self.bitrate_assumed else ""
        return (
            f"bus load: {100.0 * self.fraction:.1f} % of {self.bitrate_bps / 1000:g} kbit/s"
            f"{assumed} ({self.frames_per_s:.0f} frames/s, {self.error_frames} error frames) "
            f"over {self.window_s:.1f} s"
        )

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready form (``frame_bits`` names the bit-count rule)."""
        return {**self._asdict(), "frame_bits": "classical CAN, worst-case stuffing"}


class BusLoadMeter(can.Listener):
    """Counts frames and wire bits over a sliding window (thread-safe; see the module doc).

    ``bitrate_bps=None``: :data:`DEFAULT_BITRATE_BPS` assumed. ``clock`` (monotonic
    seconds) stamps each frame on arrival.
    """

    def __init__(
        self,
        bitrate_bps: int | None = None,
        *,
        window_s: float = WINDOW_S,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        if bitrate_bps is not None and bitrate_bps <= 0:
            raise ValueError(f"bitrate must be > 0 bit/s, got {bitrate_bps}")
        if not window_s > 0.0:
            raise ValueError(f"window must be > 0 s, got {window_s}")
        self.bitrate_assumed = bitrate_bps is None
        self.bitrate_bps = DEFAULT_BITRATE_BPS if bitrate_bps is None else int(bitrate_bps)
        self.window_s = window_s
        self._clock = clock
        self._started = clock()
        self._lock = threading.Lock()
        self._frames: collections.deque[tuple[float, int, bool]] = collections.deque()
        self.frames_total = 0
        self.error_frames_total = 0

    def stop(self) -> None:
        """Nothing to release (python-can 4.4 declares it abstract)."""

    def on_message_received(self, msg: can.Message) -> None:
        """Count one frame (python-can's receive thread)."""
        now = self._clock()
        with self._lock:
            self._frames.append((now, frame_bits(msg), msg.is_error_frame))
            self.frames_total += 1
            self.error_frames_total += msg.is_error_frame
            self._prune(now)

    def _prune(self, now: float) -> None:
        while self._frames and self._frames[0][0] < now - self.window_s:
            self._frames.popleft()

    def load(self, *, full_window: bool = False) -> BusLoad:
        """Load over the last ``window_s`` (or since the meter started, if sooner).

        ``full_window``: first sleep until the meter has run for a whole window.
        """
        if full_window:
            time.sleep(max(0.0, self._started + self.window_s - self._clock()))
        now = self._clock()
        with self._lock:
            self._prune(now)
            frames = list(self._frames)
            errors_total = self.error_frames_total
        span = min(self.window_s, now - self._started)
        bits = sum(b for _, b, _ in frames)
        errors = sum(e for _, _, e in frames)
        fraction = bits / (self.bitrate_bps * span) if span > 0.0 else 0.0
        rate = len(frames) / span if span > 0.0 else 0.0
        return BusLoad(
            fraction,
            rate,
            errors,
            errors_total,
            span,
            self.bitrate_bps,
            self.bitrate_assumed,
        )
