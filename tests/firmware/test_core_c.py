"""The firmware core (``firmware/module/imu_cal.c``) built with gcc: its C unit tests, and
the same inputs through C and through the Python side (``canimucal.device.od``).

Differential checks: the CRC (random byte strings chained as ``zlib.crc32`` does, and random
blocks against :func:`od.block_crc`), every range decision (random values plus each limit's
float32 neighbours, NaN and ±inf, against :func:`od.range_problems` with the same row
diagonal and nominal LSBs) and the correction with the alignment of the mounting trim
(against :func:`od.apply_firmware`, equal within float32 rounding). Inputs come from fixed
seeds.
"""

from __future__ import annotations

import ctypes
import math
import subprocess
import zlib

import numpy as np
import pytest

from canimucal.device import objects, od
from canimucal.model.frames import trim_dcm
from tests.firmware.conftest import MODULE, Compile

SEEDS = (1, 2, 3)
ACCEL_LSB = float(np.float32(9.80665 / 2048.0))
GYRO_LSB = float(np.float32(math.pi / (180.0 * 16.4)))
N_OBJECTS = len(od.CALIBRATION_OBJECTS)


class Block(ctypes.Structure):
    """``imu_cal_block_t``."""

    _fields_ = [
        ("accel_bias", ctypes.c_float * 3),
        ("accel_m", ctypes.c_float * 9),
        ("gyro_bias", ctypes.c_float * 3),
        ("gyro_n", ctypes.c_float * 9),
        ("gyro_g", ctypes.c_float * 9),
        ("base_tilt", ctypes.c_float * 2),
        ("time_unix_s", ctypes.c_uint32),
        ("plan_code", ctypes.c_uint8),
        ("temp_c", ctypes.c_float),
        ("rms_ms2", ctypes.c_float),
        ("mounting_trim", ctypes.c_float * 3),
        ("valid", ctypes.c_uint8),
        ("crc", ctypes.c_uint32),
    ]


class Cal(ctypes.Structure):
    """``imu_cal_t``."""

    _fields_ = [
        ("value", ctypes.c_void_p * N_OBJECTS),
        ("accel_lsb", ctypes.c_float),
        ("gyro_lsb", ctypes.c_float),
        ("active", ctypes.c_uint8),
        ("counter", ctypes.c_uint16),
        ("align", ctypes.c_float * 9),
    ]


class Core:
    """The shared library with one bound block."""

    def __init__(self, lib: ctypes.CDLL, accel_lsb: float, gyro_lsb: float) -> None:
        self.lib = lib
        self.block = Block()
        self.cal = Cal()
        lib.imu_cal_bind_block(ctypes.byref(self.cal), ctypes.byref(self.block))
        self.cal.accel_lsb, self.cal.gyro_lsb = accel_lsb, gyro_lsb
        lib.imu_cal_factory(ctypes.byref(self.cal))

    def write(self, index: int, sub: int, data: bytes) -> int:
        buf = (ctypes.c_uint8 * len(data)).from_buffer_copy(data)
        return int(self.lib.imu_cal_write(ctypes.byref(self.cal), index, sub, buf, len(data)))

    def check(self, index: int, sub: int, data: bytes) -> int:
        buf = (ctypes.c_uint8 * len(data)).from_buffer_copy(data)
        return int(self.lib.imu_cal_check(ctypes.byref(self.cal), index, sub, buf, len(data)))

    def read(self, index: int, sub: int) -> bytes:
        out = (ctypes.c_uint8 * 4)()
        n = self.lib.imu_cal_read(ctypes.byref(self.cal), index, sub, out)
        return bytes(out)[:n]

    def correct(self, u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        cu, cv = (ctypes.c_int16 * 3)(*map(int, u)), (ctypes.c_int16 * 3)(*map(int, v))
        a, w = (ctypes.c_float * 3)(), (ctypes.c_float * 3)()
        self.lib.imu_cal_correct(ctypes.byref(self.cal), cu, cv, a, w)
        return np.array(a[:], dtype=float), np.array(w[:], dtype=float)


@pytest.fixture(scope="module")
def lib(compile_c: Compile) -> ctypes.CDLL:
    path = compile_c([MODULE / "imu_cal.c"], "libimu_cal.so", [f"-I{MODULE}"], shared=True)
    library = ctypes.CDLL(str(path))
    library.imu_cal_crc32.restype = ctypes.c_uint32
    library.imu_cal_crc32.argtypes = [ctypes.c_uint32, ctypes.c_char_p, ctypes.c_size_t]
    library.imu_cal_block_crc.restype = ctypes.c_uint32
    library.imu_cal_refresh.restype = ctypes.c_uint8
    library.imu_cal_read.restype = ctypes.c_size_t
    return library


def test_c_unit_tests(compile_c: Compile) -> None:
    exe = compile_c(
        [MODULE / "imu_cal.c", MODULE.parent / "tests" / "test_imu_cal.c"],
        "test_imu_cal",
        [f"-I{MODULE}"],
    )
    run = subprocess.run([str(exe)], capture_output=True, text=True, timeout=60, check=False)
    assert run.returncode == 0, run.stdout + run.stderr
    assert run.stdout.rstrip().endswith(" 0 failed"), run.stdout


def test_object_table_matches_the_registry(lib: ctypes.CDLL) -> None:
    """The C table holds the Python objects in the same (CRC) order, with the same types."""
    sizes = {"f32": 4, "u32": 4, "u8": 1}
    core = Core(lib, ACCEL_LSB, GYRO_LSB)
    for index, sub, code in od.CALIBRATION_OBJECTS:
        assert len(core.read(index, sub)) == sizes[code], (hex(index), sub)
    assert core.read(0x2121, 7) == b"" and core.read(0x2122, 4) == b""
    assert core.read(0x2123, 1) == b""


@pytest.mark.parametrize("seed", SEEDS)
def test_crc32_equals_zlib(lib: ctypes.CDLL, seed: int) -> None:
    rng = np.random.default_rng(seed)
    crc = 0
    for length in rng.integers(0, 70, size=60):
        data = rng.bytes(int(length))
        start = int(rng.integers(0, 2**32))
        assert lib.imu_cal_crc32(start, data, len(data)) == zlib.crc32(data, start)
        crc = lib.imu_cal_crc32(crc, data, len(data))
    assert crc != 0


def _random_block(
    rng: np.random.Generator, accel_lsb: float, gyro_lsb: float
) -> od.CalibrationBlock:
    def matrix(lsb: float) -> np.ndarray:
        m = np.diag(rng.uniform(0.6, 1.4, 3) * lsb * rng.choice([-1.0, 1.0], 3))
        # off-diagonals of at most 0.05 |diagonal|: the device checks each against the
        # diagonal it holds when the entry is written, and rows 2-3 come before their
        # diagonals in CRC order (the client's write order)
        off = rng.uniform(-0.05, 0.05, (3, 3)) * np.abs(np.diag(m))[:, None]
        return m + off * (1 - np.eye(3))

    return od.CalibrationBlock(
        accel_bias=rng.uniform(-3000, 3000, 3),
        accel_correction=matrix(accel_lsb),
        gyro_bias=rng.uniform(-300, 300, 3),
        gyro_correction=matrix(gyro_lsb),
        gyro_g=rng.uniform(-20, 20, (3, 3)),
        base_tilt_rad=rng.uniform(-0.1, 0.1, 2),
        time_unix_s=int(rng.integers(0, 2**32)),
        plan_code=int(rng.integers(0, 7)),
        temp_c=float(rng.uniform(-40, 85)),
        rms_ms2=float(rng.uniform(0, 0.1)),
        mounting_trim_rad=rng.uniform(-0.05, 0.05, 3),
    )


def _load(core: Core, block: od.CalibrationBlock, valid: int) -> dict[tuple[int, int], float | int]:
    """Write a whole block the way the client does (valid 0, values, CRC, valid)."""
    objects = block.to_objects()
    assert core.write(od.CAL_INFO, od.CAL_VALID_SUB, b"\x00") == 0
    for index, sub, code in od.CRC_ORDER:
        assert core.write(index, sub, od.encode(code, objects[(index, sub)])) == 0, (index, sub)
    crc = od.block_crc(objects)
    assert core.write(od.CAL_INFO, od.CAL_CRC_SUB, od.encode("u32", crc)) == 0
    assert core.write(od.CAL_INFO, od.CAL_VALID_SUB, bytes([valid])) == 0
    return objects


@pytest.mark.parametrize("seed", SEEDS)
def test_block_crc_and_gate_equal_python(lib: ctypes.CDLL, seed: int) -> None:
    rng = np.random.default_rng(seed)
    core = Core(lib, ACCEL_LSB, GYRO_LSB)
    factory = od.factory_block(ACCEL_LSB, GYRO_LSB).to_objects()
    assert lib.imu_cal_block_crc(ctypes.byref(core.cal)) == od.block_crc(factory) == 0x36701FFB
    for _ in range(20):
        objects = _load(core, _random_block(rng, ACCEL_LSB, GYRO_LSB), 1)
        assert lib.imu_cal_block_crc(ctypes.byref(core.cal)) == od.block_crc(objects)
        assert core.cal.active == 1
        for index, sub, code in od.CALIBRATION_OBJECTS[: len(od.CRC_ORDER)]:
            assert core.read(index, sub) == od.encode(code, objects[(index, sub)])
        core.write(od.CAL_INFO, od.CAL_TIME_SUB, od.encode("u32", objects[(0x2121, 1)] ^ 1))
        assert core.cal.active == 0  # one bit changed: the gate closes


def _candidates(rng: np.random.Generator, index: int, sub: int, lsb: float, diag: float) -> list:
    """Values around every limit of one object, plus random ones, as float32."""
    limits = {
        od.ACCEL_BIAS: [objects.BIAS_LIMIT_COUNTS],
        od.GYRO_BIAS: [objects.BIAS_LIMIT_COUNTS],
        od.GYRO_G: [objects.G_LIMIT],
        od.BASE_TILT: [objects.TILT_LIMIT_RAD],
        od.MOUNTING_TRIM: [objects.TRIM_LIMIT_RAD],
        od.CAL_INFO: [0.0],
    }.get(index, [])
    if index in (od.ACCEL_CORRECTION, od.GYRO_CORRECTION):
        if od.row_diagonal_sub(sub) == sub:
            limits = [0.5 * abs(lsb), 1.5 * abs(lsb)]
        else:
            limits = [0.2 * abs(diag)]
    values = [0.0, -0.0, math.nan, math.inf, -math.inf]
    for limit in limits:
        f = np.float32(limit)
        for x in (f, np.nextafter(f, np.float32(0)), np.nextafter(f, np.float32(np.inf))):
            values += [float(x), -float(x)]
    scale = max(limits, default=100.0) * 2.0
    values += [float(np.float32(v)) for v in rng.uniform(-scale, scale, 12)]
    return values


@pytest.mark.parametrize("seed", SEEDS)
def test_range_decisions_equal_python(lib: ctypes.CDLL, seed: int) -> None:
    """Every value C accepts, Python accepts, and the other way round; refused leaves it."""
    rng = np.random.default_rng(seed)
    accel_lsb = float(np.float32(ACCEL_LSB * rng.choice([-1.0, 1.0])))
    gyro_lsb = float(np.float32(GYRO_LSB * rng.uniform(0.5, 2.0)))
    core = Core(lib, accel_lsb, gyro_lsb)
    _load(core, _random_block(rng, accel_lsb, gyro_lsb), int(rng.integers(0, 2)))
    decided = 0
    for index, sub, code in od.CALIBRATION_OBJECTS:
        lsb = accel_lsb if index == od.ACCEL_CORRECTION else gyro_lsb
        row_diagonal = None
        if (
            index in (od.ACCEL_CORRECTION, od.GYRO_CORRECTION)
            and not od.row_diagonal_sub(sub) == sub
        ):
            row_diagonal = od.decode("f32", core.read(index, od.row_diagonal_sub(sub)))
        diag = row_diagonal if row_diagonal is not None else lsb
        if code == "f32":
            values: list = _candidates(rng, index, sub, lsb, diag)
            encoded = [od.encode("f32", v) for v in values]
        else:
            top = 255 if code == "u8" else 2**32 - 1
            values = [0, 1, 2, 5, 6, 7, top, *rng.integers(0, top, 5, endpoint=True).tolist()]
            encoded = [od.encode(code, v) for v in values]
        for data in encoded:
            value = od.decode(code, data)
            python_ok = (
                od.range_problems(index, sub, value, accel_lsb, gyro_lsb, row_diagonal) is None
            )
            before = core.read(index, sub)
            result = core.check(index, sub, data)
            assert result in (0, 1), result
            assert (result == 0) == python_ok, (hex(index), sub, value, data.hex())
            decided += 1
            if not python_ok:
                assert core.write(index, sub, data) == 1 and core.read(index, sub) == before
    assert decided > 400


@pytest.mark.parametrize("seed", SEEDS)
def test_correction_equals_python_within_float32(lib: ctypes.CDLL, seed: int) -> None:
    rng = np.random.default_rng(seed)
    core = Core(lib, ACCEL_LSB, GYRO_LSB)
    eps = float(np.finfo(np.float32).eps)
    for case in range(40):
        block = _random_block(rng, ACCEL_LSB, GYRO_LSB)
        valid = int(case % 4 != 0)  # every fourth block stays invalid: nominal output
        _load(core, block, valid)
        stored = od.CalibrationBlock.from_objects(block.to_objects())  # float32 values
        for _ in range(10):
            u = rng.integers(-32768, 32768, 3)
            v = rng.integers(-32768, 32768, 3)
            a_c, w_c = core.correct(u, v)
            a_py, w_py = od.apply_firmware(stored, bool(valid), True, u, v, ACCEL_LSB, GYRO_LSB)
            du = np.abs(u - stored.accel_bias)
            a_scale = np.abs(stored.accel_correction) @ du if valid else np.abs(u * ACCEL_LSB)
            g_a = np.abs(stored.gyro_g) @ (np.abs(a_py) + a_scale)
            dv = np.abs(v) + np.abs(stored.gyro_bias) + g_a
            w_scale = np.abs(stored.gyro_correction) @ dv if valid else np.abs(v * GYRO_LSB)
            if valid:  # turned into the vehicle frame by the trim: R' a, R' w (each in float)
                turn = np.abs(trim_dcm(np.asarray(stored.mounting_trim_rad))).T
                a_scale = turn @ a_scale + np.sum(a_scale)
                w_scale = turn @ w_scale + np.sum(w_scale)
            assert np.all(np.abs(a_c - a_py) <= 8 * eps * a_scale + 1e-30), (a_c, a_py)
            assert np.all(np.abs(w_c - w_py) <= 8 * eps * w_scale + 1e-30), (w_c, w_py)
