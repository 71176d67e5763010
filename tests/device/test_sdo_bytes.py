"""Byte script of a transactional write: the client's SDO requests, frame by frame.

A spy bus on the same virtual channel records every frame the client sends to the node
(COB-ID 0x600 + node) and every answer (0x580 + node), for the simulated and the independent
durand node alike (``device_kind``). The script expected here is written from CiA 301 and
docs/design.md §4 alone: expedited uploads ``40 ii ii ss``, expedited downloads ``23``/``2B``/``2F``
(4/2/1 bytes) with index and value little-endian; valid cleared first, the block in CRC
order, every value read back, the CRC, valid set last, read back, then the store signature
'save' to 0x1010:04. The simulated node has the mounting-trim object 0x2122 (the 42-object
CRC layout); the independent one is a firmware before it: its upload of 0x2122:01 aborts with
0x06020000 ("object does not exist"), and the block is written in the 39-object layout.
"""

from __future__ import annotations

import struct
from collections.abc import Iterator
from pathlib import Path

import can
import canopen
import numpy as np
import pytest

from canimucal.device import od
from canimucal.device.client import ImuClient
from canimucal.device.transaction import write_calibration_transaction
from canimucal.io.calibration import Calibration
from tests.support.nodes import node_on

NODE_ID = 0x10
SERIAL = 31337
REQUEST, RESPONSE = 0x600 + NODE_ID, 0x580 + NODE_ID
DOWNLOAD_COMMAND = {4: 0x23, 2: 0x2B, 1: 0x2F}
SEGMENT_REQUESTS = (0x60, 0x70)  # segmented uploads of 0x1008–0x100A (toggle bit)


def upload(index: int, sub: int) -> bytes:
    return struct.pack("<BHB", 0x40, index, sub) + bytes(4)


def download(index: int, sub: int, data: bytes) -> bytes:
    return struct.pack("<BHB", DOWNLOAD_COMMAND[len(data)], index, sub) + data.ljust(4, b"\0")


@pytest.fixture
def wired(
    bus_channel: str, tmp_path: Path, device_kind: str
) -> Iterator[tuple[ImuClient, can.BusABC]]:
    buses = [can.Bus(interface="virtual", channel=bus_channel) for _ in range(3)]
    nets = [canopen.Network(buses[1])]
    for net in nets:
        net.NOTIFIER_CYCLE = 0.05
        net.connect()
    node = node_on(
        device_kind,
        buses[0],
        NODE_ID,
        start=False,
        sim_options={"state_file": tmp_path / "nv.json", "seed": None},
        serial=SERIAL,
    )
    client = ImuClient(nets[0], NODE_ID, sdo_timeout_s=0.5)
    node.start()
    assert client.find_node(1.0) == "boot-up"
    while buses[2].recv(0.02) is not None:  # boot-up and heartbeats so far
        pass
    yield client, buses[2]
    client.close()
    node.stop()
    for net in nets:
        assert net.notifier is not None
        net.notifier.stop()
    for bus in buses:
        bus.shutdown()


def test_transactional_write_byte_script(
    wired: tuple[ImuClient, can.BusABC], tmp_path: Path, device_kind: str
) -> None:
    client, spy = wired
    trim = device_kind == "simulated"  # the independent node has no 0x2122
    lsb_a, lsb_g = 9.80665 / 2048.0, float(np.pi / (180.0 * 16.4))
    record = {
        "schema": "canimucal.calibration/1",
        "device": {"serial": SERIAL},
        "accel": {"bias": [1.0, -2.0, 3.0], "K": (np.eye(3) * 1.01 / lsb_a).tolist()},
        "gyro": {"bias": [0.5, 0.0, -0.5], "S": (np.eye(3) / lsb_g).tolist()},
        "plan": "two",
    }
    report = write_calibration_transaction(
        client, Calibration.from_dict(record), backup_dir=tmp_path / "b"
    )

    frames = []
    while (msg := spy.recv(0.05)) is not None:
        frames.append((msg.arbitration_id, bytes(msg.data)))
    requests = [d for cob, d in frames if cob == REQUEST and d[0] not in SEGMENT_REQUESTS]
    responses = [d for cob, d in frames if cob == RESPONSE]

    values = report.block.to_objects()
    crc = od.block_crc(values)
    assert crc == report.crc
    order = od.crc_order(trim)
    block_writes = [download(i, s, od.encode(code, values[(i, s)])) for i, s, code in order]
    backup = od.calibration_objects(trim)
    if not trim:  # the backup's read of 0x2122:01 aborts: 02 and 03 are not asked for
        at = [k[:2] for k in od.CALIBRATION_OBJECTS].index(od.TRIM_KEYS[0])
        backup = backup[:at] + ((*od.TRIM_KEYS[0], "f32"),) + backup[at:]
    expected = (
        [upload(od.IDENTITY, 4)]  # one answer only: no second device as node 16 (docs/design.md §9)
        + [upload(od.IDENTITY, sub) for sub in (1, 2, 3, 4)]
        + [upload(od.DEVICE_NAME, 0)]
        + [upload(od.HARDWARE_VERSION, 0), upload(od.SOFTWARE_VERSION, 0)]  # 0x1009, 0x100A
        + [upload(od.NOMINAL, 1), upload(od.NOMINAL, 2)]
        + [upload(*od.TRIM_KEYS[0])]  # the mounting-trim object: the node's CRC layout
        + [upload(0x2011, 0)]  # which 0x1010 sub-index stores the calibration (issue 24)
        + [upload(od.STORE, 4)]  # 0x1010:04 offered ("save on command")? Before any write
        + [upload(od.HEARTBEAT, 0)]  # its heartbeat period: a gap while writing is a restart
        + [upload(i, s) for i, s, _ in backup]  # step 3: the backup
        + [bytes.fromhex("2f21210500000000")]  # step 4: valid = 0, first write
        + block_writes  # step 5, CRC order
        + [upload(i, s) for i, s, _ in order]  # step 6: read back
        + [bytes.fromhex("23212106") + struct.pack("<I", crc)]  # step 7: CRC
        + [bytes.fromhex("2f21210501000000")]  # step 8: valid = 1, last calibration write
        + [upload(0x2121, 6), upload(0x2121, 5)]  # step 9
        + [bytes.fromhex("2310100473617665")]  # step 10: 'save' to 0x1010:04
        + [upload(od.IDENTITY, 4), upload(0x2121, 5), upload(0x2121, 6)]  # read back after it
    )
    assert len(requests) == len(expected)
    for n, (got, want) in enumerate(zip(requests, expected, strict=True)):
        assert got == want, f"request {n}: {got.hex()} != {want.hex()}"
    # spot checks of the encoding written by hand
    assert block_writes[0] == bytes.fromhex("23002101") + struct.pack("<f", 1.0)
    plan_write = block_writes[[i for i, s, _ in order].index(0x2121) + 1]
    assert plan_write == bytes.fromhex("2f21210201000000")  # U8 plan code 1 ("two")
    # every download was confirmed (0x60 with the same index/sub), no abort (0x80)
    downloads = [r for r in requests if r[0] in DOWNLOAD_COMMAND.values()]
    confirmations = [r for r in responses if r[0] == 0x60]
    assert [c[1:4] for c in confirmations] == [d[1:4] for d in downloads]
    aborts = [r for r in responses if r[0] == 0x80]
    no_object = struct.pack("<BHBI", 0x80, *od.TRIM_KEYS[0], od.ABORT_NO_OBJECT)
    assert aborts == ([] if trim else [no_object, no_object])  # the check, the backup's read
    assert report.trim_object is trim
