"""Bad PDO mappings are refused up front; a stream pairing nothing fails in time (issue 13)."""

from __future__ import annotations

import logging
import time
from pathlib import Path

import numpy as np
import pytest

from canimucal.device import od
from canimucal.device.pdo_layout import (
    ACCEL_RAW,
    GYRO_RAW,
    SAMPLE_INFO,
    layout_from_mapping,
    mapping_entry,
)
from canimucal.errors import DeviceError
from canimucal.io.recording_writer import RecordingWriter
from canimucal.model.vocabulary.plans import builtin_plan
from canimucal.runtime.inputs import read_recording
from canimucal.runtime.recorder import Recorder
from canimucal.runtime.wiring import demo_settings, open_devices
from canimucal.sim.truth import Truth

NODE = 0x10
COBS = {1: 0x190, 2: 0x290, 3: 0x390}


def _entries(counter_bits: int = 16, extra: list[int] | None = None) -> dict[int, list[int]]:
    xyz = {
        n: [mapping_entry(index, s, 16) for s in (1, 2, 3)]
        + [mapping_entry(SAMPLE_INFO, 2, counter_bits)]
        + list(extra or [])
        for n, index in ((1, ACCEL_RAW), (2, GYRO_RAW))
    }
    return {**xyz, 3: [mapping_entry(SAMPLE_INFO, 1, 16), mapping_entry(SAMPLE_INFO, 2, 16)]}


@pytest.mark.parametrize(
    ("cobs", "entries", "message"),
    [
        (COBS, _entries(extra=[mapping_entry(SAMPLE_INFO, 3, 0)]), "maps 0x2002:03 with 0 bits"),
        ({**COBS, 2: 0x190}, _entries(), "TPDO2 has TPDO1's COB-ID 0x190"),
        (COBS, _entries(counter_bits=8), "counter 0x2002:02 with 8 bits; it needs 16"),
        (COBS, _entries(extra=[mapping_entry(SAMPLE_INFO, 1, 16)]), "10 bytes"),
    ],
)
def test_bad_mappings_are_refused_with_a_clear_message(
    cobs: dict[int, int], entries: dict[int, list[int]], message: str
) -> None:
    with pytest.raises(ValueError, match=message):
        layout_from_mapping(cobs, entries)


def test_the_design_mapping_is_accepted() -> None:
    layout = layout_from_mapping(COBS, _entries())
    assert layout.accel.size_bytes == layout.gyro.size_bytes == 8


def test_frames_one_byte_short_fail_within_the_stall_timeout(tmp_path: Path) -> None:
    truth = Truth.random(np.random.default_rng(8), cross_axis_max=0.0, tilt_max_deg=0.0)
    position = builtin_plan("two").positions[0]
    with open_devices(demo_settings([truth], time_scale=1.0, seed=3)) as rig:
        rig.identities()
        client = rig.clients[NODE]
        rate = float(client.output_data_rate())
        real = client.pdo_mapping()  # read before the node's mapping changes
        client.pdo_mapping = lambda: real  # type: ignore[method-assign]
        local = rig.sim_nodes[NODE].local_node
        for tpdo in od.TPDO_MAP[:2]:  # the node now sends the counter's low byte only
            # past the node's own mapping checks: a firmware that packs what it should not
            local.data_store.setdefault(tpdo, {})[4] = od.encode(
                "u32", mapping_entry(SAMPLE_INFO, 2, 8)
            )
        with RecordingWriter.open(tmp_path / "r.csv", {"sample_rate_hz": rate}) as writer:
            recorder = Recorder([(client, writer, rate)], idle_timeout_s=1.0)
            recorder.start()
            started = time.monotonic()
            try:
                with pytest.raises(DeviceError) as raised:
                    recorder.record_pose(0, position, settle_s=0.0)
            finally:
                recorder.stop()
    assert time.monotonic() - started < 5.0
    assert "sent no sample for 1 s" in str(raised.value)
    assert "frames did not match the node's PDO mapping" in str(raised.value)


def test_claimed_rate_is_checked_against_the_timestamps(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    truth = Truth.random(np.random.default_rng(8), cross_axis_max=0.0, tilt_max_deg=0.0)
    position = builtin_plan("two").with_total_seconds(2.0).positions[0]  # 1 s
    path = tmp_path / "r.csv"
    with open_devices(demo_settings([truth], time_scale=1.0, seed=3)) as rig:
        rig.identities()
        client = rig.clients[NODE]
        assert client.output_data_rate() == 200
        claimed = 50.0  # what a device might claim in 0x2010:03 while sending 200 Hz
        with RecordingWriter.open(path, {"sample_rate_hz": claimed}) as writer:
            recorder = Recorder([(client, writer, claimed)], check_rate=True)
            with caplog.at_level(logging.WARNING):
                recorder.start()
            try:
                recorder.record_pose(0, position, settle_s=0.2)
            finally:
                recorder.stop()
    assert "claims 50 Hz (0x2010:03) but its samples arrive at 200 Hz" in caplog.text
    rec = read_recording(path)
    assert rec.sample_rate_hz == 200.0
    assert (rec.position == 0).sum() == 200  # 1 s counted at the measured rate
