"""The EDS against docs/design.md §4's object table, loaded the way nodes and clients load it."""

from __future__ import annotations

import re
from pathlib import Path

import canopen
import numpy as np
import pytest
from canopen.objectdictionary import ODArray, ODRecord, ODVariable, datatypes

from canimucal.device import objects, od
from canimucal.device.objects import Nominal
from canimucal.model.sensor import DEFAULT_ACCEL_LSB, DEFAULT_GYRO_LSB

NODE_ID = 0x10
NOMINAL = Nominal(DEFAULT_ACCEL_LSB, DEFAULT_GYRO_LSB)
TYPES = {
    "u8": datatypes.UNSIGNED8,
    "u16": datatypes.UNSIGNED16,
    "u32": datatypes.UNSIGNED32,
    "i16": datatypes.INTEGER16,
    "f32": datatypes.REAL32,
    "vstr": datatypes.VISIBLE_STRING,
}


@pytest.fixture(scope="module", params=["repository", "packaged"])
def eds(request: pytest.FixtureRequest) -> canopen.ObjectDictionary:
    """The EDS in eds/ and its packaged copy in canimucal/data/, as canopen loads them."""
    path = od.eds_path() if request.param == "repository" else PACKAGED
    return canopen.import_od(str(path), NODE_ID)


PACKAGED = Path(od.__file__).resolve().parent.parent / "data" / "canimucal_imu.eds"


def _variables(eds: canopen.ObjectDictionary) -> dict[tuple[int, int], ODVariable]:
    """Every variable of the EDS but the "highest sub-index" sub 0 of an ARRAY or RECORD."""
    out = {}
    for entry in eds.values():
        if isinstance(entry, ODVariable):
            out[(entry.index, 0)] = entry
            continue
        out.update({(entry.index, s): v for s, v in entry.subindices.items() if s or _counted(v)})
    return out


def _counted(sub0: ODVariable) -> bool:
    """A sub 0 that is an object of its own (a PDO map's number of mapped objects)."""
    return sub0.name != "Highest sub-index supported"


def _default(obj: objects.DeviceObject) -> object:
    value = obj.default_value(NOMINAL)
    if isinstance(value, str) and value.startswith("$NODEID+"):
        return NODE_ID + int(value.removeprefix("$NODEID+"), 0)
    return float(np.float32(value)) if obj.data_type == "f32" else value


def test_every_object_of_the_table_is_in_the_eds_and_back(
    eds: canopen.ObjectDictionary,
) -> None:
    found = _variables(eds)
    table = {o.key: o for o in objects.OBJECTS}
    assert sorted(found) == sorted(table)
    for key, obj in table.items():
        var, where = found[key], od.format_key(*key)
        assert var.name == obj.name, where
        assert var.data_type == TYPES[obj.data_type], where
        assert var.access_type == obj.access, where
        assert var.pdo_mappable == obj.pdo, where
        assert var.default == _default(obj), where


def test_every_group_of_the_table_is_in_the_eds_and_back(eds: canopen.ObjectDictionary) -> None:
    groups = {g.index: g for g in objects.GROUPS}
    found = {e.index: e for e in eds.values() if not isinstance(e, ODVariable)}
    assert sorted(found) == sorted(groups)
    for index, group in groups.items():
        entry = found[index]
        assert entry.name == group.name
        assert isinstance(entry, ODArray if group.kind == "array" else ODRecord)
        if not _counted(entry[0]):
            assert entry[0].default == max(s for s in entry.subindices)


def test_every_object_carries_a_range_rule() -> None:
    """A row without a rule cannot be written: the field has no default."""
    with pytest.raises(TypeError, match="valid"):
        objects.DeviceObject(0x2200, 1, "new", "f32", "rw", 0.0)  # type: ignore[call-arg]
    assert all(isinstance(o.valid, objects.RangeRule) for o in objects.OBJECTS)
    assert od.range_problems(0x2200, 1, 0.0, DEFAULT_ACCEL_LSB, DEFAULT_GYRO_LSB) is not None


def test_calibration_defaults_are_factory(eds: canopen.ObjectDictionary) -> None:
    factory = od.factory_block(DEFAULT_ACCEL_LSB, DEFAULT_GYRO_LSB).to_objects()
    for (index, sub), value in factory.items():
        assert _variables(eds)[(index, sub)].default == value, f"0x{index:04X}:{sub:02X}"
    assert _variables(eds)[(0x2121, 5)].default == 0
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
