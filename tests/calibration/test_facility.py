"""The facility model: inverse accuracy, file round trip, coverage, radiometry."""

import math

import numpy as np
import pytest

from skynav.infra.errors import ConfigValueError
from skynav.scenes.constants import ARCSEC_RAD
from skynav.scenes.facility import FlatField, facility_from_mapping, screen_preset, screen_small_preset
from skynav.scenes.screen import GeometricModel, ResidualField, ScreenProjection
from skynav.scenes.projection import Projection


def _bent(screen, roll_rad=0.004):
    x = np.linspace(-0.5, screen.width_px - 0.5, 9)
    X, Y = np.meshgrid(x / screen.width_px, x / screen.height_px)
    res = ResidualField(x_px=x, y_px=x, dx_rad=3 * ARCSEC_RAD * np.sin(6 * X + Y), dy_rad=3 * ARCSEC_RAD * np.cos(4 * Y - X))
    return GeometricModel(focal_length_mm=50.3, decentre_x_mm=0.2, decentre_y_mm=-0.1, tilt_x_rad=0.01, tilt_y_rad=-0.02,
                          roll_rad=roll_rad, k1=0.05, k2=-0.02, p1=4e-4, p2=-6e-4, misalignment_rad=(1e-3, -2e-3, 5e-4), residual=res)


@pytest.mark.parametrize("roll_rad", [0.004, math.pi / 2 + 0.003, math.pi])
def test_inverse_accurate_to_a_hundredth_of_an_arcsec_everywhere(roll_rad):
    f = screen_preset()
    P = ScreenProjection(screen=f.screen, model=_bent(f.screen, roll_rad))
    assert isinstance(P, Projection)
    rng = np.random.default_rng(5)
    edges = np.array([[-0.5, -0.5], [2559.5, 2559.5], [-0.5, 2559.5], [2559.5, -0.5]])
    xy = np.concatenate([rng.uniform(-0.5, 2559.5, (20000, 2)), edges])
    v = P.line_of_sight(xy)
    xy2 = P.project(v)
    ang = np.linalg.norm(np.cross(P.line_of_sight(xy2), v), axis=-1) / ARCSEC_RAD
    assert ang.max() < 0.01  # the requirement
    assert np.abs(xy2 - xy).max() < 1e-6
    assert np.allclose(np.linalg.norm(v, axis=-1), 1.0)


def test_file_form_round_trip_and_fixed_keys():
    f = screen_preset()
    g = _bent(f.screen)
    flat = FlatField(x_px=[0, 1279.5, 2559], y_px=[0, 1279.5, 2559], relative=[[0.8, 0.9, 0.8], [0.9, 1.0, 0.9], [0.8, 0.9, 0.8]])
    f2 = f.replace(geometric=g, flat_field=flat)
    m = f2.to_mapping()
    for key in ("width_px", "height_px", "pixel_pitch_um", "bit_depth"):
        assert key in m["screen"]
    assert m["collimator"]["focal_length_mm"] == g.focal_length_mm
    assert m["schema"] == "skynav.facility/1" and "geometric" in m and "radiometric" in m and "camera" in m
    back = facility_from_mapping(m)
    xy = np.array([[10.0, 20.0], [1500.0, 2000.0]])
    assert np.allclose(back.projection.line_of_sight(xy), f2.projection.line_of_sight(xy), atol=1e-15, rtol=0)
    assert np.allclose(back.flat(xy), f2.flat(xy))
    assert back.radiometric == f2.radiometric and back.camera == f2.camera


def test_presets_cover_the_field_with_two_screen_px_per_camera_px():
    for f in (screen_preset(), screen_small_preset()):
        f.check_coverage()
        scale = f.geometric.focal_length_mm / (f.screen.pixel_pitch_um * 1e-3) / f.camera.focal_length_px
        assert scale >= 2.0
        assert abs(math.degrees(f.camera.fov_x_rad) - 20.0) < 1e-9


def test_a_screen_too_small_is_refused():
    f = screen_preset()
    small = f.replace(screen=type(f.screen)(width_px=1800, height_px=1800, pixel_pitch_um=8.0, bit_depth=10))
    small = small.replace(radiometric=f.radiometric)
    with pytest.raises(ConfigValueError, match="cover"):
        small.check_coverage()


def test_radiometric_curve_monotone_and_inverse():
    rm = screen_preset().radiometric
    dn = np.arange(0, rm.max_dn + 1)
    e = rm.irradiance_w_m2(dn)
    assert np.all(np.diff(e) > 0)
    assert np.allclose(rm.digital_count(e), dn, atol=1e-9)


def test_electrons_per_watt_use_the_screen_spectrum_not_broadband_watts():
    f = screen_preset()
    k = f.electrons_per_s_per_w_m2()
    # equal spectra: a screen emitting like a 550 nm line gives A * QE(550) * photons per joule at 550 nm
    line = f.replace(screen_spectrum=((549.0, 550.0, 551.0), (0.0, 1.0, 0.0)))
    qe = np.interp(550.0, f.camera.response_wavelengths_nm, f.camera.response_qe_t)
    expect = f.camera.aperture_area_m2 * qe * 550e-9 / (6.62607015e-34 * 299792458.0)
    assert abs(line.electrons_per_s_per_w_m2() / expect - 1) < 1e-3
    assert abs(k / expect - 1) > 0.01  # the default screen spectrum differs from a line
