"""Non-volatile memory of the simulated node: what 0x1010 stores and 0x1011 restores.

CiA 301 groups: sub 1 all parameters, sub 2 communication (0x1000–0x1FFF), sub 3
application (0x2010:03, the output data rate), sub 4 calibration (0x2100–0x2122). Values are
kept as the raw little-endian bytes the object dictionary holds, so a reload is bit-exact.
With a ``state_file`` the memory is a JSON file (written atomically) and survives a new
instance; without one it lives as long as the :class:`NonVolatileStore` object.
"""

from __future__ import annotations

import json
import logging
import os
import threading
from collections.abc import Iterable, Mapping
from pathlib import Path

from canimucal.device import od
from canimucal.errors import InputError
from canimucal.schema import parse_json, read_text
from canimucal.sim.truth import Truth

log = logging.getLogger(__name__)

STATE_SCHEMA = "canimucal.simnode-state/1"

COMM_PARAMETERS = (od.HEARTBEAT, *od.TPDO_COMM, *od.TPDO_MAP)
"""Indices of the communication parameters that 0x1010:02 stores."""

APP_PARAMETERS = ((od.NOMINAL, 3),)
"""Application parameters 0x1010:03 stores (besides the calibration block)."""

Key = tuple[int, int]


def factory_values(truth: Truth, comm_odr_hz: int | None = None) -> dict[Key, bytes]:
    """Raw values that differ from the EDS defaults for this unit (its truth).

    The nominal LSBs, output data rate, factory calibration (with its CRC, valid = 0),
    serial number, TPDO1/2 event timers (1000/ODR ms), the truth's heartbeat and, with
    ``sync_pdos``, transmission type 1 for TPDO1–3. With ``comm_odr_hz`` only the
    communication objects, for that output data rate (NMT reset communication).
    """
    odr = int(truth.sample_rate_hz) if comm_odr_hz is None else int(comm_odr_hz)
    values: dict[Key, bytes] = {
        (od.TPDO_COMM[0], 5): od.encode("u16", 1000 // odr),
        (od.TPDO_COMM[1], 5): od.encode("u16", 1000 // odr),
        (od.IDENTITY, 4): od.encode("u32", truth.serial & 0xFFFFFFFF),
        (od.DEVICE_NAME, 0): truth.device_name.encode("utf-8", "surrogateescape"),
        (od.HARDWARE_VERSION, 0): truth.hardware_version.encode("utf-8", "surrogateescape"),
        (od.SOFTWARE_VERSION, 0): truth.software_version.encode("utf-8", "surrogateescape"),
    }
    if truth.heartbeat_ms is not None:
        values[(od.HEARTBEAT, 0)] = od.encode("u16", truth.heartbeat_ms)
    if truth.sync_pdos:  # TPDO1–3 on every SYNC (transmission type 1), not their timers
        for comm in od.TPDO_COMM:
            values[(comm, 2)] = od.encode("u8", 1)
    if comm_odr_hz is not None:
        return values
    accel_lsb, gyro_lsb = truth.accel.nominal_lsb, truth.gyro.nominal_lsb
    values[(od.NOMINAL, 1)] = od.encode("f32", accel_lsb)
    values[(od.NOMINAL, 2)] = od.encode("f32", gyro_lsb)
    values[(od.NOMINAL, 3)] = od.encode("u16", odr)
    factory = od.factory_block(accel_lsb, gyro_lsb, truth.trim_object).to_objects()
    for index, sub, code in od.crc_order(truth.trim_object):
        values[(index, sub)] = od.encode(code, factory[(index, sub)])
    values[(od.CAL_INFO, od.CAL_VALID_SUB)] = od.encode("u8", 0)
    values[(od.CAL_INFO, od.CAL_CRC_SUB)] = od.encode("u32", od.block_crc(factory))
    return values


def group_of(key: Key, calibration_sub: int = od.STORE_CALIBRATION_SUB) -> int | None:
    """Store group (0x1010 sub-index) an object belongs to, None if not stored.

    Communication parameters 2, application parameters 3, the calibration ``calibration_sub``
    (4 unless the truth's ``calibration_store_sub`` says otherwise).
    """
    index = key[0]
    if index in COMM_PARAMETERS:
        return od.STORE_COMM_SUB
    if key in APP_PARAMETERS:
        return od.STORE_APP_SUB
    if key in od.OBJECT_CODES:
        return calibration_sub
    return None


def in_group(key: Key, store_sub: int, calibration_sub: int = od.STORE_CALIBRATION_SUB) -> bool:
    """Whether 0x1010/0x1011 sub-index ``store_sub`` covers object ``key`` (sub 1 = all)."""
    group = group_of(key, calibration_sub)
    return group is not None and store_sub in (od.STORE_ALL_SUB, group)


class NonVolatileStore:
    """Stored object values, optionally persisted to a JSON ``state_file``."""

    def __init__(
        self, state_file: Path | None = None, calibration_sub: int = od.STORE_CALIBRATION_SUB
    ) -> None:
        self.state_file = None if state_file is None else Path(state_file)
        self.calibration_sub = calibration_sub
        """The 0x1010 sub-index whose 'save' covers the calibration group."""
        self._lock = threading.Lock()
        self._values: dict[Key, bytes] = {}
        self.log: list[int] = []
        """0x1010 sub-index of every store since this object was made."""
        if self.state_file is not None and self.state_file.exists():
            self._values = _read_state(self.state_file)
            log.info("loaded %d stored objects from %s", len(self._values), self.state_file)

    def values(self) -> dict[Key, bytes]:
        """Return a copy of every stored ``(index, sub) -> raw bytes``."""
        with self._lock:
            return dict(self._values)

    def store(self, objects: Mapping[Key, bytes], store_sub: int) -> None:
        """Persist the objects of group ``store_sub`` among ``objects`` (0x1010 'save')."""
        chosen = {
            k: bytes(v) for k, v in objects.items() if in_group(k, store_sub, self.calibration_sub)
        }
        with self._lock:
            self._values.update(chosen)
            self._flush()
            self.log.append(store_sub)
        log.info("stored %d objects (0x1010:%02X)", len(chosen), store_sub)

    def forget(self, store_sub: int) -> None:
        """Drop the stored objects of a group: defaults apply at the next reset (0x1011)."""
        with self._lock:
            dropped = [k for k in self._values if in_group(k, store_sub, self.calibration_sub)]
            for key in dropped:
                del self._values[key]
            self._flush()
        log.info("defaults for %d objects at next reset (0x1011:%02X)", len(dropped), store_sub)

    def _flush(self) -> None:
        if self.state_file is None:
            return
        _write_state(self.state_file, self._values.items())


def _read_state(path: Path) -> dict[Key, bytes]:
    try:
        doc = parse_json(read_text(path), f"simulated node state {path}")
        if doc.get("schema") != STATE_SCHEMA:
            raise InputError(f"{path}: schema must be {STATE_SCHEMA!r}")
        return {od.parse_key(k): bytes.fromhex(v) for k, v in doc["objects"].items()}
    except (OSError, ValueError, KeyError, AttributeError, TypeError) as exc:
        raise InputError(f"cannot read simulated node state {path}: {exc}") from exc


def _write_state(path: Path, items: Iterable[tuple[Key, bytes]]) -> None:
    objects = {od.format_key(*k): v.hex() for k, v in sorted(items)}
    doc = {"schema": STATE_SCHEMA, "objects": objects}
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(doc, indent=1) + "\n", encoding="utf-8")
    os.replace(tmp, path)
