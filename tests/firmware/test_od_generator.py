"""The object dictionary generator (``firmware/tools/eds2od.py``) against CANopenNode v4.

The generated ``OD.c`` compiles warning-free with ``-Wall -Wextra -Wpedantic -Werror``
against CANopenNode's headers (its bare-metal example target and the module's configuration
overrides), and so does the module's glue. A small C program walks the generated OD with
CANopenNode's own accessors (``OD_getSub``, the default read) and prints every sub-index's
length, attributes and default bytes; these must equal what an independent EDS parser
(python-canopen) reads from the same EDS. Skips without gcc or without
``../shared/third_party``.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import canopen
import pytest
from canopen.objectdictionary import ODArray, ODRecord, ODVariable

from canimucal.device import od
from tests.firmware.conftest import (
    CANOPENNODE,
    FIRMWARE,
    MODULE,
    Compile,
    gcc_or_skip,
    third_party_or_skip,
)

GENERATOR = FIRMWARE / "tools" / "eds2od.py"
ODA_SDO_R, ODA_SDO_W, ODA_TPDO, ODA_RPDO = 0x01, 0x02, 0x04, 0x08

DUMP = r"""
#include <stdio.h>
#include "301/CO_ODinterface.h"
#include "OD.h"
int main(void) {
    for (uint16_t i = 0; i < OD->size; i++) {
        OD_entry_t* entry = &OD->list[i];
        for (unsigned sub = 0; sub < 256; sub++) {
            OD_IO_t io;
            uint8_t buf[300];
            OD_size_t n = 0;
            if (OD_getSub(entry, (uint8_t)sub, &io, false) != ODR_OK) continue;
            if (io.read(&io.stream, buf, sizeof buf, &n) != ODR_OK) return 1;
            printf("%04X %02X %02X ", entry->index, sub, io.stream.attribute);
            for (OD_size_t k = 0; k < n; k++) printf("%02X", buf[k]);
            printf("\n");
        }
    }
    return 0;
}
"""


@pytest.fixture(scope="module")
def generated(tmp_path_factory: pytest.TempPathFactory) -> Path:
    gcc_or_skip()
    third_party_or_skip()
    out = tmp_path_factory.mktemp("od")
    run = subprocess.run(
        [sys.executable, str(GENERATOR), str(od.eds_path()), str(out)],
        capture_output=True,
        text=True,
        check=False,
    )
    assert run.returncode == 0, run.stderr
    return out


def _includes(generated: Path) -> list[str]:
    return [
        f"-I{generated}",
        f"-I{MODULE}",
        f"-I{CANOPENNODE}",
        f"-I{CANOPENNODE / 'example'}",
        "-include",
        str(MODULE / "imu_cal_co_config.h"),
    ]


def test_generated_od_and_glue_compile_warning_free(generated: Path, compile_c: Compile) -> None:
    flags = _includes(generated)
    compile_c([generated / "OD.c"], "OD.o", flags, link=False)
    compile_c([MODULE / "imu_cal_co.c"], "imu_cal_co.o", flags, link=False)


def test_stock_canopennode_builds_on_the_generated_od(generated: Path, compile_c: Compile) -> None:
    """CANopen.c, the stack's own user of ``OD.h``, with only the module's overrides.

    The EDS before issue 24 fails here: SYNC needs 0x1006, which it lacked (issue case 4).
    """
    compile_c(
        [CANOPENNODE / "CANopen.c"], "CANopen.o", _includes(generated), link=False, strict=False
    )


def test_generated_od_holds_the_eds(generated: Path, compile_c: Compile) -> None:
    """Every object, sub-index, access, PDO flag and default as python-canopen reads the EDS."""
    source = generated / "dump.c"
    source.write_text(DUMP)
    exe = compile_c(
        [source, generated / "OD.c", CANOPENNODE / "301" / "CO_ODinterface.c"],
        "od_dump",
        _includes(generated),
    )
    run = subprocess.run([str(exe)], capture_output=True, text=True, timeout=30, check=False)
    assert run.returncode == 0, run.stderr
    dumped = {}
    for line in run.stdout.splitlines():
        index, sub, attribute, data = [*line.split(), ""][:4]
        dumped[(int(index, 16), int(sub, 16))] = (int(attribute, 16), bytes.fromhex(data))

    eds = canopen.import_od(str(od.eds_path()), node_id=0)  # $NODEID+base -> base, as the OD
    expected = {}
    for entry in eds.values():
        variables = [entry] if isinstance(entry, ODVariable) else []
        if isinstance(entry, ODArray | ODRecord):
            variables = [entry[s] for s in sorted(entry.subindices)]
        for var in variables:
            expected[(var.index, var.subindex)] = var
    assert set(dumped) == set(expected)
    for key, var in expected.items():
        attribute, data = dumped[key]
        default = var.default if var.default is not None else 0
        assert data == var.encode_raw(default), (hex(key[0]), key[1], data.hex())
        readable, writable = (
            "r" in var.access_type or var.access_type == "const",
            "w" in var.access_type,
        )
        assert bool(attribute & ODA_SDO_R) == readable, key
        assert bool(attribute & ODA_SDO_W) == writable, key
        assert bool(attribute & (ODA_TPDO | ODA_RPDO)) == var.pdo_mappable, key


def test_generator_refuses_an_unknown_data_type(tmp_path: Path) -> None:
    text = od.eds_path().read_text(encoding="utf-8")
    broken = tmp_path / "broken.eds"
    broken.write_text(
        text.replace(
            "[1000]\nParameterName=Device type\nObjectType=0x7\nDataType=0x0007",
            "[1000]\nParameterName=Device type\nObjectType=0x7\nDataType=0x0010",
        )
    )
    run = subprocess.run(
        [sys.executable, str(GENERATOR), str(broken), str(tmp_path / "out")],
        capture_output=True,
        text=True,
        check=False,
    )
    assert run.returncode == 2
    assert run.stderr.startswith("eds2od: [1000]: data type 0x0010 is not supported")
    assert not (tmp_path / "out").exists()
