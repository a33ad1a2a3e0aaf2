"""Frames and attitude: round trips and the documented signs (docs/conventions.md).

Oracles: orthonormality identities, the definition of the passive elementary rotations, and a
central finite difference of the attitude kinematics.
"""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from skynav.scenes import frames

angles = st.floats(min_value=0.0, max_value=2 * np.pi, allow_nan=False)
decs = st.floats(min_value=-1.55, max_value=1.55, allow_nan=False)


@settings(max_examples=200, deadline=None)
@given(angles, decs, angles)
def test_radec_twist_round_trip(ra, dec, twist):
    R = frames.radec_twist_to_dcm(ra, dec, twist)
    assert np.allclose(R @ R.T, np.eye(3), atol=1e-14)
    assert np.linalg.det(R) == pytest.approx(1.0, abs=1e-14)
    ra2, dec2, tw2 = frames.dcm_to_radec_twist(R)
    assert np.allclose(frames.radec_twist_to_dcm(ra2, dec2, tw2), R, atol=1e-12)
    # the boresight is at (ra, dec): third row of R_cam_icrs is camera +z in ICRS
    assert np.allclose(R[2], frames.radec_to_unit(ra, dec), atol=1e-14)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.floats(-1, 1, allow_nan=False), min_size=4, max_size=4))
def test_quaternion_round_trip(qs):
    q = np.array(qs)
    if np.linalg.norm(q) < 1e-3:
        return
    q = q / np.linalg.norm(q)
    R = frames.quat_to_dcm(q)
    assert np.allclose(R @ R.T, np.eye(3), atol=1e-13)
    q2 = frames.dcm_to_quat(R)
    # q and -q are one attitude; q0 >= 0 is returned (sign free when q0 == 0)
    assert np.allclose(q2, q, atol=1e-12) or np.allclose(q2, -q, atol=1e-12)
    assert q2[0] >= 0


def test_quaternion_matches_paper000_eq14_small_rotation():
    # Andreis et al. (2023a), Eq. 14 (passive): for q = (cos(a/2), 0, 0, sin(a/2)), A = R3(a).
    a = 0.3
    q = np.array([np.cos(a / 2), 0.0, 0.0, np.sin(a / 2)])
    assert np.allclose(frames.quat_to_dcm(q), frames.rot3(a), atol=1e-15)


def test_twist_sign_is_documented():
    # At twist 0, +x_cam points to decreasing Dec (south), +y_cam to increasing RA (east).
    ra, dec = 1.1, 0.4
    R0 = frames.radec_twist_to_dcm(ra, dec, 0.0)
    u = frames.radec_to_unit(ra, dec)
    east = np.array([-np.sin(ra), np.cos(ra), 0.0])
    north = np.cross(u, east)
    assert R0[0] @ north == pytest.approx(-1.0, abs=1e-14)
    assert R0[1] @ east == pytest.approx(1.0, abs=1e-14)
    t = 0.25
    Rt = frames.radec_twist_to_dcm(ra, dec, t)
    assert np.allclose(Rt[0], np.cos(t) * R0[0] + np.sin(t) * R0[1], atol=1e-14)


def test_attitude_kinematics_against_finite_difference():
    # dR/dt = -[w x] R with w in the camera frame; central difference, h = 1e-4 s.
    R = frames.radec_twist_to_dcm(0.4, -0.2, 1.0)
    w = np.array([1e-3, -2e-3, 5e-3])
    h = 1e-4
    dR = (frames.propagate_attitude(R, w, h) - frames.propagate_attitude(R, w, -h)) / (2 * h)
    assert np.allclose(dR, -frames.skew(w) @ R, atol=1e-10)


def test_point_boresight():
    u = frames.normalize(np.array([0.3, -0.5, 0.8]))
    R = frames.point_boresight(u, twist_rad=0.7)
    assert np.allclose(R @ u, [0, 0, 1], atol=1e-14)


def test_cross_repeats_numpy_cross(rng):
    """frames.cross (numpy.cross's products and differences without its axis handling) against
    numpy.cross, for one vector, stacks and a vector against a stack: within 2 ulps of the
    largest product (a - b of two rounded products; a wrong component is off by O(1))."""
    from skynav.scenes.frames import cross

    a, b = rng.normal(size=(50, 3)) * 1e8, rng.normal(size=(50, 3))
    for x, y in ((a[0], b[0]), (a, b), (a[0], b), (a, b[0]), ([0.0, 0.0, 1.0], a[3])):
        got, want = cross(x, y), np.cross(x, y)
        assert got.shape == want.shape
        scale = np.abs(np.asarray(x))[..., None, :].max(-1) * np.abs(np.asarray(y))[..., None, :].max(-1)
        assert np.all(np.abs(got - want) <= 2 * np.spacing(scale)), (x, y)
