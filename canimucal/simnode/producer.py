"""The sampling thread of the simulated node: simulator blocks in, TPDO frames out.

Samples are produced at the output data rate in *simulated* time; ``time_scale`` simulated
seconds pass per wall second. The thread wakes every millisecond or so and produces the
samples that are due, in small batches, so a fast time scale paces frames onto the bus
instead of flooding it in one burst. After a stall it catches up at most
:data:`MAX_LAG_WALL_S` of wall time; beyond that, and while the listeners of a virtual bus
lag (``backlog()`` above :data:`~canimucal.simnode.backlog.BACKLOG_LIMIT_FRAMES`), the
simulated clock slips instead: ``time_scale`` is an upper bound, never a reason to bury the
bus under frames the host cannot dispatch (the slip is counted in ``clock_slip_s``). Samples
are never skipped: the counter and the simulated time run on, only slower.

With ``wall_clock`` (a node in its own process on a real bus, ``canimucal sim``) a host too
slow to keep up does not slow the unit's world: a real unit's sensor and the operator moving it
keep the wall clock, whatever its CPU manages to send. The samples past the catch-up limit are
made (the simulated time, the pose schedule and the counter run on) but never sent, as an
overloaded MCU drops them: the recorder sees counter gaps, counts them lost, and the sample
rate it measures over the receive times stays the device's (counted in ``samples_dropped``).
A slowed clock there would look like a device sampling slower than it claims, and a schedule
labelled at the measured rate would name the wrong pose.

Event-driven TPDOs (transmission type 254/255) follow their event timers in simulated time;
SYNC-driven ones (1..240) are sent from :meth:`SampleProducer.on_sync`. Nothing is sent unless
the node is OPERATIONAL.

With ``second_send_ms`` TPDO1 and TPDO2 go out once more that long after each sample, the
same frame: a second send trigger, as an event timer beside data-ready sending is in
CANopenNode (issue 24, case 3).

With ``timer_skew_ppm`` the event timers run on a clock of their own, that many ppm slow
(+) or fast (−) against the sample clock, as on an MCU whose timer and sensor do not share an
oscillator: each tick sends the newest sample at its own time, between samples, so a slow
timer skips a counter every 10⁶/ppm ticks and a fast one sends a counter twice
(:meth:`~canimucal.simnode.pdo.EventTimer.ticks`). Without skew the two are one clock and a
TPDO goes out with the sample that makes it due.
"""

from __future__ import annotations

import heapq
import itertools
import logging
import threading
import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from canimucal.device import od
from canimucal.model.vocabulary.constants import COUNTER_MODULUS, INT16_MAX, INT16_MIN
from canimucal.sim.imu import ImuSimulator, SimBlock
from canimucal.simnode.backlog import BACKLOG_LIMIT_FRAMES
from canimucal.simnode.pdo import EventTimer, TpdoLayout

log = logging.getLogger(__name__)

Key = tuple[int, int]
Frame = tuple[int, bytes]
TimedFrame = tuple[int, float, int, bytes]
"""(sample index in its block, simulated seconds after that sample, COB-ID, data)."""

MAX_BATCH = 32
"""Most samples produced per wake-up (64 PDO frames at most), to pace a fast time scale."""
MIN_SLEEP_S = 0.001
MAX_LAG_WALL_S = 0.1
"""A stall longer than this (wall time) is not caught up: the simulated clock slips."""
MAX_SLEEP_S = 0.02


def _int16_rows(values: object) -> list[Any]:
    """Round to INT16, saturating (the simulator saturates already; this guards rounding)."""
    arr = np.clip(np.rint(np.asarray(values, dtype=float)), INT16_MIN, INT16_MAX)
    return arr.astype(np.int64).tolist()


class SampleProducer:
    """Produces samples from an :class:`ImuSimulator` and sends TPDO1–3.

    ``layouts()`` returns the current TPDO layouts, ``operational()`` whether the node is
    OPERATIONAL, ``send(cob_id, data)`` puts a frame on the bus and ``cal_active()`` whether
    the firmware applies the calibration (status bit 2). ``lock`` guards the simulator and
    the live values; the node takes it too.
    """

    def __init__(
        self,
        simulator: ImuSimulator,
        lock: threading.RLock,
        *,
        time_scale: float,
        layouts: Callable[[], Sequence[TpdoLayout]],
        operational: Callable[[], bool],
        send: Callable[[int, bytes], None],
        cal_active: Callable[[], bool],
        on_time: Callable[[float], None] | None = None,
        backlog: Callable[[], int] | None = None,
        timer_skew_ppm: float = 0.0,
        second_send_ms: float = 0.0,
        before_sending: Callable[[], None] | None = None,
        wall_clock: bool = False,
    ) -> None:
        self.simulator = simulator
        self.wall_clock = bool(wall_clock)
        self._before_sending = before_sending
        self.lock = lock
        self.time_scale = float(time_scale)
        self._layouts = layouts
        self._operational = operational
        self._send = send
        self._cal_active = cal_active
        self._on_time = on_time
        self._backlog = backlog
        self.timer_skew_ppm = float(timer_skew_ppm)
        self.second_send_s = float(second_send_ms) / 1000.0
        """TPDO1/2 again this long (simulated s) after each sample: a second send trigger."""
        self._timed: list[tuple[float, int, int, bytes]] = []  # (wall time, seq, COB-ID, data)
        self._timed_seq = itertools.count()
        self.clock_slip_s = 0.0
        """Simulated seconds the clock fell behind ``time_scale`` × wall time (host too slow)."""
        self.samples_dropped = 0
        """Samples made but never sent because the host fell behind (``wall_clock`` only)."""
        self.error_register = 0
        """0x1001 as the live value reports it (an EMCY sets it)."""
        self.live: dict[Key, int] = {}
        self.last_block: SimBlock | None = None
        self.counter = 0
        self.samples_produced = 0
        self._rate_hz = 0.0
        self._anchor_wall = 0.0
        self._anchor_count = 0
        self._timers = [EventTimer() for _ in od.TPDO_COMM]
        self._sync_counts = [0 for _ in od.TPDO_COMM]
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.error: BaseException | None = None

    # -- lifecycle -------------------------------------------------------------------------

    def start(self, rate_hz: float) -> None:
        """Start the thread producing at ``rate_hz`` (simulated)."""
        self.set_rate(rate_hz)
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name="sim-imu-producer", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """Stop the thread and wait for it."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
            self._thread = None

    def set_rate(self, rate_hz: float) -> None:
        """Change the output data rate; pacing restarts from now."""
        with self.lock:
            self.simulator.set_sample_rate(rate_hz)
            self._rate_hz = float(rate_hz)
            self._anchor_wall = time.monotonic()
            self._anchor_count = 0
            for timer in self._timers:
                timer.reset()
            self._timed.clear()

    def reset_counter(self) -> None:
        """Counter back to 0 and event timers restarted (NMT reset)."""
        with self.lock:
            self.counter = 0
            self._sync_counts = [0 for _ in od.TPDO_COMM]
            for timer in self._timers:
                timer.reset()
            self._timed.clear()  # ticks of the old schedule never go out after a reset

    # -- the loop --------------------------------------------------------------------------

    def _run(self) -> None:
        try:
            while not self._stop.is_set():
                frames, wait_s = self._step()
                if frames and self._operational():
                    for cob_id, data in frames:
                        self._send(cob_id, data)
                if self.timer_skew_ppm or self.second_send_s:
                    next_tick = self._send_timed()
                    if next_tick is not None:
                        wait_s = min(wait_s, next_tick)
                if self._on_time is not None and self.last_block is not None:
                    self._on_time(float(self.last_block.t_s[-1]))
                if wait_s > 0.0:
                    self._stop.wait(wait_s)
        except Exception as exc:  # a dead producer must be visible, not silent
            self.error = exc
            log.exception("simulated IMU producer stopped")

    def _step(self) -> tuple[list[Frame], float]:
        """Produce the samples due now (at most MAX_BATCH); return frames and a sleep."""
        with self.lock:
            rate = self._rate_hz * self.time_scale
            elapsed = time.monotonic() - self._anchor_wall
            due = int(elapsed * rate) - self._anchor_count
            if due <= 0:
                next_in = (self._anchor_count + 1) / rate - elapsed
                return [], min(MAX_SLEEP_S, max(MIN_SLEEP_S, next_in))
            held_back = self._backlog is not None and self._backlog() > BACKLOG_LIMIT_FRAMES
            lag_limit = max(MAX_BATCH, int(MAX_LAG_WALL_S * rate))
            if held_back or due > lag_limit:
                slip = due if held_back else due - lag_limit
                self._anchor_count += slip
                if self.wall_clock and not held_back:
                    self._drop(slip)
                else:
                    self.clock_slip_s += slip / self._rate_hz
                if held_back:
                    return [], MIN_SLEEP_S
                due -= slip
            n = min(due, MAX_BATCH)
            # decided once per block: a state change mid-block never sends samples made
            # before it, and what must start with the first sample sent starts here
            sending = self._operational()
            if sending and self._before_sending is not None:
                self._before_sending()
            block = self.simulator.next_block(n)
            first_due_wall = self._anchor_wall + (self._anchor_count + 1) / rate
            self._anchor_count += n
            frames, ticks = self._consume(block, sending)
            if ticks:
                self._schedule(ticks, first_due_wall, rate)
        return frames, (MIN_SLEEP_S if due <= MAX_BATCH else 0.0)

    def _drop(self, n: int) -> None:
        """Make ``n`` samples and send none: the world and the counter keep the wall clock.

        The live values (0x2001, 0x2002, read by SDO) become the last of them, as an MCU's
        registers hold the newest sample whether or not its frames went out.
        """
        block = self.last_block = self.simulator.next_block(n)
        self.counter = (self.counter + n - 1) % COUNTER_MODULUS
        self.samples_produced += n - 1
        self.samples_dropped += n
        last = slice(n - 1, n)
        status = od.STATUS_CAL_ACTIVE if self._cal_active() else 0
        status |= od.STATUS_SATURATED if bool(np.asarray(block.saturated)[-1]) else 0
        status |= od.STATUS_MOVING if bool(np.asarray(block.moving)[-1]) else 0
        temp = _int16_rows(np.asarray(block.temp_c, dtype=float)[last] * 100.0)[0]
        accel, gyro = _int16_rows(block.accel[last])[0], _int16_rows(block.gyro[last])[0]
        self._update_live(accel, gyro, temp, status)  # the last sample: counter + 1

    def _schedule(self, ticks: list[TimedFrame], first_due_wall: float, rate: float) -> None:
        """Queue skewed timer ticks at their wall times.

        Sample j of a block was due ``j/rate`` wall seconds after its first; a tick's offset
        is in simulated seconds.
        """
        for j, offset_s, cob_id, data in ticks:
            wall = first_due_wall + j / rate + offset_s / self.time_scale
            heapq.heappush(self._timed, (wall, next(self._timed_seq), cob_id, data))

    def _send_timed(self) -> float | None:
        """Send the ticks now due; return the wall seconds until the next one (None: none)."""
        while True:
            with self.lock:
                if not self._timed:
                    return None
                wait = self._timed[0][0] - time.monotonic()
                if wait > 0.0:
                    return wait
                _, _, cob_id, data = heapq.heappop(self._timed)
            if self._operational():
                self._send(cob_id, data)

    def _consume(self, block: SimBlock, sending: bool) -> tuple[list[Frame], list[TimedFrame]]:
        """Update live values sample by sample and collect the event-driven frames.

        Returns the frames to send now (none unless ``sending``) and, with a skewed timer,
        the ticks to send later.
        """
        self.last_block = block
        layouts = (
            [lay for lay in self._layouts() if lay.enabled and lay.on_event] if sending else []
        )
        frames: list[Frame] = []
        accel = _int16_rows(block.accel)
        gyro = _int16_rows(block.gyro)
        temps = _int16_rows(np.asarray(block.temp_c, dtype=float) * 100.0)  # 0.01 °C
        base_status = od.STATUS_CAL_ACTIVE if self._cal_active() else 0
        saturated = np.asarray(block.saturated, dtype=bool)
        moving = np.asarray(block.moving, dtype=bool)
        skew = 1.0 + self.timer_skew_ppm * 1e-6
        sample_period_s = 1.0 / self._rate_hz
        ticks: list[TimedFrame] = []
        for i, t_s in enumerate(np.asarray(block.t_s, dtype=float).tolist()):
            status = base_status
            status |= od.STATUS_SATURATED if saturated[i] else 0
            status |= od.STATUS_MOVING if moving[i] else 0
            self._update_live(accel[i], gyro[i], temps[i], status)
            for layout in layouts:
                timer = self._timers[layout.number - 1]
                if self.timer_skew_ppm:
                    period_s = layout.event_timer_ms / 1000.0 * skew
                    offsets = timer.ticks(t_s, period_s, sample_period_s)
                    if offsets:
                        data = layout.pack(self.live)
                        ticks.extend((i, offset, layout.cob_id, data) for offset in offsets)
                elif timer.due(t_s, layout.event_timer_ms / 1000.0):
                    data = layout.pack(self.live)
                    frames.append((layout.cob_id, data))
                    if self.second_send_s and layout.number in (1, 2):
                        ticks.append((i, self.second_send_s, layout.cob_id, data))
        return frames, ticks

    def _update_live(self, accel: list[int], gyro: list[int], temp: int, status: int) -> None:
        self.counter = (self.counter + 1) % COUNTER_MODULUS  # 0x2002:02 wraps
        self.samples_produced += 1
        live = self.live
        live[(od.ACCEL_RAW, 1)], live[(od.ACCEL_RAW, 2)], live[(od.ACCEL_RAW, 3)] = accel
        live[(od.GYRO_RAW, 1)], live[(od.GYRO_RAW, 2)], live[(od.GYRO_RAW, 3)] = gyro
        live[(od.SAMPLE_INFO, 1)] = temp
        live[(od.SAMPLE_INFO, 2)] = self.counter
        live[(od.SAMPLE_INFO, 3)] = status
        live[(od.ERROR_REGISTER, 0)] = self.error_register

    # -- SYNC ------------------------------------------------------------------------------

    def on_sync(self) -> list[Frame]:
        """Frames due on this SYNC (every n-th SYNC for transmission type n; 0 = every)."""
        frames: list[Frame] = []
        with self.lock:
            if not self.live:
                return frames
            for layout in self._layouts():
                if not (layout.enabled and layout.on_sync):
                    continue
                k = layout.number - 1
                self._sync_counts[k] += 1
                every = max(1, layout.trans_type)
                if self._sync_counts[k] % every == 0:
                    frames.append((layout.cob_id, layout.pack(self.live)))
        return frames
