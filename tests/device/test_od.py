"""Object-dictionary definitions: encodings, CRC, calibration block, ranges, firmware."""

from __future__ import annotations

import math
import struct
import zlib
from dataclasses import replace

import numpy as np
import pytest
from canopen.sdo.exceptions import SdoAbortedError
from hypothesis import given, settings
from hypothesis import strategies as st

from canimucal.device import od
from canimucal.device.bus import abort_text
from canimucal.errors import InputError
from canimucal.model.frames import trim_dcm
from canimucal.model.sensor import DEFAULT_ACCEL_LSB, DEFAULT_GYRO_LSB

A_LSB, G_LSB = DEFAULT_ACCEL_LSB, DEFAULT_GYRO_LSB
FACTORY_CRC = 0x36701FFB  # the EDS's test vector, computed independently below
LEGACY_FACTORY_CRC = 0x88E40123  # a node without 0x2122: the 39-object layout


def test_crc_order_is_design_order() -> None:
    expected = (
        [(0x2100, s) for s in range(1, 4)]
        + [(0x2101, s) for s in range(1, 10)]
        + [(0x2110, s) for s in range(1, 4)]
        + [(0x2111, s) for s in range(1, 10)]
        + [(0x2112, s) for s in range(1, 10)]
        + [(0x2120, s) for s in range(1, 3)]
        + [(0x2121, s) for s in range(1, 5)]
    )
    trim = [(0x2122, s) for s in range(1, 4)]
    assert [(i, s) for i, s, _ in od.CRC_ORDER] == expected + trim
    assert [(i, s) for i, s, _ in od.crc_order(False)] == expected  # older firmware
    codes = {(i, s): c for i, s, c in od.CRC_ORDER}
    assert codes[(0x2121, 1)] == "u32" and codes[(0x2121, 2)] == "u8"
    assert {codes[k] for k in expected + trim if k[0] != 0x2121} == {"f32"}
    assert od.CALIBRATION_OBJECTS[-2:] == ((0x2121, 5, "u8"), (0x2121, 6, "u32"))
    assert len(od.CALIBRATION_OBJECTS) == 44 and len(od.calibration_objects(False)) == 41
    sizes = [len(od.encode(c, 0)) for _, _, c in od.CRC_ORDER]
    assert (len(sizes), sum(sizes)) == (42, 165)
    assert sum(sizes[:39]) == 153


def test_signatures_spell_save_and_load() -> None:
    assert struct.pack("<I", od.SAVE_SIGNATURE) == b"save"
    assert struct.pack("<I", od.LOAD_SIGNATURE) == b"load"


def test_factory_crc_test_vector_by_hand() -> None:
    # independent of block_crc: pack the factory values directly, little-endian
    floats = [0.0] * 3 + list(np.eye(3).ravel() * A_LSB) + [0.0] * 3
    floats += list(np.eye(3).ravel() * G_LSB) + [0.0] * 9 + [0.0] * 2
    data = struct.pack(f"<{len(floats)}f", *floats) + struct.pack("<IBff", 0, 0, 0.0, 0.0)
    assert zlib.crc32(data) == LEGACY_FACTORY_CRC
    assert zlib.crc32(data + struct.pack("<3f", 0.0, 0.0, 0.0)) == FACTORY_CRC
    block = od.factory_block(A_LSB, G_LSB)
    assert od.block_crc(block.to_objects()) == FACTORY_CRC
    legacy = od.factory_block(A_LSB, G_LSB, trim=False)
    assert legacy.mounting_trim_rad is None
    assert od.block_crc(legacy.to_objects()) == LEGACY_FACTORY_CRC
    # the 42-object CRC continues the 39-object one over the trim's 12 bytes
    assert zlib.crc32(struct.pack("<3f", 0.0, 0.0, 0.0), LEGACY_FACTORY_CRC) == FACTORY_CRC


def test_crc_changes_with_any_object_and_ignores_valid_flag() -> None:
    objects = od.factory_block(A_LSB, G_LSB).to_objects()
    base = od.block_crc(objects)
    for key in objects:
        changed = dict(objects)
        changed[key] = objects[key] + 1
        assert od.block_crc(changed) != base, key
    with_extra = dict(objects)
    with_extra[(0x2121, 5)] = 1
    with_extra[(0x2121, 6)] = 12345
    assert od.block_crc(with_extra) == base


def test_crc_missing_object_is_input_error() -> None:
    objects = od.factory_block(A_LSB, G_LSB).to_objects()
    del objects[(0x2112, 5)]
    with pytest.raises(InputError, match="0x2112:05"):
        od.block_crc(objects)
    objects = od.factory_block(A_LSB, G_LSB).to_objects()
    del objects[(0x2122, 2)]  # a trim is all three angles or none
    with pytest.raises(InputError, match="0x2122:02"):
        od.block_crc(objects)


def test_a_flipped_trim_byte_breaks_the_crc() -> None:
    objects = od.factory_block(A_LSB, G_LSB).to_objects()
    objects[(0x2122, 3)] = 0.01
    crc = od.block_crc(objects)
    for key in od.TRIM_KEYS:
        data = bytearray(od.encode("f32", objects[key]))
        for byte in range(4):
            flipped = bytearray(data)
            flipped[byte] ^= 0x01
            changed = dict(objects)
            changed[key] = od.decode("f32", bytes(flipped))
            assert od.block_crc(changed) != crc, (key, byte)


@pytest.mark.parametrize(
    ("code", "value", "raw"),
    [
        ("f32", 1.5, b"\x00\x00\xc0\x3f"),
        ("u32", od.SAVE_SIGNATURE, b"save"),
        ("u8", 1, b"\x01"),
        ("u16", 65535, b"\xff\xff"),
        ("i16", -2, b"\xfe\xff"),
    ],
)
def test_encode_decode_known_bytes(code: str, value: float, raw: bytes) -> None:
    assert od.encode(code, value) == raw
    assert od.decode(code, raw) == value


def test_encode_refuses_bad_input() -> None:
    with pytest.raises(InputError):
        od.encode("u8", 256)
    with pytest.raises(InputError):
        od.encode("x", 1)
    with pytest.raises(InputError):
        od.decode("u32", b"\x00")


@settings(derandomize=True, deadline=None, max_examples=50)
@given(
    st.lists(st.floats(min_value=-1e3, max_value=1e3, allow_nan=False), min_size=37, max_size=37),
    st.integers(0, 2**32 - 1),
    st.integers(0, 5),
    st.booleans(),
)
def test_block_objects_round_trip(values: list[float], time_s: int, plan: int, trim: bool) -> None:
    v = np.array(values)
    block = od.CalibrationBlock(
        accel_bias=v[0:3],
        accel_correction=v[3:12].reshape(3, 3),
        gyro_bias=v[12:15],
        gyro_correction=v[15:24].reshape(3, 3),
        gyro_g=v[24:33].reshape(3, 3),
        base_tilt_rad=v[33:35],
        time_unix_s=time_s,
        plan_code=plan,
        temp_c=float(v[35]),
        rms_ms2=float(v[36]),
        mounting_trim_rad=v[0:3] / 1e4 if trim else None,
    )
    objects = block.to_objects()
    assert list(objects) == [(i, s) for i, s, _ in od.crc_order(trim)]
    # REAL32 values are already float32: encoding and decoding is exact
    for (i, s), value in objects.items():
        code = od.OBJECT_CODES[(i, s)]
        assert od.decode(code, od.encode(code, value)) == value
    again = od.CalibrationBlock.from_objects(objects).to_objects()
    assert again == objects
    np.testing.assert_allclose(
        od.CalibrationBlock.from_objects(objects).accel_correction,
        v[3:12].reshape(3, 3),
        rtol=1e-6,
        atol=1e-30,
    )


def test_factory_block_is_in_range() -> None:
    assert od.block_range_problems(od.factory_block(A_LSB, G_LSB), A_LSB, G_LSB) == []
    inverted = od.factory_block(-A_LSB, G_LSB)  # an inverted axis is allowed
    assert od.block_range_problems(inverted, -A_LSB, G_LSB) == []


@pytest.mark.parametrize(
    ("index", "sub", "value", "ok"),
    [
        (0x2100, 1, 65536.0, True),
        (0x2100, 1, 65537.0, False),
        (0x2110, 3, -65537.0, False),
        (0x2100, 2, math.nan, False),
        (0x2110, 2, math.inf, False),
        (0x2101, 1, 1.49 * A_LSB, True),
        (0x2101, 1, 1.51 * A_LSB, False),
        (0x2101, 5, 0.51 * A_LSB, True),
        (0x2101, 5, 0.49 * A_LSB, False),
        (0x2101, 9, -A_LSB, True),  # inverted axis, either sign
        (0x2111, 1, 1.6 * G_LSB, False),
        (0x2111, 9, -0.7 * G_LSB, True),
        (0x2101, 2, 0.19 * A_LSB, True),
        (0x2101, 2, 0.21 * A_LSB, False),
        (0x2112, 4, -1000.0, True),
        (0x2112, 4, 1000.5, False),
        (0x2120, 1, 0.2, True),
        (0x2120, 2, -0.21, False),
        (0x2121, 5, 1, True),
        (0x2121, 5, 2, False),
        (0x2121, 2, 6, True),  # vehicle
        (0x2121, 2, 7, False),
        (0x2121, 4, -0.1, False),
        (0x2121, 3, math.nan, False),
        (0x2010, 3, 250, True),
        (0x2010, 3, 300, False),
    ],
)
def test_range_problems(index: int, sub: int, value: float, ok: bool) -> None:
    problem = od.range_problems(index, sub, value, A_LSB, G_LSB)
    assert (problem is None) == ok, problem
    if problem is not None:
        assert f"0x{index:04X}:{sub:02X}" in problem and "\n" not in problem


def test_off_diagonal_is_relative_to_row_diagonal() -> None:
    diagonal = 1.4 * A_LSB
    assert od.range_problems(0x2101, 4, 0.27 * A_LSB, A_LSB, G_LSB, diagonal) is None
    assert od.range_problems(0x2101, 4, 0.29 * A_LSB, A_LSB, G_LSB, diagonal) is not None
    assert od.range_problems(0x2101, 4, 0.11 * A_LSB, A_LSB, G_LSB, 0.5 * A_LSB) is not None
    assert od.row_diagonal_sub(4) == 5 and od.row_diagonal_sub(3) == 1
    assert od.row_diagonal_sub(8) == 9


def test_block_range_problems_lists_each() -> None:
    block = od.factory_block(A_LSB, G_LSB)
    bad = od.CalibrationBlock(
        accel_bias=np.array([0.0, 7e4, 0.0]),
        accel_correction=block.accel_correction + np.array([[0, 0.3 * A_LSB, 0], [0] * 3, [0] * 3]),
        gyro_bias=block.gyro_bias,
        gyro_correction=block.gyro_correction,
        gyro_g=block.gyro_g,
        base_tilt_rad=np.array([0.0, 0.5]),
    )
    problems = od.block_range_problems(bad, A_LSB, G_LSB)
    assert len(problems) == 3
    assert any("0x2100:02" in p for p in problems)
    assert any("0x2101:02" in p for p in problems)
    assert any("0x2120:02" in p for p in problems)


def test_apply_firmware_valid_inverts_sensor_model() -> None:
    rng = np.random.default_rng(3)
    k = (np.eye(3) + rng.uniform(-0.02, 0.02, (3, 3))) / A_LSB
    s = (np.eye(3) + rng.uniform(-0.02, 0.02, (3, 3))) / G_LSB
    g_sens = rng.uniform(-2, 2, (3, 3))
    b, bg = rng.uniform(-30, 30, 3), rng.uniform(-30, 30, 3)
    f = np.array([[0.3, -9.7, 1.1], [1.0, 2.0, -9.0]])
    w = np.array([[0.01, -0.02, 0.03], [0.0, 0.1, 0.0]])
    u = b + f @ k.T
    v = bg + w @ s.T + f @ g_sens.T
    block = od.CalibrationBlock(b, np.linalg.inv(k), bg, np.linalg.inv(s), g_sens, np.zeros(2))
    accel, gyro = od.apply_firmware(block, True, True, u, v, A_LSB, G_LSB)
    np.testing.assert_allclose(accel, f, atol=1e-9)
    np.testing.assert_allclose(gyro, w, atol=1e-9)
    for valid, crc_ok in ((False, True), (True, False)):
        accel, gyro = od.apply_firmware(block, valid, crc_ok, u, v, A_LSB, G_LSB)
        np.testing.assert_allclose(accel, u * A_LSB)
        np.testing.assert_allclose(gyro, v * G_LSB)


def test_apply_firmware_turns_the_output_into_the_vehicle_frame() -> None:
    """With the mounting trim R_m: a_v = R_mᵀ M (U − b), w_v = R_mᵀ N (V − B − G a)."""
    trim = np.array([0.02, -0.03, 0.05])
    r_m = trim_dcm(trim)  # unit ← vehicle
    f_vehicle, w_vehicle = np.array([0.4, -9.7, 1.0]), np.array([0.01, 0.0, -0.02])
    k, s = np.eye(3) / A_LSB, np.eye(3) / G_LSB
    u, v = (r_m @ f_vehicle) @ k.T, (r_m @ w_vehicle) @ s.T  # the unit sees R_m x
    zero = np.zeros(3)
    block = od.CalibrationBlock(
        zero, np.linalg.inv(k), zero, np.linalg.inv(s), np.zeros((3, 3)), np.zeros(2),
        mounting_trim_rad=trim,
    )  # fmt: skip
    accel, gyro = od.apply_firmware(block, True, True, u, v, A_LSB, G_LSB)
    np.testing.assert_allclose(accel, f_vehicle, atol=1e-12)
    np.testing.assert_allclose(gyro, w_vehicle, atol=1e-15)
    legacy = replace(block, mounting_trim_rad=None)  # no 0x2122: the unit's own axes
    accel, _ = od.apply_firmware(legacy, True, True, u, v, A_LSB, G_LSB)
    np.testing.assert_allclose(accel, r_m @ f_vehicle, atol=1e-12)


def test_keys() -> None:
    assert od.format_key(0x2100, 1) == "0x2100:01"
    assert od.parse_key("0x2121:0a") == (0x2121, 10)
    with pytest.raises(InputError):
        od.parse_key("2100-01")


def test_abort_text_is_canopens() -> None:
    """The words of each abort code are canopen's table (no hand copy to drift from it)."""
    assert abort_text(0x06090030) == "0x06090030 value range of parameter exceeded"
    assert abort_text(0x12345678) == "0x12345678 unknown abort code"
    for code in (od.ABORT_VALUE_RANGE, 0x06010002, od.ABORT_NO_OBJECT, 0x05040000):
        words = SdoAbortedError.CODES[code]  # every code the tool sends or tests for has words
        assert abort_text(code) == f"0x{code:08X} {words[0].lower()}{words[1:]}"
    assert od.ABORT_CANNOT_STORE in SdoAbortedError.CODES
    assert od.ABORT_NO_SUBINDEX in SdoAbortedError.CODES


def test_eds_path_exists() -> None:
    assert od.eds_path().is_file()
    assert od.eds_path().name == "canimucal_imu.eds"
