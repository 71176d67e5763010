"""A small CiA 306 (EDS) checker of our own: structure, object lists, types and mapping.

It reads the file as plain ``key=value`` sections (no third-party parser) and returns every
problem found as one line, so a test can assert an empty list and print what is wrong.
Checked: [FileInfo] and [DeviceInfo] keys (dates ``MM-DD-YYYY``, times ``hh:mm(AM|PM)``);
no line outside a section, no comment line (several parsers split every line on ``=``),
one ``=`` per line; the object lists ([Mandatory/Optional/ManufacturerObjects]) count and
name exactly the object sections present; 0x1000, 0x1001 and 0x1018 present; every
VAR has a known DataType, AccessType and PDOMapping and a DefaultValue its type can hold;
every ARRAY/RECORD has SubNumber sub-sections starting at sub 0; TPDO mappings name
existing PDO-mappable objects and fit 64 bits; 0x1005 present when TPDOs exist (SYNC
transmission types) and 0x1014 with 0x1001 (EMCY); [Comments] Lines counts its lines.
"""

from __future__ import annotations

import re
from pathlib import Path

FILEINFO_KEYS = (
    "FileName FileVersion FileRevision EDSVersion Description CreationTime CreationDate "
    "CreatedBy ModificationTime ModificationDate ModifiedBy"
).split()
DEVICEINFO_KEYS = (
    "VendorName VendorNumber ProductName ProductNumber RevisionNumber BaudRate_10 BaudRate_20 "
    "BaudRate_50 BaudRate_125 BaudRate_250 BaudRate_500 BaudRate_800 BaudRate_1000 "
    "SimpleBootUpMaster SimpleBootUpSlave Granularity DynamicChannelsSupported GroupMessaging "
    "NrOfRXPDO NrOfTXPDO LSS_Supported"
).split()
ACCESS_TYPES = {"ro", "wo", "rw", "rwr", "rww", "const"}
# CiA 301 basic data types: code -> (bits, signed) ; 0x09 VISIBLE_STRING and 0x0F DOMAIN
DATA_TYPES = {
    0x01: (1, False),
    0x02: (8, True),
    0x03: (16, True),
    0x04: (32, True),
    0x05: (8, False),
    0x06: (16, False),
    0x07: (32, False),
    0x08: (32, None),
    0x09: (0, None),
    0x0F: (0, None),
}
OBJECT_VAR, OBJECT_ARRAY, OBJECT_RECORD = 0x7, 0x8, 0x9
SECTION_RE = re.compile(r"^\[([^\]]+)\]$")
OBJECT_RE = re.compile(r"^([0-9A-Fa-f]{4})(?:sub([0-9A-Fa-f]{1,2}))?$")


def _int(text: str, node_id: int = 0x10) -> int:
    text = text.strip()
    if text.upper().startswith("$NODEID"):
        rest = text[len("$NODEID") :].strip()
        return node_id + (_int(rest.lstrip("+")) if rest else 0)
    return int(text, 0)


def parse_sections(text: str) -> tuple[dict[str, dict[str, str]], list[str]]:
    """Sections as ``{name: {key: value}}`` and the structural problems met on the way."""
    sections: dict[str, dict[str, str]] = {}
    problems: list[str] = []
    current: dict[str, str] | None = None
    for n, raw in enumerate(text.splitlines(), start=1):
        line = raw.strip()
        if not line:
            continue
        if line.startswith(";"):
            problems.append(f"line {n}: comment line (put it in [Comments])")
            continue
        match = SECTION_RE.match(line)
        if match:
            name = match.group(1)
            if name in sections:
                problems.append(f"line {n}: section [{name}] twice")
            current = sections.setdefault(name, {})
            continue
        if current is None:
            problems.append(f"line {n}: outside any section")
            continue
        if line.count("=") != 1:
            problems.append(f"line {n}: needs exactly one '=': {line}")
            continue
        key, value = (part.strip() for part in line.split("="))
        if key in current:
            problems.append(f"line {n}: key {key} twice in its section")
        current[key] = value
    return sections, problems


def check_eds(path: Path) -> list[str]:
    """Every CiA 306 problem of the EDS at ``path`` (empty: none found)."""
    sections, problems = parse_sections(path.read_text(encoding="ascii"))
    problems += _check_info(sections)
    objects = {
        int(m.group(1), 16): name
        for name in sections
        if (m := OBJECT_RE.match(name)) and m.group(2) is None
    }
    problems += _check_lists(sections, set(objects))
    for index in sorted(objects):
        problems += _check_object(sections, index)
    problems += _check_mapping(sections)
    problems += _check_comments(sections)
    return problems


def _check_info(sections: dict[str, dict[str, str]]) -> list[str]:
    out = []
    info = sections.get("FileInfo", {})
    out += [f"[FileInfo] lacks {k}" for k in FILEINFO_KEYS if k not in info]
    for key in ("CreationDate", "ModificationDate"):
        if key in info and not re.fullmatch(
            r"(0[1-9]|1[0-2])-(0[1-9]|[12]\d|3[01])-\d{4}", info[key]
        ):
            out.append(f"[FileInfo] {key} must be MM-DD-YYYY, got {info[key]}")
    for key in ("CreationTime", "ModificationTime"):
        if key in info and not re.fullmatch(r"(0\d|1[0-2]):[0-5]\d(AM|PM)", info[key]):
            out.append(f"[FileInfo] {key} must be hh:mm(AM|PM), got {info[key]}")
    device = sections.get("DeviceInfo", {})
    out += [f"[DeviceInfo] lacks {k}" for k in DEVICEINFO_KEYS if k not in device]
    if device.get("NrOfTXPDO") is not None:
        tpdos = sum(1 for i in range(0x1800, 0x1A00) if f"{i:04X}" in sections)
        if _int(device["NrOfTXPDO"]) != tpdos:
            out.append(f"[DeviceInfo] NrOfTXPDO={device['NrOfTXPDO']} but {tpdos} TPDOs")
    return out


def _check_lists(sections: dict[str, dict[str, str]], present: set[int]) -> list[str]:
    out: list[str] = []
    listed: set[int] = set()
    ranges = {
        "MandatoryObjects": lambda i: i in (0x1000, 0x1001, 0x1018),
        "OptionalObjects": lambda i: i < 0x2000 or i >= 0x6000,
        "ManufacturerObjects": lambda i: 0x2000 <= i < 0x6000,
    }
    for name, belongs in ranges.items():
        section = sections.get(name)
        if section is None:
            out.append(f"[{name}] missing")
            continue
        count = _int(section.get("SupportedObjects", "0"))
        entries = [_int(section[str(k)]) for k in range(1, count + 1) if str(k) in section]
        if len(entries) != count or len(section) != count + 1:
            out.append(f"[{name}] SupportedObjects={count} but {len(section) - 1} entries")
        for index in entries:
            if not belongs(index):
                out.append(f"[{name}] lists 0x{index:04X}, which belongs elsewhere")
            if index not in present:
                out.append(f"[{name}] lists 0x{index:04X}, which has no section")
        listed.update(entries)
    out += [f"0x{i:04X} has a section but is in no object list" for i in sorted(present - listed)]
    out += [
        f"mandatory object 0x{i:04X} missing" for i in (0x1000, 0x1001, 0x1018) if i not in present
    ]
    if any(0x1800 <= i < 0x1A00 for i in present) and 0x1005 not in present:
        out.append("TPDOs (SYNC transmission types) but no 0x1005 COB-ID SYNC")
    if 0x1001 in present and 0x1014 not in present:
        out.append("0x1001 (EMCY) but no 0x1014 COB-ID EMCY")
    return out


def _check_object(sections: dict[str, dict[str, str]], index: int) -> list[str]:
    name = f"{index:04X}"
    section = sections[name]
    out = [f"[{name}] lacks {k}" for k in ("ParameterName", "ObjectType") if k not in section]
    kind = _int(section.get("ObjectType", "0x7"))
    if kind == OBJECT_VAR:
        return out + _check_var(name, section)
    if kind not in (OBJECT_ARRAY, OBJECT_RECORD):
        return out + [f"[{name}] ObjectType 0x{kind:X} unknown"]
    count = _int(section.get("SubNumber", "0"))
    subs = sorted(
        int(m.group(2), 16)
        for other in sections
        if (m := OBJECT_RE.match(other)) and m.group(2) is not None and int(m.group(1), 16) == index
    )
    if len(subs) != count:
        out.append(f"[{name}] SubNumber={count} but {len(subs)} sub-sections")
    if not subs or subs[0] != 0:
        out.append(f"[{name}] has no sub-index 0")
    for sub in subs:
        out += _check_var(f"{name}sub{sub:X}", sections[f"{name}sub{sub:X}"])
    is_mapping = 0x1600 <= index < 0x1800 or 0x1A00 <= index < 0x1C00  # sub 0: entries mapped
    if subs and subs[0] == 0 and count and not is_mapping:
        highest = _int(sections[f"{name}sub0"].get("DefaultValue", "0"))
        if highest != subs[-1] and kind == OBJECT_RECORD:
            out.append(f"[{name}sub0] DefaultValue {highest} is not the highest sub {subs[-1]}")
    return out


def _check_var(name: str, section: dict[str, str]) -> list[str]:
    out = [
        f"[{name}] lacks {k}"
        for k in ("ParameterName", "DataType", "AccessType")
        if k not in section
    ]
    if "DataType" not in section:
        return out
    code = _int(section["DataType"])
    if code not in DATA_TYPES:
        return out + [f"[{name}] DataType 0x{code:04X} unknown"]
    if section.get("AccessType", "ro").lower() not in ACCESS_TYPES:
        out.append(f"[{name}] AccessType {section['AccessType']} unknown")
    if section.get("PDOMapping", "0") not in ("0", "1"):
        out.append(f"[{name}] PDOMapping must be 0 or 1")
    default = section.get("DefaultValue")
    bits, signed = DATA_TYPES[code]
    if default and bits and signed is not None:
        try:
            value = _int(default)
        except ValueError:
            return out + [f"[{name}] DefaultValue {default} is not an integer"]
        low, high = (-(1 << (bits - 1)), (1 << (bits - 1)) - 1) if signed else (0, (1 << bits) - 1)
        if not low <= value <= high:
            out.append(f"[{name}] DefaultValue {default} outside its {bits}-bit type")
    elif default and signed is None and bits:
        try:
            float(default)
        except ValueError:
            out.append(f"[{name}] DefaultValue {default} is not a number")
    return out


def _check_mapping(sections: dict[str, dict[str, str]]) -> list[str]:
    out = []
    for index in range(0x1A00, 0x1C00):
        name = f"{index:04X}"
        if name not in sections:
            continue
        count = _int(sections.get(f"{name}sub0", {}).get("DefaultValue", "0"))
        bits = 0
        for sub in range(1, count + 1):
            entry = _int(sections.get(f"{name}sub{sub:X}", {}).get("DefaultValue", "0"))
            target, target_sub, length = entry >> 16, (entry >> 8) & 0xFF, entry & 0xFF
            bits += length
            var = sections.get(f"{target:04X}sub{target_sub:X}") or (
                sections.get(f"{target:04X}") if target_sub == 0 else None
            )
            if var is None:
                out.append(
                    f"[{name}sub{sub:X}] maps 0x{target:04X}:{target_sub:02X}: no such object"
                )
            elif var.get("PDOMapping") != "1":
                out.append(f"[{name}sub{sub:X}] maps 0x{target:04X}:{target_sub:02X}: not mappable")
            elif DATA_TYPES.get(_int(var.get("DataType", "0")), (0, None))[0] != length:
                out.append(f"[{name}sub{sub:X}] length {length} bits differs from the object's")
        if bits > 64:
            out.append(f"[{name}] maps {bits} bits: more than one classic CAN frame (64)")
    return out


def _check_comments(sections: dict[str, dict[str, str]]) -> list[str]:
    comments = sections.get("Comments")
    if comments is None:
        return []
    count = _int(comments.get("Lines", "0"))
    lines = [k for k in comments if k.startswith("Line") and k != "Lines"]
    if len(lines) != count or any(f"Line{k}" not in comments for k in range(1, count + 1)):
        return [f"[Comments] Lines={count} but {len(lines)} lines"]
    return []
