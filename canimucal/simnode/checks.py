"""Write checks of the simulated node: what its firmware refuses with an SDO abort.

canopen's ``LocalNode`` runs write callbacks *before* it stores a value, so raising
:class:`canopen.SdoAbortedError` here leaves the object unchanged. ``LocalNode`` itself
already refuses writes to read-only objects (0x06010002) and wrong lengths (0x06070010).
"""

from __future__ import annotations

import logging
import struct
from collections.abc import Callable

from canopen import LocalNode, SdoAbortedError
from canopen.objectdictionary import ODArray, ODRecord, ODVariable

from canimucal.device import od

log = logging.getLogger(__name__)

ABORT_MAPPING = 0x06040041  # object cannot be mapped to the PDO
ABORT_PDO_LENGTH = 0x06040042  # number and length of mapped objects exceed the PDO

ReadRaw = Callable[[int, int], bytes]


def check_subindex_exists(node: LocalNode, index: int, sub: int) -> None:
    """Refuse sub-indices the EDS does not define (canopen answers any ARRAY sub 1–255)."""
    if index not in node.object_dictionary:
        raise SdoAbortedError(od.ABORT_NO_OBJECT)
    entry = node.object_dictionary[index]
    if isinstance(entry, ODArray | ODRecord) and sub not in entry.subindices:
        raise SdoAbortedError(od.ABORT_NO_SUBINDEX)
    if isinstance(entry, ODVariable) and sub != 0:
        raise SdoAbortedError(od.ABORT_NO_SUBINDEX)


def check_write(
    node: LocalNode,
    index: int,
    sub: int,
    data: bytes,
    read_raw: ReadRaw,
    accel_lsb: float,
    gyro_lsb: float,
) -> None:
    """Raise ``SdoAbortedError`` if writing ``data`` to ``index:sub`` must be refused.

    ``read_raw(index, sub)`` returns the object's current raw bytes (used for the row
    diagonal of an off-diagonal M/N entry and for PDO mapping checks).
    """
    check_subindex_exists(node, index, sub)
    _check_range(index, sub, data, read_raw, accel_lsb, gyro_lsb)
    if index == od.STORE and struct.unpack("<I", data)[0] != od.SAVE_SIGNATURE:
        raise SdoAbortedError(od.ABORT_CANNOT_STORE)
    elif index == od.RESTORE and struct.unpack("<I", data)[0] != od.LOAD_SIGNATURE:
        raise SdoAbortedError(od.ABORT_CANNOT_STORE)
    elif index in od.TPDO_COMM:
        _check_tpdo_comm(sub, data)
    elif index in od.TPDO_MAP:
        _check_tpdo_map(node, index, sub, data, read_raw)


def _refuse_if(problem: str | None) -> None:
    if problem is not None:
        log.info("write refused: %s", problem)
        raise SdoAbortedError(od.ABORT_VALUE_RANGE)


def _check_range(
    index: int, sub: int, data: bytes, read_raw: ReadRaw, accel_lsb: float, gyro_lsb: float
) -> None:
    """Refuse a value outside the object's rule in the object table (every object has one)."""
    obj = od.object_at(index, sub)
    if obj is None or obj.data_type == "vstr":  # sub 0 of an ARRAY or RECORD, or text
        return
    value = od.decode(obj.data_type, data)
    diagonal_key = od.row_diagonal_key(obj)
    row_diagonal = None if diagonal_key is None else od.decode("f32", read_raw(*diagonal_key))
    _refuse_if(od.range_problems(index, sub, value, accel_lsb, gyro_lsb, row_diagonal))


def _check_tpdo_comm(sub: int, data: bytes) -> None:
    if sub == 1 and struct.unpack("<I", data)[0] & 0x1FFFF800 and not data[3] & 0x20:
        # an 11-bit COB-ID must fit 0x001–0x7FF unless the 29-bit frame bit is set
        raise SdoAbortedError(od.ABORT_VALUE_RANGE)


def _check_tpdo_map(node: LocalNode, index: int, sub: int, data: bytes, read_raw: ReadRaw) -> None:
    if sub == 0:
        count = data[0]
        if count > 8:
            raise SdoAbortedError(od.ABORT_VALUE_RANGE)
        entries = [struct.unpack("<I", read_raw(index, k))[0] for k in range(1, count + 1)]
        if sum(entry & 0xFF for entry in entries) > 64:
            raise SdoAbortedError(ABORT_PDO_LENGTH)
        for entry in entries:
            _check_mappable(node, entry)
        return
    entry = struct.unpack("<I", data)[0]
    if entry:
        _check_mappable(node, entry)


def _check_mappable(node: LocalNode, entry: int) -> None:
    index, sub, bits = entry >> 16, (entry >> 8) & 0xFF, entry & 0xFF
    try:
        check_subindex_exists(node, index, sub)
    except SdoAbortedError:
        raise SdoAbortedError(ABORT_MAPPING) from None
    entry_od = node.object_dictionary[index]
    var = entry_od if isinstance(entry_od, ODVariable) else entry_od[sub]
    if not var.pdo_mappable or len(var) != bits:
        raise SdoAbortedError(ABORT_MAPPING)
