"""PDO mappings as the client reads them from the node (0x1A00–0x1A02) and fast decoders.

The client never assumes the EDS default: a device that orders the objects differently or
maps them with other widths streams too, as long as each TPDO fits one classic CAN frame
(8 bytes). INT32 raw values do not fit: x/y/z plus the counter would take 14 bytes, so such a
mapping is refused with a clear error. :func:`read_layout` builds the layout from the
communication and mapping objects however they are read (SDO uploads from the node, the
uploads a bus log holds, a ``read-params --json`` document); :func:`default_layout` is the
EDS default of a node id, what a bus log without any of these is decoded with.
"""

from __future__ import annotations

import struct
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

from canimucal.device.objects import (
    ACCEL_RAW,
    GYRO_RAW,
    OBJECTS,
    SAMPLE_INFO,
    TPDO_COMM,
    TPDO_MAP,
    object_at,
)
from canimucal.model.vocabulary.constants import COUNTER_BITS

SIGNED_OBJECTS = frozenset(o.key for o in OBJECTS if o.data_type == "i16")
"""The raw outputs and the temperature are INTEGER16 (the object table's)."""
TEMP_SCALE_C = 0.01
"""0x2002:01 is in 0.01 °C."""

CLASSIC_CAN_BITS = 64
"""Most data bits one classic CAN frame carries (8 bytes)."""


@dataclass(frozen=True)
class MappedField:
    """One mapped object of a PDO: where it sits in the frame and how to read it."""

    index: int
    sub: int
    bits: int
    offset_bits: int
    signed: bool

    @classmethod
    def from_entry(cls, entry: int, offset_bits: int) -> MappedField:
        """Decode a CiA 301 mapping entry ``index << 16 | sub << 8 | bit length``."""
        index, sub, bits = entry >> 16, (entry >> 8) & 0xFF, entry & 0xFF
        return cls(index, sub, bits, offset_bits, (index, sub) in SIGNED_OBJECTS)


@dataclass(frozen=True)
class PdoLayout:
    """The mapping of one TPDO: its COB-ID and fields, with a fast decoder."""

    cob_id: int
    fields: tuple[MappedField, ...]
    _struct: struct.Struct | None = field(default=None, compare=False, repr=False)

    @classmethod
    def from_entries(cls, cob_id: int, entries: Sequence[int]) -> PdoLayout:
        """Build from the raw 0x1A0x sub-index values (sub 1..n).

        A mapping longer than one classic CAN frame (64 bits) is refused (``ValueError``):
        x/y/z as INT32 plus the counter would need 14 bytes.
        """
        fields, offset = [], 0
        for entry in entries:
            mapped = MappedField.from_entry(entry, offset)
            fields.append(mapped)
            offset += mapped.bits
        if offset > CLASSIC_CAN_BITS:
            raise ValueError(
                f"PDO 0x{cob_id:X} maps {offset} bits ({(offset + 7) // 8} bytes); a classic "
                "CAN frame holds 8 bytes (map x/y/z as INT16 with the counter)"
            )
        return cls(cob_id, tuple(fields), _compile(fields))

    @property
    def size_bytes(self) -> int:
        """Bytes the mapped objects occupy."""
        return (sum(f.bits for f in self.fields) + 7) // 8

    def position(self, index: int, sub: int) -> int | None:
        """Position of object ``index:sub`` among the decoded values, or None."""
        for i, mapped in enumerate(self.fields):
            if (mapped.index, mapped.sub) == (index, sub):
                return i
        return None

    def decode(self, data: bytes) -> tuple[int, ...]:
        """Values of the mapped objects, in mapping order (``struct.error`` on a wrong length)."""
        if len(data) != self.size_bytes:
            raise struct.error(f"{len(data)} bytes, mapping needs {self.size_bytes}")
        if self._struct is not None:
            return self._struct.unpack_from(data)
        raw = int.from_bytes(data, "little")
        values = []
        for f in self.fields:
            value = (raw >> f.offset_bits) & ((1 << f.bits) - 1)
            if f.signed and value >> (f.bits - 1):
                value -= 1 << f.bits
            values.append(value)
        return tuple(values)


_STRUCT_CODES = {(8, False): "B", (8, True): "b", (16, False): "H", (16, True): "h"}
_STRUCT_CODES |= {(32, False): "I", (32, True): "i"}


def _compile(fields: Sequence[MappedField]) -> struct.Struct | None:
    """Return a ``struct`` format when every field is a whole 8/16/32-bit integer, else None."""
    codes = [_STRUCT_CODES.get((f.bits, f.signed)) for f in fields]
    if any(code is None for code in codes):
        return None
    return struct.Struct("<" + "".join(code for code in codes if code))


@dataclass(frozen=True)
class SampleLayout:
    """Where accel, gyro, counter and temperature sit in TPDO1/2/3 (read from the node)."""

    accel: PdoLayout
    gyro: PdoLayout
    info: PdoLayout | None

    def __post_init__(self) -> None:
        """Check that the mapping can be decoded and the halves carry what pairing needs.

        Refused (``ValueError``): a 0-bit entry, a TPDO longer than a CAN frame's 8 bytes,
        two TPDOs on one COB-ID, a counter 0x2002:02 not mapped with 16 bits (pairing and
        loss counting wrap it at 65536), and a half without x, y, z or the counter.
        """
        layouts = [(n, layout) for n, layout in ((1, self.accel), (2, self.gyro), (3, self.info))]
        seen: dict[int, int] = {}
        for number, layout in layouts:
            if layout is None:
                continue
            for f in layout.fields:
                if f.bits == 0:
                    raise ValueError(f"TPDO{number} maps 0x{f.index:04X}:{f.sub:02X} with 0 bits")
            if layout.size_bytes > 8:
                raise ValueError(
                    f"TPDO{number} maps {layout.size_bytes} bytes; a CAN frame holds 8"
                )
            if layout.cob_id in seen:
                raise ValueError(
                    f"TPDO{number} has TPDO{seen[layout.cob_id]}'s COB-ID 0x{layout.cob_id:X}"
                )
            seen[layout.cob_id] = number
            for f in layout.fields:
                if (f.index, f.sub) == (SAMPLE_INFO, 2) and f.bits != COUNTER_BITS:
                    raise ValueError(
                        f"TPDO{number} maps the counter 0x2002:02 with {f.bits} bits; "
                        f"it needs {COUNTER_BITS}"
                    )
        needed = [(self.accel, ACCEL_RAW), (self.gyro, GYRO_RAW)]
        for layout, index in needed:
            for sub in (1, 2, 3):
                if layout.position(index, sub) is None:
                    raise ValueError(
                        f"TPDO 0x{layout.cob_id:X} does not map 0x{index:04X}:{sub:02d}"
                    )
            if layout.position(SAMPLE_INFO, 2) is None:
                raise ValueError(f"TPDO 0x{layout.cob_id:X} does not map the counter 0x2002:02")

    def picks(self, layout: PdoLayout, index: int) -> tuple[int, int, int, int]:
        """Positions of x, y, z of ``index`` and of the counter in ``layout``'s values."""
        pos = [layout.position(index, sub) for sub in (1, 2, 3)]
        pos.append(layout.position(SAMPLE_INFO, 2))
        return (pos[0] or 0, pos[1] or 0, pos[2] or 0, pos[3] or 0)


def layout_from_mapping(
    cob_ids: Mapping[int, int], entries: Mapping[int, Sequence[int]]
) -> SampleLayout:
    """Sample layout from TPDO number → COB-ID and TPDO number → mapping entries (1, 2, 3)."""
    info = PdoLayout.from_entries(cob_ids[3], entries[3]) if 3 in entries else None
    return SampleLayout(
        PdoLayout.from_entries(cob_ids[1], entries[1]),
        PdoLayout.from_entries(cob_ids[2], entries[2]),
        info,
    )


def mapping_entry(index: int, sub: int, bits: int) -> int:
    """Return the CiA 301 mapping entry ``index << 16 | sub << 8 | bit length``."""
    return (index << 16) | (sub << 8) | bits


ObjectReader = Callable[[int, int], int]
"""Reads one unsigned object ``(index, sub)`` of the node: an SDO upload, a log, a document."""

COB_ID_INVALID = 0x8000_0000
"""Bit 31 of a TPDO COB-ID (0x180x:01): the PDO does not exist (CiA 301)."""
COB_ID_EXTENDED = 0x2000_0000
"""Bit 29 of a TPDO COB-ID: a 29-bit identifier."""


RESTRICTED_COB_IDS = (
    (0x000, 0x000, "NMT"),
    (0x001, 0x07F, "reserved"),
    (0x101, 0x180, "reserved (TIME and below TPDO1's range)"),
    (0x581, 0x5FF, "SDO answers"),
    (0x601, 0x67F, "SDO requests"),
    (0x6E0, 0x6FF, "reserved"),
    (0x701, 0x77F, "heartbeats and boot-ups"),
    (0x780, 0x7FF, "reserved"),
)
"""CAN-IDs CiA 301 (§7.3.5) does not allow for a PDO: a TPDO there would be taken for an SDO
answer, a heartbeat or an NMT command by every other device and tool on the bus."""


def read_layout(read: ObjectReader) -> SampleLayout:
    """Build the sample layout from TPDO1–3's COB-IDs (0x1800–0x1802:01) and mappings.

    ``read(index, sub)`` returns an object's value; a TPDO whose COB-ID has the invalid bit
    set or that maps nothing is left out. ``ValueError`` when TPDO1 or TPDO2 is not there,
    an 11-bit COB-ID is one CiA 301 reserves (:data:`RESTRICTED_COB_IDS`), or the mapping
    cannot be decoded (:class:`SampleLayout`).
    """
    cob_ids: dict[int, int] = {}
    entries: dict[int, list[int]] = {}
    for number, (comm, mapping) in enumerate(zip(TPDO_COMM, TPDO_MAP, strict=True), start=1):
        cob = read(comm, 1)
        count = read(mapping, 0)
        if cob & COB_ID_INVALID or count == 0:
            continue
        cob_ids[number] = cob & (0x1FFF_FFFF if cob & COB_ID_EXTENDED else 0x7FF)
        if not cob & COB_ID_EXTENDED:
            _refuse_restricted(number, cob_ids[number])
        entries[number] = [read(mapping, sub) for sub in range(1, count + 1)]
    if 1 not in entries or 2 not in entries:
        raise ValueError("TPDO1 and TPDO2 must be valid and mapped to stream samples")
    return layout_from_mapping(cob_ids, entries)


def _refuse_restricted(number: int, cob_id: int) -> None:
    """ValueError when TPDO ``number`` sits on a CAN-ID CiA 301 reserves (11-bit IDs)."""
    for low, high, what in RESTRICTED_COB_IDS:
        if low <= cob_id <= high:
            raise ValueError(
                f"TPDO{number} has COB-ID 0x{cob_id:03X}, which CiA 301 reserves ({what}, "
                f"0x{low:03X}-0x{high:03X}): check 0x{0x1800 + number - 1:04X}:01"
            )


def default_value(index: int, sub: int, node_id: int) -> int:
    """Return the EDS default of an unsigned object of the object table, ``$NODEID`` resolved.

    ``KeyError`` for an object the table does not hold or whose default is not an integer.
    """
    obj = object_at(index, sub)
    default = obj.default if obj is not None else None
    if isinstance(default, str) and default.startswith("$NODEID+"):
        return node_id + int(default.removeprefix("$NODEID+"), 0)
    if isinstance(default, int) and not isinstance(default, bool):
        return default
    raise KeyError(f"0x{index:04X}:{sub:02X} has no integer EDS default")


def default_layout(node_id: int) -> SampleLayout:
    """Return node ``node_id``'s EDS default layout (TPDOs at 0x180/0x280/0x380 + id)."""
    return read_layout(lambda index, sub: default_value(index, sub, node_id))
