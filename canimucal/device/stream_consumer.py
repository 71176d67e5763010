"""The consumer thread of a stream: raw frames queued by the receive callback, paired here.

Kept apart from :mod:`canimucal.device.stream`, which decides *what* a sample is (decoding
and pairing); this module decides *when*: it owns the thread, the raw-frame queue, batching
into :class:`~canimucal.device.stream.SampleBlock`s and the bounded drain on stop.
"""

from __future__ import annotations

import logging
import queue
import threading
import time

from canimucal.device.stream import SamplePairer
from canimucal.model.samples import SampleBlock

logger = logging.getLogger(__name__)

BATCH_INTERVAL_S = 0.02
"""The consumer thread hands out a :class:`SampleBlock` at most every 20 ms (or 256 rows)."""
BATCH_MAX_ROWS = 256
REBOOT_MARK = -1
"""Pseudo COB-ID queued when the node boots: the pairer restarts (counters begin again)."""
STOP_TIMEOUT_S = 10.0
"""How long stopping the stream waits for the consumer to drain what was received."""


class StreamConsumer:
    """Raw-frame queue (filled by the callback) and the consumer thread that pairs."""

    def __init__(self, pairer: SamplePairer, out: queue.SimpleQueue[SampleBlock]) -> None:
        self.pairer = pairer
        self.out = out
        self.raw: queue.SimpleQueue[tuple[int, bytes, float]] = queue.SimpleQueue()
        self.stopping = threading.Event()
        self.thread = threading.Thread(target=self._run, name="canimucal-stream", daemon=True)
        self.cpu_s = 0.0

    def cob_ids(self) -> list[int]:
        """COB-IDs of the TPDOs the layout uses."""
        layout = self.pairer.layout
        ids = [layout.accel.cob_id, layout.gyro.cob_id]
        return ids + ([layout.info.cob_id] if layout.info is not None else [])

    def on_frame(self, can_id: int, data: bytearray, timestamp: float) -> None:
        """Receive callback (notifier thread): enqueue only."""
        self.raw.put((can_id, bytes(data), timestamp))

    def on_boot(self, can_id: int, data: bytearray, timestamp: float) -> None:
        """Boot-up frame: tell the consumer, in frame order, that counters restart."""
        if data[:1] == b"\x00":
            self.raw.put((REBOOT_MARK, b"", timestamp))

    def start(self) -> None:
        """Start the consumer thread."""
        self.thread.start()

    def _feed(self, can_id: int, data: bytes, timestamp: float) -> None:
        if can_id == REBOOT_MARK:
            self.pairer.restart()
        else:
            self.pairer.feed(can_id, data, timestamp)

    def stop(self) -> None:
        """Drain what was received, flush pending halves, hand out the last block.

        The caller unsubscribes first, so the raw queue only shrinks and the drain is
        bounded; the join still has a deadline, so a stuck consumer is reported, never a
        hung Ctrl-C (which would keep a recording's ``.partial`` from being renamed).
        """
        self.stopping.set()
        self.thread.join(STOP_TIMEOUT_S)
        if self.thread.is_alive():
            logger.error(
                "stream consumer did not finish within %g s; %d frames not paired",
                STOP_TIMEOUT_S,
                self.raw.qsize(),
            )

    def _run(self) -> None:
        pairer, last_put = self.pairer, time.monotonic()
        idle_s = max(2.0 * pairer.period_s, 0.005)
        while True:
            try:
                self._feed(*self.raw.get(timeout=idle_s))
                for _ in range(1024):
                    self._feed(*self.raw.get_nowait())
            except queue.Empty:
                if self.stopping.is_set():
                    break
                pairer.expire(time.time() if pairer.clock is None else pairer.clock())
            now = time.monotonic()
            if pairer.ready >= BATCH_MAX_ROWS or (
                pairer.has_news() and now - last_put >= BATCH_INTERVAL_S
            ):
                self.out.put(pairer.take())
                last_put = now
            self.cpu_s = time.thread_time()
        pairer.flush()
        if pairer.has_news():
            self.out.put(pairer.take())
        self.cpu_s = time.thread_time()
