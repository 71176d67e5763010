"""Fault injection for the simulated node: the truth JSON's ``faults`` block.

Every key is optional; an empty block injects nothing. Times are *simulated* seconds (the
sample clock), so a fast ``time_scale`` runs long scenarios quickly.

=========================  ===================================================================
key                        meaning
=========================  ===================================================================
``seed``                   seed of the fault draws (default 0), independent of the noise seed
``tpdo_drop_fraction``     each TPDO frame is dropped with this probability
``burst_loss``             ``{"probability": p, "frames": n}``: with probability p per frame a
                           burst starts and n consecutive TPDO frames are dropped
``duplicate_fraction``     each TPDO frame is sent twice with this probability
``delay_fraction``         each TPDO frame is held back with this probability and sent after
                           ``delay_frames`` (default 3) later frames
``wrong_length_fraction``  each TPDO frame loses its last byte with this probability
``sdo_aborts``             list of ``{"object": "0x2101:05", "code": 0x08000020, "access":
                           "write"|"read"|"any", "after_writes": n, "at_access": k}``: abort the
                           object's transfers (after n accepted writes to it; only the k-th
                           matching access, 1-based); code defaults to 0x08000020
``sdo_silent_after``       the SDO server answers this many requests, then goes silent
                           (request counts restart at every ``set``)
``sdo_silent_mode``        ``"request"`` (default: requests ignored unprocessed) or
                           ``"response"`` (requests processed, answers lost)
``reboot_at_sdo_request``  power-cycle instead of answering the n-th SDO request (1-based)
``reboot_before_sdo_``     power-cycle just before serving the n-th SDO request, then serve it
``request``                (the request lands on the freshly booted node, as one sent right
                           after a restart the client had not yet heard of)
``abort_at_sdo_request``   abort the n-th SDO request, whatever it is (code 0x08000020)
``reboot_at_s``            power-cycle at this simulated time
``emergency``              list of ``{"at_s": t, "code": 0x5000, "register": 0x01}``: EMCY frames
``heartbeat_loss``         ``{"from_s": t, "until_s": t or null}``: no heartbeat in between
``serial_after_reboot``    the identity serial (0x1018:04) the node reports after a reboot
``error_frames_at_s``      list of simulated times: an error frame is put on the bus
``twin_serial``            a second unit with this serial answers as the same node-id (its
                           own ``LocalNode`` on the node's network, booted with it, nominal
                           truth otherwise); read when the node is made, not by ``set``
=========================  ===================================================================

Control API: ``node.faults.set(**keys)`` merges keys (same schema and checks), ``clear()``
removes every fault, ``stats`` counts what was injected. Client-side bus faults (a bus that
raises on send) are modelled by :class:`tests.support.buses.FaultyBus`.
"""

from __future__ import annotations

import logging
import threading
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from canimucal.simnode.fault_config import (
    DEFAULT_ABORT_CODE,
    AbortRule,
    Emergency,
    FaultConfig,
    parse_faults,
)

__all__ = [
    "AbortRule",
    "Emergency",
    "FaultConfig",
    "FaultInjector",
    "FaultStats",
    "emcy_frame",
    "parse_faults",
]

log = logging.getLogger(__name__)

EMCY_BASE = 0x80
REQUEST_UPLOAD, REQUEST_DOWNLOAD, CLIENT_ABORT = 0x40, 0x20, 0x80


@dataclass
class FaultStats:
    """What the injector did so far (the soak and the tests compare the client's counts)."""

    tpdo_frames: int = 0
    dropped: dict[int, int] = field(default_factory=dict)
    duplicated: dict[int, int] = field(default_factory=dict)
    delayed: dict[int, int] = field(default_factory=dict)
    truncated: dict[int, int] = field(default_factory=dict)
    sdo_requests: int = 0
    sdo_aborted: int = 0
    sdo_ignored: int = 0
    reboots: int = 0
    emergencies: int = 0
    error_frames: int = 0

    def count(self, what: str, *cob_ids: int) -> int:
        """Frames ``dropped``/``duplicated``/``delayed``/``truncated`` with these COB-IDs."""
        table: dict[int, int] = getattr(self, what)
        return sum(table.get(cob, 0) for cob in cob_ids)


def _bump(table: dict[int, int], cob_id: int) -> None:
    table[cob_id] = table.get(cob_id, 0) + 1


class FaultInjector:
    """Applies a :class:`FaultConfig` to the node's traffic; thread-safe.

    The node calls :meth:`filter_tpdo` for each TPDO frame, :meth:`on_sdo_request` for each
    SDO request and :meth:`due` with the simulated time; tests call :meth:`set`/:meth:`clear`.
    """

    def __init__(self, doc: Any = None) -> None:
        self._lock = threading.Lock()
        self._doc: dict[str, Any] = {}
        self.config = FaultConfig()
        self.stats = FaultStats()
        self._rng = np.random.default_rng(0)
        self._burst_left = 0
        self._held: list[tuple[int, int, bytes]] = []  # (release after n frames, cob, data)
        self._writes: dict[tuple[int, int], int] = {}
        self._accesses: dict[int, int] = {}
        self._fired: set[str] = set()
        self.rebooted = False
        parse_faults(doc)  # a non-object block is refused here, not silently emptied
        self.set(**dict(doc or {}))

    # -- control API -----------------------------------------------------------------------

    def set(self, **keys: Any) -> FaultConfig:
        """Merge ``keys`` into the active faults (schema of the module table); return them."""
        doc = {**self._doc, **keys}
        config = parse_faults(doc)
        with self._lock:
            reseed = "seed" in keys or not self._doc
            self._doc, self.config = doc, config
            if reseed:
                self._rng = np.random.default_rng(config.seed)
            self._fired.clear()
            self._accesses.clear()
            self._writes.clear()
            self.stats.sdo_requests = 0
        log.info("faults set: %s", ", ".join(sorted(keys)) or "none")
        return config

    def clear(self) -> None:
        """Remove every fault (held frames are released on the next TPDO)."""
        with self._lock:
            self._doc, self.config = {}, FaultConfig()
            self._burst_left = 0
            self._writes.clear()
            self._accesses.clear()
            self._fired.clear()
        log.info("faults cleared")

    # -- TPDOs -----------------------------------------------------------------------------

    def filter_tpdo(self, cob_id: int, data: bytes) -> list[tuple[int, bytes]]:
        """Frames to send instead of ``(cob_id, data)`` (none, one, two, or held ones)."""
        with self._lock:
            cfg = self.config
            self.stats.tpdo_frames += 1
            out = self._release_held()
            if not cfg.touches_tpdos:
                return out + [(cob_id, data)]
            if self._dropped(cfg):
                _bump(self.stats.dropped, cob_id)
                return out
            draw = self._rng.random(3)
            if draw[0] < cfg.wrong_length_fraction:
                _bump(self.stats.truncated, cob_id)
                data = data[:-1]
            if draw[1] < cfg.delay_fraction:
                _bump(self.stats.delayed, cob_id)
                self._held.append((cfg.delay_frames, cob_id, data))
                return out
            frames = out + [(cob_id, data)]
            if draw[2] < cfg.duplicate_fraction:
                _bump(self.stats.duplicated, cob_id)
                frames.append((cob_id, data))
            return frames

    def _dropped(self, cfg: FaultConfig) -> bool:
        if self._burst_left > 0:
            self._burst_left -= 1
            return True
        if cfg.burst_probability and self._rng.random() < cfg.burst_probability:
            self._burst_left = cfg.burst_frames - 1
            return True
        return bool(cfg.tpdo_drop_fraction) and self._rng.random() < cfg.tpdo_drop_fraction

    def _release_held(self) -> list[tuple[int, bytes]]:
        if not self._held:
            return []
        out, keep = [], []
        for left, cob, data in self._held:
            if left <= 1:
                out.append((cob, data))
            else:
                keep.append((left - 1, cob, data))
        self._held = keep
        return out

    # -- SDO -------------------------------------------------------------------------------

    def on_sdo_request(self, data: bytes) -> str:
        """Decide the fate of one SDO request.

        Returns ``"serve"``, ``"ignore"`` (silent: drop the request), ``"mute"`` (process,
        drop the answer), ``"reboot"``, ``"reboot+serve"`` or ``"abort:<code>"``.
        """
        if data[:1] and data[0] & 0xE0 == CLIENT_ABORT:
            return "serve"  # the client giving up a transfer: no answer expected, not counted
        with self._lock:
            cfg = self.config
            self.stats.sdo_requests += 1
            n = self.stats.sdo_requests
            if cfg.reboot_at_sdo_request == n:
                self.stats.reboots += 1
                return "reboot"
            if cfg.reboot_before_sdo_request == n:
                self.stats.reboots += 1
                return "reboot+serve"
            if cfg.sdo_silent_after is not None and n > cfg.sdo_silent_after:
                self.stats.sdo_ignored += 1
                return "ignore" if cfg.sdo_silent_mode == "request" else "mute"
            code = DEFAULT_ABORT_CODE if cfg.abort_at_sdo_request == n else None
            code = self._abort_code(cfg, data) if code is None else code
            if code is not None:
                self.stats.sdo_aborted += 1
                return f"abort:{code}"
            return "serve"

    def _abort_code(self, cfg: FaultConfig, data: bytes) -> int | None:
        if len(data) < 4 or not cfg.sdo_aborts:
            return None
        ccs = data[0] & 0xE0
        if ccs not in (REQUEST_UPLOAD, REQUEST_DOWNLOAD):
            return None
        key = (int.from_bytes(data[1:3], "little"), data[3])
        is_write = ccs == REQUEST_DOWNLOAD
        for i, rule in enumerate(cfg.sdo_aborts):
            if (rule.index, rule.sub) != key or rule.access == ("read" if is_write else "write"):
                continue
            if is_write and self._writes.get(key, 0) < rule.after_writes:
                continue
            self._accesses[i] = self._accesses.get(i, 0) + 1
            if rule.at_access is None or rule.at_access == self._accesses[i]:
                return rule.code
        if is_write:
            self._writes[key] = self._writes.get(key, 0) + 1
        return None

    # -- timed events ----------------------------------------------------------------------

    def due(self, t_s: float) -> list[tuple[str, Any]]:
        """Events due at simulated time ``t_s``, each returned once (``set`` re-arms them)."""
        cfg, events = self.config, []
        with self._lock:
            if cfg.reboot_at_s is not None and t_s >= cfg.reboot_at_s:
                events += self._once("reboot", ("reboot", None))
            for i, emcy in enumerate(cfg.emergency):
                if t_s >= emcy.at_s:
                    events += self._once(f"emcy{i}", ("emergency", emcy))
            for i, at_s in enumerate(cfg.error_frames_at_s):
                if t_s >= at_s:
                    events += self._once(f"errf{i}", ("error_frame", None))
            if cfg.heartbeat_loss is not None:
                start, end = cfg.heartbeat_loss
                if t_s >= start:
                    events += self._once("hb_off", ("heartbeat", False))
                if t_s >= end:
                    events += self._once("hb_on", ("heartbeat", True))
        return events

    def _once(self, name: str, event: tuple[str, Any]) -> list[tuple[str, Any]]:
        if name in self._fired:
            return []
        self._fired.add(name)
        return [event]

    def serial_override(self) -> int | None:
        """Return the serial to report now (after a reboot with ``serial_after_reboot``) or None."""
        return self.config.serial_after_reboot if self.rebooted else None


def emcy_frame(code: int, register: int) -> bytes:
    """CiA 301 EMCY payload: error code (LE16), error register, 5 manufacturer bytes."""
    return code.to_bytes(2, "little") + bytes([register & 0xFF]) + bytes(5)
