"""The planet-pixel measurement model: Jacobian against central differences, cases, case 2."""

import numpy as np
import pytest

from skynav.pipeline.measurement import CASES, LightCorrections, deaberrate_pixel, planet_pixel
from skynav.scenes.camera import paper_camera
from skynav.scenes.distortion import BrownConrady
from skynav.scenes.constants import AU_KM


def _look_at(u):
    """A passive attitude whose boresight is ``u`` (small twist)."""
    z = u / np.linalg.norm(u)
    x = np.cross([0.1, 0.2, 1.0], z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return np.vstack([x, y, z])


def _geometry():
    r = np.array([1.0, 0.2, 0.05]) * AU_KM
    v = np.array([-5.0, 28.0, 3.0])
    rp = np.array([-0.3, 1.45, 0.6]) * AU_KM
    vp = np.array([-22.0, -3.0, -1.0])
    # point slightly off the planet so the projection is off-centre (distortion matters)
    R = _look_at(rp - r + np.array([2e6, -1e6, 3e6]))
    return r, v, rp, vp, R


@pytest.mark.parametrize("case", [1, 2, 3, 4, 5])
@pytest.mark.parametrize("distorted", [False, True])
def test_jacobian_against_central_differences(case, distorted):
    cam = paper_camera()
    if distorted:
        cam = cam.replace(distortion=BrownConrady(k1=-0.05, k2=0.01, p1=1e-4, p2=-2e-4))
    r, v, rp, vp, R = _geometry()
    m = planet_pixel(r, v, rp, vp, R, cam, corrections=CASES[case])
    assert np.all(np.abs(m.xy_px - 511.5) < 511.5)
    num = np.zeros((2, 6))
    x0 = np.concatenate([r, v])
    steps = np.array([1e3] * 3 + [1e-2] * 3)  # km, km/s: pure pixel curvature is tiny at these steps
    for j in range(6):
        xp, xm = x0.copy(), x0.copy()
        xp[j] += steps[j]
        xm[j] -= steps[j]
        fp = planet_pixel(xp[:3], xp[3:], rp, vp, R, cam, corrections=CASES[case]).xy_px
        fm = planet_pixel(xm[:3], xm[3:], rp, vp, R, cam, corrections=CASES[case]).xy_px
        num[:, j] = (fp - fm) / (2 * steps[j])
    for j in range(6):
        col = m.H[:, j]
        if not CASES[case].aberration and j >= 3:
            assert np.all(col == 0.0)
            continue
        scale = np.linalg.norm(num[:, j])
        assert np.linalg.norm(col - num[:, j]) <= 1e-6 * scale, (j, col, num[:, j])


def test_light_time_and_aberration_sizes():
    cam = paper_camera()
    r, v, rp, vp, R = _geometry()
    full = planet_pixel(r, v, rp, vp, R, cam, corrections=CASES[1])
    none = planet_pixel(r, v, rp, vp, R, cam, corrections=CASES[3])
    lt = planet_pixel(r, v, rp, vp, R, cam, corrections=CASES[5])
    dist = np.linalg.norm(rp - r)
    assert full.light_time_s == pytest.approx(dist / 299792.458, rel=1e-3)
    ifov_arcsec = np.degrees(cam.ifov_rad) * 3600
    # light-time shift ~ |v_p,perp| tau / dist, aberration ~ |v_perp| / c: both tens of arcsec
    assert 5.0 < np.linalg.norm(lt.xy_px - none.xy_px) * ifov_arcsec < 200.0
    assert np.linalg.norm(full.xy_px - lt.xy_px) * ifov_arcsec > 5.0


def test_case_two_deaberration_matches_model():
    """De-aberrating the measurement and modelling light-time only equals case 1 to first order."""
    cam = paper_camera().replace(distortion=BrownConrady(k1=-0.05))
    r, v, rp, vp, R = _geometry()
    z1 = planet_pixel(r, v, rp, vp, R, cam, corrections=CASES[1]).xy_px
    z2 = planet_pixel(r, v, rp, vp, R, cam, corrections=CASES[2]).xy_px
    assert np.linalg.norm(z1 - z2) > 0.1
    assert np.linalg.norm(deaberrate_pixel(z1, v, R, cam) - z2) < 1e-3


def test_aberration_in_model_and_measurement_is_refused():
    with pytest.raises(ValueError):
        LightCorrections(aberration=True, deaberrate_measurement=True)


def test_lambert_photocentre_offset_limits_and_direction():
    from skynav.pipeline.measurement import lambert_photocentre_offset

    assert lambert_photocentre_offset(0.0) == 0.0
    assert lambert_photocentre_offset(np.pi) == pytest.approx(9 * np.pi / 32)
    assert lambert_photocentre_offset(np.pi - 1e-3) == pytest.approx(9 * np.pi / 32, rel=1e-4)
    assert lambert_photocentre_offset(np.radians(120)) == pytest.approx(0.7456, abs=1e-3)
    cam = paper_camera()
    r, v, rp, vp, R = _geometry()
    sun = np.zeros(3)
    plain = planet_pixel(r, v, rp, vp, R, cam)
    lit = planet_pixel(r, v, rp, vp, R, cam, sun_position_km=sun, planet_radius_km=6000.0)
    # the shift points towards the Sun's projection as seen from the planet
    toward = cam.project((R @ (rp + 1e6 * (sun - rp) / np.linalg.norm(sun - rp) - r))[None])[0] - plain.xy_px
    shift = lit.xy_px - plain.xy_px
    assert 0 < np.linalg.norm(shift) < 0.1 and shift @ toward > 0.99 * np.linalg.norm(shift) * np.linalg.norm(toward)
    # the Jacobian that ignores the offset's own derivative stays within 1e-3
    assert np.abs(lit.H - plain.H).max() < 1e-3 * np.abs(plain.H).max()


@pytest.mark.parametrize("phase_deg", [30.0, 90.0, 120.6, 146.4])
def test_saturated_photocentre_is_the_lit_area_centroid(phase_deg):
    """Independent check of 4/(3 pi)(1 - cos a): the centroid of the lit region of a unit disc,
    rasterised on a 2001^2 grid (a point of the disc is lit when the sphere's normal there faces
    the Sun: X sin a + Z cos a > 0). Grid step 1e-3 radius: agreement to 2e-3 radius (0.005 px for
    the Earth's 2.4 px radius early in the cruise, far below its 0.1 px centroid noise)."""
    from skynav.pipeline.measurement import saturated_photocentre_offset

    a = np.radians(phase_deg)
    g = np.linspace(-1.0, 1.0, 2001)
    X, Y = np.meshgrid(g, g)
    inside = X * X + Y * Y <= 1.0
    Z = np.sqrt(np.clip(1.0 - X * X - Y * Y, 0.0, None))
    lit = inside & (X * np.sin(a) + Z * np.cos(a) > 0.0)
    assert float(saturated_photocentre_offset(a)) == pytest.approx(float(X[lit].mean()), abs=2e-3)
    assert float(saturated_photocentre_offset(0.0)) == 0.0


def test_saturated_law_moves_the_model_less_than_lambert_at_crescent_phase():
    from skynav.pipeline.measurement import lambert_photocentre_offset, saturated_photocentre_offset

    cam = paper_camera()
    r, v, rp, vp, R = _geometry()
    sun = rp + 1.5e8 * np.array([0.0, 0.0, 1.0])   # Sun behind the planet's side: a crescent
    plain = planet_pixel(r, v, rp, vp, R, cam)
    lam = planet_pixel(r, v, rp, vp, R, cam, sun_position_km=sun, planet_radius_km=6000.0)
    sat = planet_pixel(r, v, rp, vp, R, cam, sun_position_km=sun, planet_radius_km=6000.0, photocentre="saturated")
    d_lam, d_sat = np.linalg.norm(lam.xy_px - plain.xy_px), np.linalg.norm(sat.xy_px - plain.xy_px)
    to_sun = (sun - rp) / np.linalg.norm(sun - rp)
    los = (rp - r) / np.linalg.norm(rp - r)
    phase = np.arccos(-los @ to_sun)
    ratio = float(saturated_photocentre_offset(phase) / lambert_photocentre_offset(phase))
    assert d_sat == pytest.approx(ratio * d_lam, rel=1e-4)   # phase here without light time: 3e-5
    assert (sat.xy_px - plain.xy_px) @ (lam.xy_px - plain.xy_px) > 0


def test_spot_saturated():
    from skynav.pipeline.measurement import spot_saturated

    img = np.zeros((20, 30), dtype=np.uint8)
    img[10, 12] = 255
    assert spot_saturated(img, (12.0, 10.0), 1.5, 255)
    assert spot_saturated(img, (14.2, 10.0), 2.5, 255)
    assert not spot_saturated(img, (17.0, 10.0), 2.5, 255)
    assert not spot_saturated(img, (100.0, 100.0), 3.0, 255)   # off the image
    img[10, 12] = 254
    assert not spot_saturated(img, (12.0, 10.0), 3.0, 255)
