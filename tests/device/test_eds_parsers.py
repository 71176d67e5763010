"""The EDS passes two independent parsers and a CiA 306 checker of our own (issue 11).

eds-utils' validator (``read_eds``: no errors, no auto-fixes) and canopen-monitor's parser
(which then decodes TPDO1 and TPDO3 with the file's mapping). canopen-monitor assumes
OreSat's 0x2101 holds the node id; that one quirk is set aside while the file is parsed.
"""

from __future__ import annotations

import struct
from pathlib import Path
from unittest import mock

import pytest

from canimucal.device import od
from tests.support.cia306 import check_eds

NODE_ID = 0x10


def test_eds_utils_validates_without_errors() -> None:
    from eds_utils.core.file_io.read_eds import read_eds

    _, errors = read_eds(str(od.eds_path()))
    assert errors == []


def test_canopen_monitor_parses_and_decodes_tpdos() -> None:
    from canopen_monitor.parse import eds as monitor_eds
    from canopen_monitor.parse import pdo as monitor_pdo

    with mock.patch.object(monitor_eds.Index, "default_value", None, create=True):
        parsed = monitor_eds.load_eds_file(str(od.eds_path()))
    parsed.node_id = NODE_ID
    tpdo1 = struct.pack("<hhhH", -2, -2048, 1, 513)
    text = monitor_pdo.parse(0x180 + NODE_ID, tpdo1, parsed)
    assert "-2048" in text and "513" in text, text
    tpdo3 = struct.pack("<hHB", 2512, 7, 4)
    text = monitor_pdo.parse(0x380 + NODE_ID, tpdo3, parsed)
    assert "2512" in text and "7" in text, text


def test_our_cia306_checker_accepts_the_eds() -> None:
    assert check_eds(od.eds_path()) == []


@pytest.mark.parametrize(
    ("edit", "problem"),
    [
        (lambda t: "; a comment\n" + t, "comment line"),
        (lambda t: t.replace("ParameterName=COB-ID EMCY", "ParameterName=EMCY = 0x80"), "one '='"),
        (lambda t: t.replace("CreationDate=11-21-2026\n", ""), "lacks CreationDate"),
        (lambda t: t.replace("1=0x1005\n", ""), "0x1005 has a section but is in no object list"),
        (lambda t: t.replace("DefaultValue=0x20020210", "DefaultValue=0x20020220"), "differs"),
    ],
)
def test_our_checker_finds_what_the_parsers_choked_on(
    tmp_path: Path, edit: object, problem: str
) -> None:
    path = tmp_path / "bad.eds"
    path.write_text(edit(od.eds_path().read_text()))  # type: ignore[operator]
    problems = check_eds(path)
    assert any(problem in p for p in problems), problems
