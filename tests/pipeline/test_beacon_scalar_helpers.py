"""Scalar fast paths of the beacon prediction against the numpy functions they replace:
:func:`skynav.pipeline.beacons._v_mag` against :func:`skynav.scenes.photometry.planet_v_mag`,
and the one-body geometry helpers against their numpy references.

These are two implementations (Python floats and libm against numpy's loops), so they are
compared within a few ulps, never for exact equality: numpy's SIMD ``log10`` and ``arctan2``
differ from libm's in the last bit on some CPUs (AVX-512: 2154 and 7382 of 100k values), so an
exact test passes on one machine and fails on another. The tolerances below are a few
ulps of each transcendental result propagated through the formula, far below anything the
tracking can see (1e-13 mag, 1e-15 rad) and far above a real mistake (a wrong coefficient or
branch moves V by > 1e-4 mag)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from skynav.pipeline.beacons import BEACON_BODIES, _v_mag
from skynav.scenes.constants import AU_KM
from skynav.scenes.photometry import PHASE_RANGE_DEG, planet_v_mag

# every branch point and range end of the phase laws, deg
_EDGES_DEG = (0.0, 1.9, 2.0, 3.1, 6.0, 12.0, 50.0, 120.0, 130.0, 133.0, 150.0, 154.0, 163.7, 170.0, 179.0, 180.0)
# ulps allowed for each log10 of the two sides (libm's and numpy's SIMD loop are each within
# ~1 ulp of the exact value; measured: 1 ulp apart at most, AVX-512 against libm)
_LOG10_ULPS = 4


def _v_mag_tolerance(r_km, d_km, ref):
    """|V_twin - V_numpy| allowed, mag: ``_LOG10_ULPS`` ulps of ``5 log10(r d)`` and of the
    Jupiter law's ``2.5 log10(x)`` (x <= 1), plus 2 ulps of V for the final sum's rounding."""
    lt = abs(math.log10((r_km / AU_KM) * (d_km / AU_KM)))
    return _LOG10_ULPS * (5.0 * np.spacing(lt) + 2.5 * np.spacing(1.0)) + 2.0 * np.spacing(abs(ref))


def _assert_v_mag_close(body, r_km, d_km, alpha_rad):
    ref = float(planet_v_mag(body, r_km, d_km, alpha_rad))
    got = _v_mag(body, r_km, d_km, alpha_rad)
    if np.isnan(ref):
        assert np.isnan(got), (body, r_km, d_km, alpha_rad, got)
        return
    assert abs(got - ref) <= _v_mag_tolerance(r_km, d_km, ref), (body, r_km, d_km, alpha_rad, ref, got)


@pytest.mark.parametrize("body", BEACON_BODIES)
def test_v_mag_agrees_with_planet_v_mag_to_a_few_ulps(body):
    """NaN exactly where the reference is NaN (outside a law's range, at the range ends' next
    floats); elsewhere within :func:`_v_mag_tolerance` (~1e-13 mag)."""
    rng = np.random.default_rng(sum(map(ord, body)))
    alpha = np.concatenate([rng.uniform(0.0, np.pi, 3000), np.deg2rad(_EDGES_DEG),
                            np.nextafter(np.deg2rad(_EDGES_DEG), 4.0), np.nextafter(np.deg2rad(_EDGES_DEG), -1.0),
                            [np.nan, 0.0]])
    r = AU_KM * 10 ** rng.uniform(-0.5, 1.6, alpha.size)
    d = AU_KM * 10 ** rng.uniform(-4.0, 1.6, alpha.size)
    for ri, di, ai in zip(r.tolist(), d.tolist(), alpha.tolist()):
        _assert_v_mag_close(body, ri, di, ai)


def test_v_mag_nan_outside_the_laws_range():
    lo, hi = PHASE_RANGE_DEG["mercury"]
    assert np.isnan(_v_mag("mercury", AU_KM, AU_KM, np.deg2rad(lo) * 0.5))
    assert np.isnan(_v_mag("moon", AU_KM, 384400.0, np.deg2rad(170.0)))
    _assert_v_mag_close("Jupiter", 5.2 * AU_KM, 4.2 * AU_KM, 0.0)  # any case of the name


def test_apparent_one_agrees_with_apparent_direction():
    """Reference: apparent_direction (numpy 3-vectors); observer and bodies from 0.01 to 40 au,
    velocities up to 100 km/s. Only + - * / and sqrt (correctly rounded in both), but numpy may
    sum a dot product in another order: allowed 4 ulps of 1 on the unit vector's components
    (4e-16 rad) and 4 ulps of the largest coordinate on the retarded position and distance."""
    from skynav.pipeline.beacons import _apparent_one, apparent_direction

    eps = np.finfo(float).eps
    rng = np.random.default_rng(31)
    for _ in range(20000):
        r = rng.normal(size=3) * AU_KM * 10 ** rng.uniform(-2, 1.6)
        pos = rng.normal(size=3) * AU_KM * 10 ** rng.uniform(-2, 1.6)
        v, vel = rng.normal(size=3) * 10 ** rng.uniform(-1, 2), rng.normal(size=3) * 10 ** rng.uniform(-1, 2)
        u, p = apparent_direction(r, v, pos, vel)
        ul, pl, dist = _apparent_one(r.tolist(), v.tolist(), pos.tolist(), vel.tolist())
        scale = 4 * np.spacing(max(np.abs(p).max(), np.abs(r).max()))
        assert np.all(np.abs(np.subtract(ul, u)) <= 4 * eps), (ul, u)
        assert np.all(np.abs(np.subtract(pl, p)) <= scale), (pl, p)
        assert abs(dist - float(np.linalg.norm(p - r))) <= scale


def test_phase_angle_one_agrees_with_phase_angles():
    """Reference: _phase_angles (numpy, itself photometry.phase_angle_rad's operations). libm's
    ``atan2`` against numpy's (SIMD on some CPUs): measured 1 ulp apart at most (933 of 20000
    differ on AVX-512, none on the baseline path); allowed 4 ulps."""
    from skynav.pipeline.beacons import _phase_angle_one, _phase_angles

    rng = np.random.default_rng(32)
    p = rng.normal(size=(20000, 3)) * AU_KM * 10 ** rng.uniform(-2, 1.6, (20000, 1))
    sun = rng.normal(size=3) * 1e6
    r = rng.normal(size=3) * AU_KM
    want = _phase_angles(p, sun, r)
    got = np.array([_phase_angle_one(pi, sun.tolist(), r.tolist()) for pi in p.tolist()])
    np.testing.assert_array_max_ulp(got, want, maxulp=4)


def test_camera_constants_follow_the_camera_object():
    """Reference: the Camera properties themselves, for two cameras used in turn (a cache of
    the same code's values: exact)."""
    from skynav.pipeline.beacons import _camera_constants
    from skynav.scenes.camera import Camera

    a = Camera(width=1024, height=1024, focal_length_mm=50.0, pixel_pitch_um=5.5)
    b = Camera(width=640, height=480, focal_length_mm=20.0, pixel_pitch_um=4.8, pixel_pitch_y_um=5.0)
    for cam in (a, b, a, a, b):
        assert _camera_constants(cam) == (cam.fx_px, cam.fy_px, cam.half_diagonal_fov_rad)
