"""Scalar fast paths of the beacon prediction against the numpy functions they replace
(bit for bit): :func:`skynav.pipeline.beacons._v_mag` against
:func:`skynav.scenes.photometry.planet_v_mag`."""

from __future__ import annotations

import numpy as np
import pytest

from skynav.pipeline.beacons import BEACON_BODIES, _v_mag
from skynav.scenes.constants import AU_KM
from skynav.scenes.photometry import PHASE_RANGE_DEG, planet_v_mag

# every branch point and range end of the phase laws, deg
_EDGES_DEG = (0.0, 1.9, 2.0, 3.1, 6.0, 12.0, 50.0, 120.0, 130.0, 133.0, 150.0, 154.0, 163.7, 170.0, 179.0, 180.0)


@pytest.mark.parametrize("body", BEACON_BODIES)
def test_v_mag_bit_identical_to_planet_v_mag(body):
    rng = np.random.default_rng(sum(map(ord, body)))
    alpha = np.concatenate([rng.uniform(0.0, np.pi, 3000), np.deg2rad(_EDGES_DEG),
                            np.nextafter(np.deg2rad(_EDGES_DEG), 4.0), np.nextafter(np.deg2rad(_EDGES_DEG), -1.0),
                            [np.nan, 0.0]])
    r = AU_KM * 10 ** rng.uniform(-0.5, 1.6, alpha.size)
    d = AU_KM * 10 ** rng.uniform(-4.0, 1.6, alpha.size)
    for ri, di, ai in zip(r.tolist(), d.tolist(), alpha.tolist()):
        ref = float(planet_v_mag(body, ri, di, ai))
        got = _v_mag(body, ri, di, ai)
        assert (np.isnan(ref) and np.isnan(got)) or ref == got, (body, ri, di, ai, ref, got)


def test_v_mag_nan_outside_the_laws_range():
    lo, hi = PHASE_RANGE_DEG["mercury"]
    assert np.isnan(_v_mag("mercury", AU_KM, AU_KM, np.deg2rad(lo) * 0.5))
    assert np.isnan(_v_mag("moon", AU_KM, 384400.0, np.deg2rad(170.0)))
    assert _v_mag("Jupiter", 5.2 * AU_KM, 4.2 * AU_KM, 0.0) == float(planet_v_mag("jupiter", 5.2 * AU_KM, 4.2 * AU_KM, 0.0))


def test_apparent_one_bit_identical_to_apparent_direction():
    """Reference: apparent_direction (numpy 3-vectors); observer and bodies from 0.01 to 40 au,
    velocities up to 100 km/s."""
    from skynav.pipeline.beacons import _apparent_one, apparent_direction

    rng = np.random.default_rng(31)
    for _ in range(20000):
        r = rng.normal(size=3) * AU_KM * 10 ** rng.uniform(-2, 1.6)
        pos = rng.normal(size=3) * AU_KM * 10 ** rng.uniform(-2, 1.6)
        v, vel = rng.normal(size=3) * 10 ** rng.uniform(-1, 2), rng.normal(size=3) * 10 ** rng.uniform(-1, 2)
        u, p = apparent_direction(r, v, pos, vel)
        ul, pl, dist = _apparent_one(r.tolist(), v.tolist(), pos.tolist(), vel.tolist())
        assert ul == u.tolist() and pl == p.tolist()
        assert dist == float(np.linalg.norm(p - r))


def test_phase_angle_one_bit_identical_to_phase_angles():
    """Reference: _phase_angles (numpy, itself photometry.phase_angle_rad's operations)."""
    from skynav.pipeline.beacons import _phase_angle_one, _phase_angles

    rng = np.random.default_rng(32)
    p = rng.normal(size=(20000, 3)) * AU_KM * 10 ** rng.uniform(-2, 1.6, (20000, 1))
    sun = rng.normal(size=3) * 1e6
    r = rng.normal(size=3) * AU_KM
    want = _phase_angles(p, sun, r).tolist()
    got = [_phase_angle_one(pi, sun.tolist(), r.tolist()) for pi in p.tolist()]
    assert got == want


def test_camera_constants_follow_the_camera_object():
    """Reference: the Camera properties themselves, for two cameras used in turn."""
    from skynav.pipeline.beacons import _camera_constants
    from skynav.scenes.camera import Camera

    a = Camera(width=1024, height=1024, focal_length_mm=50.0, pixel_pitch_um=5.5)
    b = Camera(width=640, height=480, focal_length_mm=20.0, pixel_pitch_um=4.8, pixel_pitch_y_um=5.0)
    for cam in (a, b, a, a, b):
        assert _camera_constants(cam) == (cam.fx_px, cam.fy_px, cam.half_diagonal_fov_rad)
