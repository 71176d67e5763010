"""Property tests of canimucal.model.frames against docs/design.md §2 and docs/method.md §1."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from numpy.typing import NDArray

from canimucal.model.frames import (
    EARTH_RATE_RAD_S,
    TiltModel,
    a1,
    a2,
    ay,
    body_vectors,
    earth_rate_level,
    gravity_direction_angles,
    position_dcm,
    specific_force_level,
)

Array = NDArray[np.float64]
G = 9.80665
DEG = np.pi / 180.0

angle = st.floats(-np.pi, np.pi, allow_nan=False)
tilt = st.floats(-0.2, 0.2, allow_nan=False)  # a base tilt, |angle| ≤ 0.2 rad (docs/design.md §4)
small_tilt = st.floats(1e-5, 1e-3, allow_nan=False) | st.floats(-1e-3, -1e-5, allow_nan=False)
latitude = st.floats(-np.pi / 2, np.pi / 2, allow_nan=False)
model = st.sampled_from(["rigid", "additive"])
PROPS = settings(derandomize=True, deadline=None, max_examples=200)


def _rz(t: float) -> Array:
    """Active right-hand rotation about z."""
    c, s = np.cos(t), np.sin(t)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _rx(t: float) -> Array:
    """Active right-hand rotation about x."""
    c, s = np.cos(t), np.sin(t)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def _ry(t: float) -> Array:
    """Active right-hand rotation about y."""
    c, s = np.cos(t), np.sin(t)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


@PROPS
@given(angle, angle, angle, angle, angle, model)
def test_dcm_is_a_rotation(
    alpha: float, beta: float, psi: float, alpha0: float, beta0: float, tilt_model: TiltModel
) -> None:
    c = position_dcm(alpha, beta, psi, alpha0, beta0, tilt_model)
    np.testing.assert_allclose(c @ c.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(c) == pytest.approx(1.0, abs=1e-12)


@PROPS
@given(angle)
def test_elementary_rotations_are_rotations(t: float) -> None:
    for m in (a1(t), a2(t), ay(t)):
        np.testing.assert_allclose(m @ m.T, np.eye(3), atol=1e-14)
        assert np.linalg.det(m) == pytest.approx(1.0, abs=1e-14)


@pytest.mark.parametrize("lat_deg", [50.45, -33.0, 0.0])
def test_design_anchors(lat_deg: float) -> None:
    phi = lat_deg * DEG
    f_level = specific_force_level(G)
    w_level = earth_rate_level(phi)
    np.testing.assert_allclose(position_dcm(90 * DEG, 0.0) @ f_level, [-G, 0, 0], atol=1e-12)
    np.testing.assert_allclose(position_dcm(0.0, 90 * DEG) @ f_level, [0, 0, G], atol=1e-12)
    omega = EARTH_RATE_RAD_S
    expected = [0.0, -omega * np.sin(phi), -omega * np.cos(phi)]
    np.testing.assert_allclose(position_dcm(0.0, 0.0, 180 * DEG) @ w_level, expected, atol=1e-18)
    np.testing.assert_allclose(w_level, [0, -omega * np.sin(phi), omega * np.cos(phi)], atol=0)


@PROPS
@given(st.floats(1e-3, np.pi / 2 - 1e-3), st.floats(1e-3, np.pi / 2 - 1e-3))
def test_physical_senses(positive_a: float, positive_b: float) -> None:
    f_level = specific_force_level(G)
    # Positive alpha lowers the +x end: the up-pointing specific force projects negatively on x.
    assert (position_dcm(positive_a, 0.0) @ f_level)[0] < 0
    # Positive beta raises the +z end: f_z > 0.
    assert (position_dcm(0.0, positive_b) @ f_level)[2] > 0
    # Positive psi turns +z toward +x (clockwise seen from above, y being Down): body z, in L,
    # is row 3 of C (C is body <- L); it gains a +x (East, the old +x) component.
    body_z_in_level = position_dcm(0.0, 0.0, positive_a)[2]
    assert body_z_in_level[0] > 0 and body_z_in_level[1] == 0.0
    # Clockwise seen from above (looking along +y, Down) is a positive turn about +y.
    np.testing.assert_allclose(position_dcm(0.0, 0.0, positive_a).T, _ry(positive_a), atol=1e-15)


@PROPS
@given(angle, angle, angle, angle, angle)
def test_rigid_is_transpose_of_active_rotations(
    alpha: float, beta: float, psi: float, alpha0: float, beta0: float
) -> None:
    active = _rz(alpha0) @ _rx(beta0) @ _rz(alpha) @ _rx(beta) @ _ry(psi)
    c = position_dcm(alpha, beta, psi, alpha0, beta0, "rigid")
    np.testing.assert_allclose(c, active.T, atol=1e-12)


@PROPS
@given(angle, angle, angle, angle)
def test_additive_equals_rigid_when_beta0_is_zero(
    alpha: float, beta: float, psi: float, alpha0: float
) -> None:
    rigid = position_dcm(alpha, beta, psi, alpha0, 0.0, "rigid")
    additive = position_dcm(alpha, beta, psi, alpha0, 0.0, "additive")
    np.testing.assert_allclose(rigid, additive, atol=1e-12)


@PROPS
@given(st.floats(-np.pi / 2, np.pi / 2), st.floats(-0.2, 0.2), small_tilt)
def test_rigid_minus_additive_first_order(alpha: float, beta: float, beta0: float) -> None:
    """docs/method.md §1: rigid − additive = +g·β0·(1 − cos α)·[0, sin β, cos β] + O(β0²) (α0 = 0).

    The sign, from the math: rigid z = g cos α sin β + g β0 cos β, additive z =
    g cos α sin(β + β0) ≈ g cos α sin β + g β0 cos α cos β; the difference is
    +g β0 (1 − cos α) cos β, and likewise +g β0 (1 − cos α) sin β on y; x agrees to O(β0²).
    """
    f_level = specific_force_level(G)
    rigid = position_dcm(alpha, beta, 0.0, 0.0, beta0, "rigid") @ f_level
    additive = position_dcm(alpha, beta, 0.0, 0.0, beta0, "additive") @ f_level
    first_order = G * beta0 * (1.0 - np.cos(alpha)) * np.array([0.0, np.sin(beta), np.cos(beta)])
    # The second-order remainder is bounded by g·β0² (|rotation error| ≤ β0²/2 twice over).
    np.testing.assert_allclose(rigid - additive, first_order, rtol=0, atol=G * beta0**2)


@PROPS
@given(st.floats(-np.pi / 2, np.pi / 2), st.floats(-0.2, 0.2), small_tilt, small_tilt)
def test_rigid_minus_additive_first_order_with_alpha0(
    alpha: float, beta: float, beta0: float, alpha0: float
) -> None:
    # With α0 ≠ 0 the exact first-order term is g·β0·(cos α0 − cos(α + α0)); docs/method.md's
    # (1 − cos α) differs from it by at most |α0| + α0²/2: first order in the tilts overall.
    f_level = specific_force_level(G)
    rigid = position_dcm(alpha, beta, 0.0, alpha0, beta0, "rigid") @ f_level
    additive = position_dcm(alpha, beta, 0.0, alpha0, beta0, "additive") @ f_level
    first_order = G * beta0 * (1.0 - np.cos(alpha)) * np.array([0.0, np.sin(beta), np.cos(beta)])
    bound = G * (beta0**2 + abs(beta0) * (abs(alpha0) + alpha0**2))
    np.testing.assert_allclose(rigid - additive, first_order, rtol=0, atol=bound)


@PROPS
@given(st.floats(0.3, np.pi / 2), st.floats(-0.2, 0.2), small_tilt)
def test_rigid_minus_additive_is_really_first_order(
    alpha: float, beta: float, beta0: float
) -> None:
    # The difference is not a second-order artefact: with 1 − cos α ≥ 0.04 and |β| ≤ 0.2
    # its z part exceeds the remainder bound g·β0², so a wrong sign fails above.
    f_level = specific_force_level(G)
    rigid = position_dcm(alpha, beta, 0.0, 0.0, beta0, "rigid") @ f_level
    additive = position_dcm(alpha, beta, 0.0, 0.0, beta0, "additive") @ f_level
    assert abs(rigid[2] - additive[2]) > 2 * G * beta0**2
    assert np.sign(rigid[2] - additive[2]) == np.sign(beta0)


@PROPS
@given(latitude, angle)
def test_heading_turns_the_earth_rate_about_the_vertical(phi: float, heading: float) -> None:
    w0 = earth_rate_level(phi, 0.0)
    w = earth_rate_level(phi, heading)
    np.testing.assert_allclose(w, ay(heading) @ w0, atol=1e-20)
    assert w[1] == w0[1]  # the vertical part is unchanged
    # Body z (heading clockwise from North) sees Ω cos φ cos h.
    assert w[2] == pytest.approx(EARTH_RATE_RAD_S * np.cos(phi) * np.cos(heading), abs=1e-20)
    assert np.linalg.norm(w) == pytest.approx(EARTH_RATE_RAD_S, rel=1e-12)


@PROPS
@given(
    st.floats(-np.pi / 2 + 1e-6, np.pi / 2 - 1e-6),
    st.floats(-np.pi + 1e-6, np.pi - 1e-6),
    st.floats(0.1, 100.0),
)
def test_gravity_direction_angles_inverts_the_dcm(alpha: float, beta: float, g: float) -> None:
    f = position_dcm(alpha, beta) @ specific_force_level(g)
    alpha_back, beta_back = gravity_direction_angles(f)
    assert alpha_back == pytest.approx(alpha, abs=1e-9)
    # beta is undefined when the x axis is vertical (|cos alpha| small); check where defined.
    if np.cos(alpha) > 1e-4:
        assert beta_back == pytest.approx(beta, abs=1e-9)


def test_gravity_direction_angles_rejects_zero() -> None:
    with pytest.raises(ValueError, match="zero specific force"):
        gravity_direction_angles([0.0, 0.0, 0.0])


@PROPS
@given(st.lists(st.tuples(angle, angle, angle), min_size=1, max_size=4), tilt, tilt, model)
def test_body_vectors_matches_position_dcm(
    rows: list[tuple[float, float, float]], alpha0: float, beta0: float, tilt_model: TiltModel
) -> None:
    out = body_vectors(rows, specific_force_level(G), alpha0, beta0, tilt_model)
    for row, vec in zip(rows, out, strict=True):
        c = position_dcm(*row, alpha0=alpha0, beta0=beta0, tilt_model=tilt_model)
        np.testing.assert_allclose(vec, c @ specific_force_level(G), atol=1e-12)
