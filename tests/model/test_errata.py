"""One test per row of the errata table (docs/method.md §2): the printed equation fails, ours
does not.

Expected values always come from the paper's own matrices, ``f = C f_L`` and ``w = C w_L``
with ``C = position_dcm(...)`` (never from a corrected formula), with α ≠ 45° (at 45°,
sin α = cos α hides a sin↔cos slip), an inverted axis, and φ = 50.45° ≠ 45°. Each printed
equation is written inline, labelled ``PRINTED``, exactly as the errata table quotes it.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pytest
from numpy.typing import NDArray

from canimucal.model.frames import (
    EARTH_RATE_RAD_S,
    earth_rate_level,
    position_dcm,
    specific_force_level,
)
from canimucal.model.paper.accel import fourier_accel, two_position_accel
from canimucal.model.paper.gyro import nav_gyro_two_position
from canimucal.model.positions import Pose, PositionAverage

Array = NDArray[np.float64]
G = 9.80665
OMEGA = EARTH_RATE_RAD_S
PHI = np.deg2rad(50.45)
ALPHA, BETA = np.deg2rad(37.0), np.deg2rad(6.0)  # α ≠ 45°
ALPHA0, BETA0 = np.deg2rad(-1.3), np.deg2rad(0.8)
BIAS = np.array([15.0, -40.0, 9.0])
K_SIZE = 2048.0 / G  # counts per m/s²
FOURIER_DEG = [(0.0, 0.0), (15.0, 0.0), (25.0, 3.0), (37.0, 2.0), (41.0, 6.0), (30.0, -4.0)]


def _accel_average(pose: Pose, counts: Array) -> PositionAverage:
    return PositionAverage(pose, 1, counts, np.zeros((3, 3)))


def _gyro_average(pose: Pose, counts: Array) -> PositionAverage:
    return PositionAverage(pose, 1, np.zeros(3), np.zeros((3, 3)), counts, np.zeros((3, 3)))


def _accel_counts(scale: Array, pose: Pose, tilted_base: bool = False) -> Array:
    """Noiseless counts; the tilted base uses the paper's additive reading (eq. 15)."""
    if tilted_base:
        dcm = position_dcm(pose.alpha, pose.beta, 0.0, ALPHA0, BETA0, "additive")
    else:
        dcm = position_dcm(pose.alpha, pose.beta)
    return BIAS + scale * (dcm @ specific_force_level(G))


def _two_positions(scale: Array) -> tuple[PositionAverage, PositionAverage]:
    level, tilted = Pose(0.0, 0.0), Pose(ALPHA, BETA)
    return (
        _accel_average(level, _accel_counts(scale, level)),
        _accel_average(tilted, _accel_counts(scale, tilted)),
    )


def _fourier_data(scale: Array) -> list[PositionAverage]:
    poses = [Pose(np.deg2rad(a), np.deg2rad(b)) for a, b in FOURIER_DEG]
    return [_accel_average(p, _accel_counts(scale, p, tilted_base=True)) for p in poses]


def _fit(averages: Sequence[PositionAverage], channel: int) -> Array:
    """Unweighted LS coefficients of one channel on the paper's sine/cosine columns."""
    a = np.array([p.pose.alpha for p in averages])
    b = np.array([p.pose.beta for p in averages])
    if channel == 0:
        design = np.column_stack([np.ones_like(a), np.sin(a), np.cos(a)])
    else:
        sa, ca, sb, cb = np.sin(a), np.cos(a), np.sin(b), np.cos(b)
        design = np.column_stack([np.ones_like(a), ca * cb, ca * sb, sa * cb, sa * sb])
    y = np.array([p.mean_accel[channel] for p in averages])
    coef, *_ = np.linalg.lstsq(design, y, rcond=None)
    return np.asarray(coef)


# --- (5) and (12): the sign of f_z -------------------------------------------------------


def test_erratum_5_fz_of_the_tilted_position() -> None:
    f2 = position_dcm(ALPHA, BETA) @ specific_force_level(G)
    printed_fz2 = -G * np.cos(ALPHA) * np.sin(BETA)  # PRINTED eq. (5)
    assert f2[2] > 0  # positive beta raises the +z end (docs/design.md §2)
    assert printed_fz2 == pytest.approx(-f2[2], rel=1e-12)
    assert printed_fz2 != pytest.approx(f2[2], rel=1e-3)
    # Its consequence: k33 from the printed f_z has the wrong sign; ours is right.
    scale = K_SIZE * np.array([1.0, 1.0, -1.0])  # inverted z
    level, tilted = _two_positions(scale)
    printed_k33 = (tilted.mean_accel[2] - level.mean_accel[2]) / printed_fz2
    assert printed_k33 == pytest.approx(-scale[2], rel=1e-9)
    assert two_position_accel(level, tilted, G).scale[2] == pytest.approx(scale[2], rel=1e-9)


def test_erratum_12_k33() -> None:
    scale = K_SIZE * np.array([0.98, 1.01, -1.02])  # inverted z
    level, tilted = _two_positions(scale)
    uz0, uz2 = level.mean_accel[2], tilted.mean_accel[2]
    printed_k33 = (uz0 - uz2) / (G * np.cos(ALPHA) * np.sin(BETA))  # PRINTED eq. (12), k33
    assert printed_k33 == pytest.approx(-scale[2], rel=1e-9)
    result = two_position_accel(level, tilted, G)
    np.testing.assert_allclose(result.scale, scale, rtol=1e-9)
    np.testing.assert_allclose(result.bias, BIAS, atol=1e-8)


# --- (17), (23), (22)/(30)/(34): the Fourier coefficients ---------------------------------


def test_erratum_17_x_coefficients() -> None:
    scale = K_SIZE * np.array([-1.0, 1.0, 1.0])  # inverted x
    data = _fourier_data(scale)
    _, c1x, c2x = _fit(data, 0)
    printed_c1x = scale[0] * G * np.cos(ALPHA0)  # PRINTED eq. (17)
    printed_c2x = scale[0] * G * np.sin(ALPHA0)  # PRINTED eq. (17)
    assert c1x == pytest.approx(-printed_c1x, rel=1e-9)
    assert c2x == pytest.approx(-printed_c2x, rel=1e-9)
    # Solving the printed (17) for k11 returns the wrong sign; ours keeps it.
    a0 = np.arctan(c2x / c1x)
    printed_k11 = c1x / (G * np.cos(a0))  # PRINTED eq. (17) solved for k11
    assert printed_k11 == pytest.approx(-scale[0], rel=1e-9)
    assert fourier_accel(data, G).scale[0] == pytest.approx(scale[0], rel=1e-9)


@pytest.mark.parametrize("sign", [1.0, -1.0], ids=["upright", "inverted-x"])
def test_erratum_23_alpha0(sign: float) -> None:
    data = _fourier_data(K_SIZE * np.array([sign, 1.0, 1.0]))
    _, c1x, c2x = _fit(data, 0)
    printed_a0 = np.arctan(c1x / c2x)  # PRINTED eq. (23): arctg(C1x/C2x)
    assert printed_a0 == pytest.approx(np.sign(ALPHA0) * np.pi / 2 - ALPHA0, abs=1e-9)
    atan2_a0 = np.arctan2(-c2x, -c1x)  # the tempting "fix": right only if k11 > 0
    if sign > 0:
        assert atan2_a0 == pytest.approx(ALPHA0, abs=1e-9)
    else:
        assert np.rad2deg(atan2_a0) == pytest.approx(180.0 + np.rad2deg(ALPHA0), abs=1e-6)
    result = fourier_accel(data, G)
    assert result.value("base_tilt.alpha0.x") == pytest.approx(ALPHA0, abs=1e-10)
    assert result.alpha0 == pytest.approx(ALPHA0, abs=1e-10)


@pytest.mark.parametrize("axis", [0, 1, 2], ids=["k11-eq22", "k22-eq30", "k33-eq34"])
def test_erratum_22_30_34_square_roots(axis: int) -> None:
    scale = K_SIZE * np.array([1.01, 0.99, 1.02])
    scale[axis] *= -1.0  # inverted axis
    data = _fourier_data(scale)
    coef = _fit(data, axis)
    printed_k = np.sqrt(np.sum(coef[1:] ** 2)) / G  # PRINTED eq. (22), (30), (34)
    assert printed_k == pytest.approx(-scale[axis], rel=1e-9)  # reported as a good axis
    result = fourier_accel(data, G)
    np.testing.assert_allclose(result.scale, scale, rtol=1e-9)
    np.testing.assert_allclose(result.bias, BIAS, atol=1e-7)
    assert result.beta0 == pytest.approx(BETA0, abs=1e-10)


# --- (40), (41): the Earth rate -----------------------------------------------------------

S_TRUE = 1.0 / np.deg2rad(1.0 / 16.4)  # counts per rad/s
GYRO_BIAS = np.array([2.0, -3.0, 1.5])


def _gyro_pair(alpha: float, beta: float, scale: Array) -> tuple[PositionAverage, ...]:
    w_level = earth_rate_level(PHI)
    poses = (Pose(0.0, 0.0), Pose(alpha, beta))
    return tuple(
        _gyro_average(p, GYRO_BIAS + scale * (position_dcm(p.alpha, p.beta) @ w_level))
        for p in poses
    )


def _solve_z(v1: float, v2: float, w1: float, w2: float) -> tuple[float, float]:
    """Eq. (47)-(48) for one axis: ``V_i = B + s w_i``."""
    s = (v2 - v1) / (w2 - w1)
    return v1 - s * w1, s


def test_erratum_40_level_earth_rate() -> None:
    w1 = position_dcm(0.0, 0.0) @ earth_rate_level(PHI)
    printed_w1 = np.array([0.0, OMEGA * np.sin(PHI), -OMEGA * np.sin(PHI)])  # PRINTED eq. (40)
    assert w1 == pytest.approx([0.0, -OMEGA * np.sin(PHI), OMEGA * np.cos(PHI)], abs=1e-18)
    assert abs(printed_w1[2] - w1[2]) > OMEGA  # wrong by O(Ω)
    scale = S_TRUE * np.array([1.0, 1.0, -1.0])  # inverted z
    level, tilted = _gyro_pair(ALPHA, BETA, scale)
    assert level.mean_gyro is not None and tilted.mean_gyro is not None
    w2 = position_dcm(ALPHA, BETA) @ earth_rate_level(PHI)  # (41) correct, only (40) printed
    b_z, s_z = _solve_z(level.mean_gyro[2], tilted.mean_gyro[2], printed_w1[2], w2[2])
    assert abs(b_z - GYRO_BIAS[2]) > 0.1 * OMEGA * S_TRUE
    assert abs(s_z / scale[2] - 1.0) > 0.5
    result = nav_gyro_two_position(level, tilted, PHI)
    np.testing.assert_allclose(result.bias, GYRO_BIAS, atol=1e-9)
    np.testing.assert_allclose(result.scale, scale, rtol=1e-9)


def test_erratum_41_tilted_earth_rate_alpha_37() -> None:
    w2 = position_dcm(ALPHA, BETA) @ earth_rate_level(PHI)
    sp, cp = np.sin(PHI), np.cos(PHI)
    printed_wz2 = -OMEGA * sp * np.sin(ALPHA) * np.sin(BETA) + OMEGA * cp * np.cos(BETA)  # PRINTED
    assert printed_wz2 != pytest.approx(w2[2], rel=1e-3)
    w1 = position_dcm(0.0, 0.0) @ earth_rate_level(PHI)
    level, tilted = _gyro_pair(ALPHA, BETA, S_TRUE * np.ones(3))
    assert level.mean_gyro is not None and tilted.mean_gyro is not None
    _, s_z = _solve_z(level.mean_gyro[2], tilted.mean_gyro[2], w1[2], printed_wz2)
    assert abs(s_z / S_TRUE - 1.0) > 0.1
    result = nav_gyro_two_position(level, tilted, PHI)
    assert result.scale[2] == pytest.approx(S_TRUE, rel=1e-9)


def test_erratum_40_41_s33_numbers_at_45_5() -> None:
    """docs/method.md §2: noiseless s33 / truth at φ = 50.45°, (45°, 5°): 0.033, −0.90, 1.000."""
    alpha, beta = np.deg2rad(45.0), np.deg2rad(5.0)
    sp, cp = np.sin(PHI), np.cos(PHI)
    level, tilted = _gyro_pair(alpha, beta, S_TRUE * np.ones(3))
    assert level.mean_gyro is not None and tilted.mean_gyro is not None
    v1, v2 = level.mean_gyro[2], tilted.mean_gyro[2]
    printed_w1z = -OMEGA * sp  # PRINTED eq. (40), z
    printed_w2z = -OMEGA * sp * np.sin(alpha) * np.sin(beta) + OMEGA * cp * np.cos(beta)  # (41)
    w1z = (position_dcm(0.0, 0.0) @ earth_rate_level(PHI))[2]
    w2z = (position_dcm(alpha, beta) @ earth_rate_level(PHI))[2]
    both_printed = _solve_z(v1, v2, printed_w1z, printed_w2z)[1] / S_TRUE
    only_40_corrected = _solve_z(v1, v2, w1z, printed_w2z)[1] / S_TRUE
    both_corrected = _solve_z(v1, v2, w1z, w2z)[1] / S_TRUE
    assert round(both_printed, 3) == 0.033
    assert round(only_40_corrected, 2) == -0.90
    assert round(both_corrected, 3) == 1.000
    result = nav_gyro_two_position(level, tilted, PHI)
    assert result.scale[2] / S_TRUE == pytest.approx(1.0, abs=1e-9)


def test_erratum_frame_paper_gyro_axes_are_left_handed() -> None:
    # In East-North-Up coordinates: the paper's (x East, y Up, z North) against ours
    # (x East, y Down, z North; docs/design.md §2).
    east, north, up = np.eye(3)
    assert np.cross(east, up) == pytest.approx(-north)  # paper's: x × y = −z, left-handed
    assert np.cross(east, -up) == pytest.approx(north)  # ours: right-handed
    # At rest the specific force points up: +g on an Up axis, not the paper's −g.
    assert specific_force_level(G)[1] == -G  # the y axis is Down
    assert earth_rate_level(PHI)[1] == pytest.approx(-OMEGA * np.sin(PHI))  # Ω has an up part
