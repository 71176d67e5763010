#!/usr/bin/env python3
"""Write CANopenNode v4's object dictionary (``OD.h``, ``OD.c``) from a CiA 306 EDS.

Usage: ``python3 firmware/tools/eds2od.py eds/canimucal_imu.eds OUTDIR``

Standard library only, so a firmware build needs nothing but Python 3. The EDS stays the one
source of the node's objects: the simulated node loads it, the firmware is generated from it.
The output has the layout of CANopenEditor's (the generator CANopenNode documents): one
struct per storage group (``OD_RAM``, ``OD_PERSIST_COMM``, ``OD_PERSIST_APP``,
``OD_PERSIST_CAL``), ``OD_CNT_*`` counters, ``OD_ENTRY_Hxxxx`` shortcuts and the ``OD`` list.

Rules (an EDS carries no storage groups or C names, so they are fixed here):

- Storage groups: :data:`STORAGE_GROUPS` by index. The calibration block 0x2100-0x21FF is
  its own group, so the firmware stores and restores it on its own 0x1010/0x1011 sub-index.
- C names from ``ParameterName``: text in parentheses and after a comma dropped, words
  joined in camel case, a hyphen kept as ``_`` (``Vendor-ID`` -> ``vendor_ID``), as
  CANopenEditor names them; :data:`NAME_OVERRIDES` gives the names CANopenLinux's
  ``CO_main_basic.c`` uses (``x1018_identity``).
- ``$NODEID+base`` defaults become ``base``: CANopenNode adds the node-id to a COB-ID that
  equals its pre-defined base at start-up.
- REAL32 defaults are written as exact hexadecimal float literals of the value rounded once
  to float32 (as the simulated node and the CRC test vector round them).
"""

from __future__ import annotations

import configparser
import re
import struct
import sys
from dataclasses import dataclass, field
from pathlib import Path

STORAGE_GROUPS: tuple[tuple[str, tuple[tuple[int, int], ...]], ...] = (
    (
        "RAM",
        ((0x1001, 0x1001), (0x1008, 0x100A), (0x1010, 0x1011), (0x2000, 0x200F), (0x2011, 0x20FF)),
    ),
    ("PERSIST_COMM", ((0x1000, 0x1FFF),)),
    ("PERSIST_APP", ((0x2010, 0x2010),)),
    ("PERSIST_CAL", ((0x2100, 0x21FF),)),
)
"""Storage group of each index range; the first range that holds an index wins."""

NAME_OVERRIDES = {0x1018: "identity"}
"""C names other code refers to (CANopenLinux's ``OD_PERSIST_COMM.x1018_identity``)."""

C_TYPES = {
    0x0001: ("bool_t", 1),
    0x0002: ("int8_t", 1),
    0x0003: ("int16_t", 2),
    0x0004: ("int32_t", 4),
    0x0005: ("uint8_t", 1),
    0x0006: ("uint16_t", 2),
    0x0007: ("uint32_t", 4),
    0x0008: ("float32_t", 4),
    0x0009: ("char", 0),
    0x0011: ("float64_t", 8),
    0x0015: ("int64_t", 8),
    0x001B: ("uint64_t", 8),
}
"""CiA 301 data type -> (C type, size in bytes; 0 for a string)."""

VISIBLE_STRING = 0x0009
REAL32 = 0x0008
REAL64 = 0x0011
OBJECT_TYPES = {0x7: "VAR", 0x8: "ARRAY", 0x9: "RECORD"}
COUNTED = {  # OD_CNT_* name -> indices whose presence counts (CANopen.c checks these)
    "NMT": (0x1017,),
    "EM": (0x1001,),
    "SYNC": (0x1005,),
    "SYNC_PROD": (0x1005,),
    "STORAGE": (0x1010,),
    "TIME": (0x1012,),
    "EM_PROD": (0x1014,),
    "HB_CONS": (0x1016,),
    "HB_PROD": (0x1017,),
}


class EdsError(ValueError):
    """The EDS uses something this generator does not support (or is malformed)."""


@dataclass
class Sub:
    """One variable: a VAR object, or a sub-index of an ARRAY or RECORD."""

    sub: int
    name: str
    c_name: str
    data_type: int
    access: str
    pdo: bool
    default: str

    @property
    def c_type(self) -> str:
        """C type of the variable (``char`` for a string)."""
        return C_TYPES[self.data_type][0]

    @property
    def size(self) -> int:
        """Bytes the variable holds (a string: its default's length)."""
        size = C_TYPES[self.data_type][1]
        return size if size else len(self.default.encode("latin-1"))

    def attributes(self) -> str:
        """CANopenNode attribute bits (``ODA_SDO_RW | ODA_TPDO | ODA_MB``)."""
        access = {
            "ro": "ODA_SDO_R",
            "const": "ODA_SDO_R",
            "rw": "ODA_SDO_RW",
            "rwr": "ODA_SDO_RW",
            "rww": "ODA_SDO_RW",
            "wo": "ODA_SDO_W",
        }
        if self.access not in access:
            raise EdsError(f"{self.name}: unknown AccessType {self.access!r}")
        bits = [access[self.access]]
        if self.pdo:
            bits.append(
                {"ro": "ODA_TPDO", "const": "ODA_TPDO", "wo": "ODA_RPDO"}.get(
                    self.access, "ODA_TRPDO"
                )
            )
        if self.data_type == VISIBLE_STRING:
            bits.append("ODA_STR")
        elif self.size > 1:
            bits.append("ODA_MB")
        return " | ".join(bits)

    def c_value(self) -> str:
        """Return the default as a C initializer."""
        if self.data_type == VISIBLE_STRING:
            chars = [f"'{c}'" if c.isalnum() or c in " ._-" else str(ord(c)) for c in self.default]
            return "{" + ", ".join([*chars, "0"]) + "}"
        text = self.default.strip() or "0"
        text = re.sub(r"^\$NODEID\s*\+\s*", "", text, flags=re.IGNORECASE)
        if self.data_type in (REAL32, REAL64):
            value = float(text)
            if self.data_type == REAL32:
                value = struct.unpack("<f", struct.pack("<f", value))[0]
                return f"{value.hex()}f /* {value!r} */"
            return f"{value.hex()} /* {value!r} */"
        number = int(text, 0)
        if self.data_type == 0x0007:
            return f"0x{number & 0xFFFFFFFF:08X}"
        if self.data_type in (0x0005, 0x0006, 0x001B):
            return f"0x{number:0{2 * self.size}X}"
        return str(number)


@dataclass
class Obj:
    """One EDS object (index) with its sub-indices."""

    index: int
    name: str
    c_name: str
    kind: str
    group: str
    subs: list[Sub] = field(default_factory=list)

    @property
    def field(self) -> str:
        """``x1018_identity``: the member in its storage-group struct."""
        return f"x{self.index:04X}_{self.c_name}"


def c_name(text: str) -> str:
    """CANopenEditor-style C name of a ``ParameterName`` (module docstring)."""
    text = re.sub(r"\(.*?\)", " ", text).split(",")[0]
    out: list[str] = []
    after_hyphen = False
    for token in re.findall(r"[A-Za-z0-9]+|-", text):
        if token == "-":
            out.append("_")
            after_hyphen = True
            continue
        if not out:
            keep = token.isupper() and len(token) > 1
            token = token if keep else token[0].lower() + token[1:]
        elif not after_hyphen:
            token = token[0].upper() + token[1:]
        out.append(token)
        after_hyphen = False
    name = "".join(out).strip("_")
    if not name:
        raise EdsError(f"no C name can be made of {text!r}")
    return name if not name[0].isdigit() else "_" + name


def group_of(index: int) -> str:
    """Storage group of ``index`` (:data:`STORAGE_GROUPS`)."""
    for group, ranges in STORAGE_GROUPS:
        if any(low <= index <= high for low, high in ranges):
            return group
    raise EdsError(f"0x{index:04X}: no storage group for this index")


def _int(text: str, what: str) -> int:
    try:
        return int(text.strip(), 0)
    except ValueError:
        raise EdsError(f"{what}: not a number: {text!r}") from None


def _sub(section: configparser.SectionProxy, sub: int) -> Sub:
    data_type = _int(section.get("DataType", ""), f"[{section.name}] DataType")
    if data_type not in C_TYPES:
        raise EdsError(f"[{section.name}]: data type 0x{data_type:04X} is not supported")
    name = section.get("ParameterName", section.name)
    return Sub(
        sub=sub,
        name=name,
        c_name=c_name(name),
        data_type=data_type,
        access=section.get("AccessType", "ro").strip().lower(),
        pdo=section.get("PDOMapping", "0").strip() == "1",
        default=section.get("DefaultValue", ""),
    )


def read_eds(path: Path) -> list[Obj]:
    """Every object the EDS lists (mandatory, optional, manufacturer), sorted by index."""
    eds = configparser.ConfigParser(interpolation=None, strict=False)
    eds.optionxform = str  # type: ignore[assignment, method-assign]
    try:
        eds.read_string(path.read_text(encoding="latin-1"), str(path))
    except configparser.Error as exc:
        raise EdsError(f"{path}: {exc}") from None
    indices: list[int] = []
    for list_section in ("MandatoryObjects", "OptionalObjects", "ManufacturerObjects"):
        if eds.has_section(list_section):
            for key, value in eds.items(list_section):
                if key.lower() != "supportedobjects":
                    indices.append(_int(value, f"[{list_section}] {key}"))
    sections = {name.upper(): name for name in eds.sections()}
    objects = []
    for index in sorted(set(indices)):
        name = sections.get(f"{index:04X}")
        if name is None:
            raise EdsError(f"0x{index:04X} is listed but has no [{index:04X}] section")
        section = eds[name]
        kind = OBJECT_TYPES.get(_int(section.get("ObjectType", "0x7"), f"[{name}] ObjectType"))
        if kind is None:
            raise EdsError(f"[{name}]: ObjectType {section.get('ObjectType')} is not supported")
        title = section.get("ParameterName", name)
        obj = Obj(index, title, NAME_OVERRIDES.get(index, c_name(title)), kind, group_of(index))
        if kind == "VAR":
            obj.subs.append(_sub(section, 0))
        else:
            for sub in range(256):
                sub_name = sections.get(f"{index:04X}SUB{sub:X}")
                if sub_name is not None:
                    obj.subs.append(_sub(eds[sub_name], sub))
            if not obj.subs or obj.subs[0].sub != 0:
                raise EdsError(f"[{name}]: {kind} without sub-index 0")
        _check_unique(obj)
        objects.append(obj)
    return objects


def _check_unique(obj: Obj) -> None:
    names = [s.c_name for s in obj.subs]
    if obj.kind == "RECORD" and len(set(names)) != len(names):
        raise EdsError(f"0x{obj.index:04X}: sub-indices with the same C name: {names}")
    if obj.kind == "ARRAY":
        types = {s.data_type for s in obj.subs[1:]}
        if len(types) > 1:
            raise EdsError(f"0x{obj.index:04X}: an ARRAY needs one data type, got {types}")


HEADER = """/*
 * CANopen object dictionary for CANopenNode v4, generated from {eds}
 * by firmware/tools/eds2od.py. Do not edit: change the EDS and generate again.
 */
"""


def _decl(sub: Sub, name: str) -> str:
    if sub.data_type == VISIBLE_STRING:
        return f"char {name}[{sub.size + 1}];"
    return f"{sub.c_type} {name};"


def _members(obj: Obj) -> list[str]:
    if obj.kind == "VAR":
        return [_decl(obj.subs[0], obj.field)]
    if obj.kind == "ARRAY":
        element = obj.subs[1] if len(obj.subs) > 1 else obj.subs[0]
        return [
            f"uint8_t {obj.field}_sub0;",
            f"{element.c_type} {obj.field}[OD_CNT_ARR_{obj.index:04X}];",
        ]
    inner = [f"    {_decl(s, s.c_name)}" for s in obj.subs]
    return ["struct {", *inner, f"}} {obj.field};"]


def _groups(objects: list[Obj]) -> dict[str, list[Obj]]:
    groups: dict[str, list[Obj]] = {}
    for obj in objects:
        groups.setdefault(obj.group, []).append(obj)
    return groups


def render_header(objects: list[Obj], eds_name: str) -> str:
    """``OD.h``."""
    present = {o.index for o in objects}
    lines = [HEADER.format(eds=eds_name), "#ifndef OD_H", "#define OD_H", ""]
    for name, indices in COUNTED.items():
        if any(i in present for i in indices):
            lines.append(f"#define OD_CNT_{name} 1")
    tpdos = sum(1 for i in present if 0x1800 <= i <= 0x19FF)
    rpdos = sum(1 for i in present if 0x1400 <= i <= 0x15FF)
    if tpdos:
        lines.append(f"#define OD_CNT_TPDO {tpdos}")
    if rpdos:
        lines.append(f"#define OD_CNT_RPDO {rpdos}")
    lines.append("")
    for obj in objects:
        if obj.kind == "ARRAY":
            lines.append(f"#define OD_CNT_ARR_{obj.index:04X} {len(obj.subs) - 1}")
    lines.append("")
    for group, members in _groups(objects).items():
        lines.append("typedef struct {")
        for obj in members:
            lines += [f"    {line}" for line in _members(obj)]
        lines += [f"}} OD_{group}_t;", ""]
    for group in _groups(objects):
        lines += [
            f"#ifndef OD_ATTR_{group}",
            f"#define OD_ATTR_{group}",
            "#endif",
            f"extern OD_ATTR_{group} OD_{group}_t OD_{group};",
            "",
        ]
    lines += [
        "#ifndef OD_ATTR_OD",
        "#define OD_ATTR_OD",
        "#endif",
        "extern OD_ATTR_OD OD_t* OD;",
        "",
    ]
    for position, obj in enumerate(objects):
        lines.append(f"#define OD_ENTRY_H{obj.index:04X} &OD->list[{position}]")
    lines.append("")
    for position, obj in enumerate(objects):
        lines.append(f"#define OD_ENTRY_H{obj.index:04X}_{obj.c_name} &OD->list[{position}]")
    lines += ["", "#endif /* OD_H */", ""]
    return "\n".join(lines)


def _initializer(obj: Obj) -> list[str]:
    if obj.kind == "VAR":
        return [f".{obj.field} = {obj.subs[0].c_value()},"]
    if obj.kind == "ARRAY":
        values = ", ".join(s.c_value() for s in obj.subs[1:])
        return [f".{obj.field}_sub0 = {obj.subs[0].c_value()},", f".{obj.field} = {{{values}}},"]
    inner = [f"    .{s.c_name} = {s.c_value()}," for s in obj.subs]
    return [f".{obj.field} = {{", *inner, "},"]


def _descriptor(obj: Obj) -> list[str]:
    where = f"OD_{obj.group}.{obj.field}"
    if obj.kind == "VAR":
        sub = obj.subs[0]
        data = where if sub.data_type == VISIBLE_STRING else f"&{where}"
        return [
            f".o_{obj.index:04X}_{obj.c_name} = {{",
            f"    .dataOrig = {data},",
            f"    .attribute = {sub.attributes()},",
            f"    .dataLength = {sub.size}",
            "},",
        ]
    if obj.kind == "ARRAY":
        element = obj.subs[1]
        return [
            f".o_{obj.index:04X}_{obj.c_name} = {{",
            f"    .dataOrig0 = &{where}_sub0,",
            f"    .dataOrig = &{where}[0],",
            f"    .attribute0 = {obj.subs[0].attributes()},",
            f"    .attribute = {element.attributes()},",
            f"    .dataElementLength = {element.size},",
            f"    .dataElementSizeof = sizeof({element.c_type})",
            "},",
        ]
    lines = [f".o_{obj.index:04X}_{obj.c_name} = {{"]
    for s in obj.subs:
        data = f"{where}.{s.c_name}" if s.data_type == VISIBLE_STRING else f"&{where}.{s.c_name}"
        lines += [
            "    {",
            f"        .dataOrig = {data},",
            f"        .subIndex = {s.sub},",
            f"        .attribute = {s.attributes()},",
            f"        .dataLength = {s.size}",
            "    },",
        ]
    return [*lines, "},"]


def render_source(objects: list[Obj], eds_name: str) -> str:
    """``OD.c``."""
    lines = [
        HEADER.format(eds=eds_name),
        "#define OD_DEFINITION",
        '#include "301/CO_ODinterface.h"',
        '#include "OD.h"',
        "",
        "#if CO_VERSION_MAJOR < 4",
        "#error This object dictionary needs CANopenNode v4 or later",
        "#endif",
        "",
    ]
    for group, members in _groups(objects).items():
        lines.append(f"OD_ATTR_{group} OD_{group}_t OD_{group} = {{")
        for obj in members:
            lines += [f"    {line}" for line in _initializer(obj)]
        lines += ["};", ""]
    lines.append("typedef struct {")
    for obj in objects:
        kind = {"VAR": "OD_obj_var_t", "ARRAY": "OD_obj_array_t", "RECORD": "OD_obj_record_t"}
        count = f"[{len(obj.subs)}]" if obj.kind == "RECORD" else ""
        lines.append(f"    {kind[obj.kind]} o_{obj.index:04X}_{obj.c_name}{count};")
    lines += ["} ODObjs_t;", "", "static CO_PROGMEM ODObjs_t ODObjs = {"]
    for obj in objects:
        lines += [f"    {line}" for line in _descriptor(obj)]
    lines += ["};", "", "static OD_ATTR_OD OD_entry_t ODList[] = {"]
    codes = {"VAR": "ODT_VAR", "ARRAY": "ODT_ARR", "RECORD": "ODT_REC"}
    for obj in objects:
        entries = len(obj.subs) if obj.kind != "VAR" else 1
        lines.append(
            f"    {{0x{obj.index:04X}, 0x{entries:02X}, {codes[obj.kind]}, "
            f"&ODObjs.o_{obj.index:04X}_{obj.c_name}, NULL}},"
        )
    lines += [
        "    {0x0000, 0x00, 0, NULL, NULL}",
        "};",
        "",
        "static OD_t _OD = {(sizeof(ODList) / sizeof(ODList[0])) - 1, &ODList[0]};",
        "",
        "OD_t* OD = &_OD;",
        "",
    ]
    return "\n".join(lines)


def main(argv: list[str]) -> int:
    """Generate ``OD.h`` and ``OD.c``; one line on stderr and status 2 on a bad EDS."""
    if len(argv) != 3:
        print("usage: eds2od.py EDS OUTDIR", file=sys.stderr)
        return 2
    eds, out = Path(argv[1]), Path(argv[2])
    try:
        objects = read_eds(eds)
    except (OSError, EdsError) as exc:
        print(f"eds2od: {exc}", file=sys.stderr)
        return 2
    out.mkdir(parents=True, exist_ok=True)
    (out / "OD.h").write_text(render_header(objects, eds.name), encoding="ascii")
    (out / "OD.c").write_text(render_source(objects, eds.name), encoding="ascii")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
