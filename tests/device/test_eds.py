"""The EDS against docs/design.md §4's object table, loaded the way nodes and clients load it."""

from __future__ import annotations

import re

import canopen
import numpy as np
import pytest
from canopen.objectdictionary import ODArray, ODRecord, ODVariable, datatypes

from canimucal.device import od
from canimucal.model.sensor import DEFAULT_ACCEL_LSB, DEFAULT_GYRO_LSB

NODE_ID = 0x10
U8, U16, U32 = datatypes.UNSIGNED8, datatypes.UNSIGNED16, datatypes.UNSIGNED32
I16, R32, VSTR = datatypes.INTEGER16, datatypes.REAL32, datatypes.VISIBLE_STRING

# docs/design.md §4: (index, subs, type, access, PDO mappable)
TABLE = [
    (0x1000, [0], U32, "ro", False),
    (0x1001, [0], U8, "ro", True),
    (0x1005, [0], U32, "rw", False),
    (0x1006, [0], U32, "rw", False),
    (0x1008, [0], VSTR, "const", False),
    (0x1014, [0], U32, "ro", False),
    (0x1010, [1, 2, 3, 4], U32, "rw", False),
    (0x1011, [1, 2, 3, 4], U32, "rw", False),
    (0x1017, [0], U16, "rw", False),
    (0x1018, [1, 2, 3, 4], U32, "ro", False),
    (0x2000, [1, 2, 3], I16, "ro", True),
    (0x2001, [1, 2, 3], I16, "ro", True),
    (0x2002, [1], I16, "ro", True),
    (0x2002, [2], U16, "ro", True),
    (0x2002, [3], U8, "ro", True),
    (0x2010, [1, 2], R32, "ro", False),
    (0x2010, [3], U16, "rw", False),
    (0x2011, [0], U8, "ro", False),
    (0x2100, [1, 2, 3], R32, "rw", False),
    (0x2101, list(range(1, 10)), R32, "rw", False),
    (0x2110, [1, 2, 3], R32, "rw", False),
    (0x2111, list(range(1, 10)), R32, "rw", False),
    (0x2112, list(range(1, 10)), R32, "rw", False),
    (0x2120, [1, 2], R32, "rw", False),
    (0x2121, [1], U32, "rw", False),
    (0x2121, [2], U8, "rw", False),
    (0x2121, [3, 4], R32, "rw", False),
    (0x2121, [5], U8, "rw", False),
    (0x2121, [6], U32, "rw", False),
]


@pytest.fixture(scope="module")
def eds() -> canopen.ObjectDictionary:
    return canopen.import_od(str(od.eds_path()), NODE_ID)


def _var(eds: canopen.ObjectDictionary, index: int, sub: int) -> ODVariable:
    entry = eds[index]
    if isinstance(entry, ODVariable):
        assert sub == 0
        return entry
    assert sub in entry.subindices, f"0x{index:04X}:{sub:02X} not defined"
    return entry[sub]


@pytest.mark.parametrize(("index", "subs", "data_type", "access", "pdo"), TABLE)
def test_object_matches_design_table(
    eds: canopen.ObjectDictionary,
    index: int,
    subs: list[int],
    data_type: int,
    access: str,
    pdo: bool,
) -> None:
    for sub in subs:
        var = _var(eds, index, sub)
        assert var.data_type == data_type, f"0x{index:04X}:{sub:02X}"
        assert var.access_type == access, f"0x{index:04X}:{sub:02X}"
        assert var.pdo_mappable == pdo, f"0x{index:04X}:{sub:02X}"
    entry = eds[index]
    if isinstance(entry, ODArray | ODRecord):
        highest = entry[0]
        assert highest.default == max(entry.subindices)


def test_no_other_manufacturer_objects(eds: canopen.ObjectDictionary) -> None:
    indices = {o.index for o in eds.values() if o.index >= 0x2000}
    assert indices == {row[0] for row in TABLE if row[0] >= 0x2000}


def test_calibration_defaults_are_factory(eds: canopen.ObjectDictionary) -> None:
    factory = od.factory_block(DEFAULT_ACCEL_LSB, DEFAULT_GYRO_LSB).to_objects()
    for (index, sub), value in factory.items():
        assert _var(eds, index, sub).default == value, f"0x{index:04X}:{sub:02X}"
    assert _var(eds, 0x2121, 5).default == 0
    assert eds[0x2010][1].default == float(np.float32(DEFAULT_ACCEL_LSB))
    assert eds[0x2010][2].default == float(np.float32(DEFAULT_GYRO_LSB))
    assert eds[0x2010][3].default == 200


def test_crc_test_vector(eds: canopen.ObjectDictionary) -> None:
    expected = od.block_crc(od.factory_block(DEFAULT_ACCEL_LSB, DEFAULT_GYRO_LSB).to_objects())
    text = od.eds_path().read_text(encoding="utf-8")
    vectors = {int(m, 16) for m in re.findall(r"CRC test vector[^\n]*?(0x[0-9A-Fa-f]{8})", text)}
    assert vectors == {expected}
    assert f"0x{expected:08X}" in eds.comments
    assert eds[0x2121][6].default == expected  # the factory set carries its own CRC


@pytest.mark.parametrize(
    ("number", "cob_base", "timer_ms", "mapping"),
    [
        # TPDO1/2 on data-ready: event timer 0 (a timer beside it sends samples twice)
        (1, 0x180, 0, [0x20000110, 0x20000210, 0x20000310, 0x20020210]),
        (2, 0x280, 0, [0x20010110, 0x20010210, 0x20010310, 0x20020210]),
        (3, 0x380, 100, [0x20020110, 0x20020210, 0x20020308]),
    ],
)
def test_tpdo_configuration(
    eds: canopen.ObjectDictionary, number: int, cob_base: int, timer_ms: int, mapping: list[int]
) -> None:
    comm, mapping_obj = eds[0x1800 + number - 1], eds[0x1A00 + number - 1]
    assert comm[1].default == cob_base + NODE_ID
    assert comm[2].default == 254
    assert comm[5].default == timer_ms
    assert all(comm[s].access_type == "rw" for s in (1, 2, 3, 5, 6))
    assert mapping_obj[0].default == len(mapping)
    assert [mapping_obj[s].default for s in range(1, len(mapping) + 1)] == mapping
    assert all(mapping_obj[s].default == 0 for s in range(len(mapping) + 1, 9))
    bits = sum(entry & 0xFF for entry in mapping)
    assert bits == {1: 64, 2: 64, 3: 40}[number]


def test_tpdo_map_loads_in_canopen(eds: canopen.ObjectDictionary) -> None:
    node = canopen.LocalNode(NODE_ID, eds)
    canopen.Network().add_node(node)  # no bus needed: the map only subscribes
    node.tpdo.read(from_od=True)
    assert node.tpdo[1].cob_id == 0x190 and node.tpdo[1].length == 64
    assert [(v.index, v.subindex) for v in node.tpdo[2].map] == [
        (0x2001, 1),
        (0x2001, 2),
        (0x2001, 3),
        (0x2002, 2),
    ]
    assert node.tpdo[3].length == 40 and node.tpdo[3].event_timer == 100


def test_store_and_restore_objects(eds: canopen.ObjectDictionary) -> None:
    for index in (0x1010, 0x1011):
        assert [eds[index][s].default for s in (1, 2, 3, 4)] == [1, 1, 1, 1]
    assert eds[0x1017].default == 1000
    assert eds[0x1008].default == "canimucal IMU"
