"""What the simulated node does when its object dictionary is read or written over SDO.

Live values for reads of 0x2000–0x2002 and 0x1001, range checks before a write is stored, and
the side effects after it: storing on 0x1010, restoring defaults on 0x1011, a new output data
rate, dropped caches of the TPDO layout and the calibration state. One collaborator owned by
:class:`~canimucal.simnode.node.SimulatedImuNode`.
"""

from __future__ import annotations

import logging
import struct
import threading
import time
from collections.abc import Callable
from contextlib import AbstractContextManager, nullcontext
from typing import Any

import canopen
from canopen.objectdictionary import ODVariable
from canopen.objectdictionary.datatypes import SIGNED_TYPES
from canopen.sdo.exceptions import SdoAbortedError

from canimucal.device import od
from canimucal.sim.truth import Truth
from canimucal.simnode.checks import check_subindex_exists, check_write
from canimucal.simnode.pdo import TpdoLayout, read_layout
from canimucal.simnode.store import NonVolatileStore, group_of

log = logging.getLogger(__name__)

_LIVE_INDICES = (od.ACCEL_RAW, od.GYRO_RAW, od.SAMPLE_INFO, od.ERROR_REGISTER)

Key = tuple[int, int]


class ObjectAccess:
    """The node's SDO read/write callbacks, what an accepted write changes, and two caches.

    Owns the cached TPDO layouts and the cached "calibration active" state and drops them
    when a write touches what they are built from. ``live()`` returns the producer's live
    values; ``set_rate(hz)`` tells the producer a new output data rate; a slow store runs
    inside ``store_blocking()`` (what the TPDOs do meanwhile).
    """

    def __init__(
        self,
        local_node: canopen.LocalNode,
        truth: Truth,
        lock: threading.RLock,
        store: NonVolatileStore,
        *,
        live: Callable[[], dict[Key, int]],
        set_rate: Callable[[int], None],
        store_blocking: Callable[[], AbstractContextManager[None]] = nullcontext,
    ) -> None:
        self._node = local_node
        self._truth = truth
        self._lock = lock
        self._store = store
        self._live = live
        self._set_rate = set_rate
        self._store_blocking = store_blocking
        self._layout_cache: tuple[TpdoLayout, ...] | None = None
        self._cal_cache: bool | None = None

    def value(self, index: int, sub: int = 0) -> Any:
        """Return the current decoded value of an object, as an SDO read would."""
        entry = self._node.object_dictionary[index]
        var = entry if isinstance(entry, ODVariable) else entry[sub]
        return var.decode_raw(self._node.get_data(index, sub))

    def calibration_values(self) -> dict[Key, float | int]:
        """Return the CRC-covered calibration objects, decoded, in docs/design.md §4 order.

        A node without the mounting-trim object (truth ``trim_object`` false) has the
        39-object layout.
        """
        order = od.crc_order(self._truth.trim_object)
        return {(i, s): self.value(i, s) for i, s, _ in order}

    def calibration_active(self) -> bool:
        """Whether valid = 1 and the stored CRC matches (cached until a calibration write)."""
        with self._lock:
            if self._cal_cache is None:
                values = self.calibration_values()
                valid = self.value(od.CAL_INFO, od.CAL_VALID_SUB) == 1
                crc = self.value(od.CAL_INFO, od.CAL_CRC_SUB)
                self._cal_cache = valid and crc == od.block_crc(values)
            return self._cal_cache

    def invalidate(self) -> None:
        """Drop both caches (after a reload of the object dictionary)."""
        with self._lock:
            self._layout_cache = None
            self._cal_cache = None

    def _check_storage_sub(self, index: int, subindex: int) -> None:
        """0x1010/0x1011 sub-indices the truth leaves out answer "sub-index does not exist"."""
        if index in (od.STORE, od.RESTORE) and subindex >= 1:
            if subindex not in self._truth.storage_subs:
                raise SdoAbortedError(od.ABORT_NO_SUBINDEX)

    def on_read(self, index: int, subindex: int, **_: Any) -> int | None:
        """``LocalNode`` read callback: live values, and 1 for 0x1010/0x1011 (on command)."""
        check_subindex_exists(self._node, index, subindex)
        self._check_storage_sub(index, subindex)
        if index in _LIVE_INDICES:
            with self._lock:
                return self._live().get((index, subindex), None)
        if index in (od.STORE, od.RESTORE) and subindex >= 1:
            return 1  # CiA 301: the device saves / restores on command
        if index == od.CALIBRATION_STORE_SUB:  # what the node says stores its calibration
            if self._truth.documented_store_sub is None:
                raise SdoAbortedError(od.ABORT_NO_OBJECT)  # firmware before issue 24
            return self._truth.documented_store_sub
        return None

    def on_write(self, index: int, subindex: int, data: bytes, **_: Any) -> None:
        """Refuse a write before ``LocalNode`` stores it (raising ``SdoAbortedError``)."""
        self._check_storage_sub(index, subindex)
        check_write(
            self._node,
            index,
            subindex,
            bytes(data),
            self._node.get_data,
            self._truth.accel.nominal_lsb,
            self._truth.gyro.nominal_lsb,
        )

    def after_write(self, index: int, subindex: int, data: bytes) -> None:
        """Side effects of a write every callback accepted and ``LocalNode`` stored."""
        with self._lock:
            if group_of((index, subindex)) == od.STORE_CALIBRATION_SUB:
                self._cal_cache = None
            if index in od.TPDO_COMM or index in od.TPDO_MAP:
                self._layout_cache = None
        if index == od.NOMINAL and subindex == 3:
            self._set_odr(struct.unpack("<H", data)[0])
        elif index == od.STORE:
            if self._truth.store_delay_s > 0.0:
                # as CANopenNode: flash is erased inside the SDO handler, the answer waits
                # (this is the network's receive thread: SYNC and NMT wait too; the TPDOs
                # are dropped, queued or go on, as the truth's store_pdo_mode says)
                with self._store_blocking():
                    time.sleep(self._truth.store_delay_s)
                    self._store.store(self.current_raw(), subindex)
            else:
                self._store.store(self.current_raw(), subindex)
        elif index == od.RESTORE:
            self._store.forget(subindex)

    def _set_odr(self, odr_hz: int) -> None:
        """0x2010:03 written: TPDO1/2 event timers become 1000/ODR ms."""
        with self._lock:
            for comm in od.TPDO_COMM[:2]:
                self._node.data_store.setdefault(comm, {})[5] = od.encode("u16", 1000 // odr_hz)
            self._layout_cache = None
        self._set_rate(odr_hz)
        log.info("output data rate set to %d Hz", odr_hz)

    def current_raw(self) -> dict[Key, bytes]:
        """Raw current value of every storable object."""
        out: dict[Key, bytes] = {}
        for index in self._node.object_dictionary:
            entry = self._node.object_dictionary[index]
            subs = [0] if isinstance(entry, ODVariable) else list(entry.subindices)
            for sub in subs:
                if group_of((index, sub)) is not None:
                    out[(index, sub)] = self._node.get_data(index, sub)
        return out

    def layouts(self) -> tuple[TpdoLayout, ...]:
        """TPDO1–3 as currently configured (cached until a 0x18xx/0x1Axx write)."""
        with self._lock:
            if self._layout_cache is None:
                self._layout_cache = tuple(
                    read_layout(n, self._node.get_data, self._is_signed) for n in (1, 2, 3)
                )
            return self._layout_cache

    def _is_signed(self, key: Key) -> bool:
        entry = self._node.object_dictionary[key[0]]
        var = entry if isinstance(entry, ODVariable) else entry[key[1]]
        return var.data_type in SIGNED_TYPES


class ImuLocalNode(canopen.LocalNode):
    """A ``LocalNode`` that reports each stored write (its callbacks run *before* storing)."""

    after_store: Callable[[int, int, bytes], None] | None = None

    def set_data(
        self, index: int, subindex: int, data: bytes, check_writable: bool = False
    ) -> None:
        """Store as ``LocalNode`` does (callbacks may refuse), then run ``after_store``."""
        super().set_data(index, subindex, data, check_writable)
        if self.after_store is not None:
            self.after_store(index, subindex, bytes(data))
