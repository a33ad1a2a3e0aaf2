"""Camera geometry: pixel convention, round trips (hypothesis), distortion inverse."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from skynav.scenes.camera import BrownConrady, Camera, paper_camera
from skynav.scenes.errors import ConfigValueError


def test_paper_camera_matches_paper002_table4():
    cam = paper_camera()
    assert math.degrees(cam.fov_x_rad) == pytest.approx(20.0, abs=1e-5)
    assert (cam.width, cam.height) == (1024, 1024)
    assert cam.focal_length_mm == 40.0 and cam.f_number == 2.2 and cam.exposure_s == 0.4
    assert cam.defocus_sigma_px == 0.5 and cam.cosmic_rays_per_frame == 1
    assert math.degrees(cam.sun_exclusion_rad) == pytest.approx(20.0)
    wl = np.array(cam.response_wavelengths_nm)
    qe = np.array(cam.response_qe_t)
    band = (wl >= 400) & (wl <= 900)
    assert np.trapezoid(qe[band], wl[band]) / 500.0 == pytest.approx(0.49, abs=1e-4)


def test_boresight_lands_on_principal_point_and_pixel_centres():
    cam = paper_camera()
    assert np.allclose(cam.project(np.array([[0, 0, 1.0]])), [[511.5, 511.5]])
    # the centre of the top-left pixel is (0, 0): its direction projects back to (0, 0)
    v = cam.back_project(np.array([[0.0, 0.0]]))
    assert np.allclose(cam.project(v), [[0.0, 0.0]], atol=1e-9)
    assert cam.in_image(np.array([[-0.49, -0.49]]))[0] and not cam.in_image(np.array([[-0.51, 0.0]]))[0]


DIST = BrownConrady(k1=-0.08, k2=0.02, k3=-0.003, p1=4e-4, p2=-3e-4)


@settings(max_examples=300, deadline=None)
@given(st.floats(-0.5, 1023.5), st.floats(-0.5, 1023.5), st.booleans())
def test_pixel_direction_pixel_round_trip(x, y, distorted):
    cam = paper_camera(distortion=DIST) if distorted else paper_camera()
    xy = np.array([[x, y]])
    xy2 = cam.project(cam.back_project(xy))
    assert np.max(np.abs(xy2 - xy)) <= 1e-6  # acceptance: 1e-6 px


def test_distortion_inverse_against_forward_map():
    rng = np.random.default_rng(1)
    xn, yn = rng.uniform(-0.2, 0.2, (2, 10000))
    xd, yd = DIST.distort(xn, yn)
    xu, yu = DIST.undistort(xd, yd)
    assert np.max(np.hypot(xu - xn, yu - yn)) < 1e-14


def test_from_fov_and_bad_values():
    cam = Camera.from_fov(fov_rad=math.radians(20), width=1024, height=1024, pixel_pitch_um=13.775545367848826)
    assert cam.focal_length_mm == pytest.approx(40.0, rel=1e-9)
    with pytest.raises(ConfigValueError, match="camera.exposure_s"):
        paper_camera(exposure_s=-1.0)
    with pytest.raises(ConfigValueError, match="sensor.bit_depth"):
        from skynav.scenes.camera import SensorParams

        SensorParams(bit_depth=20)


def test_camera_value_semantics():
    import pickle

    cam = paper_camera(distortion=DIST)
    assert pickle.loads(pickle.dumps(cam)) == cam
    assert hash(cam) == hash(paper_camera(distortion=DIST))
    from skynav.scenes.camera import SensorParams  # noqa: F401  (names for eval)

    assert eval(repr(cam)) == cam


def test_camera_is_a_projection_and_line_of_sight_inverts_project():
    """The pinhole + Brown-Conrady camera satisfies the Projection protocol; round trip < 1e-6 px."""
    from skynav.scenes.camera import BrownConrady, paper_camera
    from skynav.scenes.projection import Projection

    cam = paper_camera(distortion=BrownConrady(k1=-0.05, p1=1e-4))
    assert isinstance(cam, Projection)
    rng = np.random.default_rng(3)
    xy = rng.uniform(-0.5, 1023.5, size=(500, 2))
    v = cam.line_of_sight(xy)
    assert np.allclose(np.linalg.norm(v, axis=-1), 1.0, atol=1e-14)
    assert np.max(np.abs(cam.project(v) - xy)) < 1e-6  # px: Newton undistortion converges to 1e-15
