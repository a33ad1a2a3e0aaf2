"""Camera geometry: pixel convention, round trips (hypothesis), distortion inverse."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from skynav.infra.errors import ConfigValueError
from skynav.scenes.camera import Camera, paper_camera
from skynav.scenes.distortion import BrownConrady


def test_paper_camera_matches_paper002_table4():
    cam = paper_camera()
    assert math.degrees(cam.fov_x_rad) == pytest.approx(20.0, abs=1e-5)
    assert (cam.width, cam.height) == (1024, 1024)
    assert cam.focal_length_mm == 40.0 and cam.f_number == 2.2 and cam.exposure_s == 0.4
    assert cam.defocus_sigma_px == 0.5
    assert cam.fx_px == cam.fy_px == cam.focal_length_px  # square pixels
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
    from skynav.scenes.psf import GaussianPSFModel  # noqa: F401  (names for eval)

    assert eval(repr(cam)) == cam


def test_camera_is_a_projection_and_line_of_sight_inverts_project():
    """The pinhole + Brown-Conrady camera satisfies the Projection protocol; round trip < 1e-6 px."""
    from skynav.scenes.camera import paper_camera
    from skynav.scenes.distortion import BrownConrady
    from skynav.scenes.projection import Projection

    cam = paper_camera(distortion=BrownConrady(k1=-0.05, p1=1e-4))
    assert isinstance(cam, Projection)
    rng = np.random.default_rng(3)
    xy = rng.uniform(-0.5, 1023.5, size=(500, 2))
    v = cam.line_of_sight(xy)
    assert np.allclose(np.linalg.norm(v, axis=-1), 1.0, atol=1e-14)
    assert np.max(np.abs(cam.project(v) - xy)) < 1e-6  # px: Newton undistortion converges to 1e-15


# ------------------------------------------------------------------------ fx != fy, to_dict/from_dict
RECT = paper_camera(pixel_pitch_y_um=12.0, cx=500.25, cy=530.75, distortion=DIST)


def test_default_projection_is_the_square_pixel_formula():
    """Defaults keep fx == fy, and project as ``f = focal_mm / pitch_mm; x = f x/z + cx``
    within 2 ulps of a 2048 px coordinate (9e-13 px, absolute: x may be near 0; the formula
    written here is a second implementation, so no identical bits are asked; an error in f or c
    is off by >= 1e-9 px)."""
    cam = paper_camera()
    f = cam.focal_length_mm / (cam.pixel_pitch_um * 1e-3)
    rng = np.random.default_rng(11)
    v = np.column_stack([rng.uniform(-0.2, 0.2, (1000, 2)), np.ones(1000)])
    want = np.stack([f * (v[:, 0] / v[:, 2]) + cam.cx, f * (v[:, 1] / v[:, 2]) + cam.cy], -1)
    np.testing.assert_allclose(cam.project(v), want, rtol=0, atol=2 * np.spacing(2048.0))
    assert cam.fx_px == cam.fy_px  # one value (the same code), exact
    assert abs(cam.fx_px - f) <= 2 * np.spacing(f)
    np.testing.assert_array_max_ulp(cam.K, np.array([[f, 0, cam.cx], [0, f, cam.cy], [0, 0, 1.0]]), maxulp=2)
    assert abs(cam.ifov_rad - 1.0 / f) <= 2 * np.spacing(1.0 / f)
    assert abs(cam.half_diagonal_fov_rad - math.atan(math.hypot(512.0, 512.0) / f)) <= 2 * np.spacing(0.1)


def test_rectangular_pixels_land_a_known_direction_at_the_analytic_pixel():
    """Independent check: a direction at angles (a, b) from the boresight, in the x-z and y-z
    planes, lies tan(a) * focal length from the principal point on the focal plane, i.e.
    tan(a) * f_mm / pitch_x pixels along x and tan(b) * f_mm / pitch_y pixels along y."""
    cam = paper_camera(pixel_pitch_y_um=12.0, cx=500.25, cy=530.75)
    a, b = math.radians(3.0), math.radians(-4.0)
    v = np.array([[math.tan(a), math.tan(b), 1.0]]) * 7.0  # any length
    x = 500.25 + math.tan(a) * 40.0e3 / cam.pixel_pitch_um
    y = 530.75 + math.tan(b) * 40.0e3 / 12.0
    assert np.allclose(cam.project(v), [[x, y]], rtol=0, atol=1e-9)
    assert cam.fy_px == pytest.approx(40.0e3 / 12.0, rel=1e-15) and cam.fx_px != cam.fy_px
    assert np.allclose(cam.K @ np.array([v[0, 0], v[0, 1], v[0, 2]]) / v[0, 2], [x, y, 1.0], atol=1e-9)
    # field of view edge to edge: 2 atan(half sensor / focal length), per axis
    assert cam.fov_y_rad == pytest.approx(2 * math.atan(0.5 * 1024 * 12.0e-3 / 40.0), rel=1e-14)
    assert cam.fov_x_rad == pytest.approx(math.radians(20.0), rel=1e-12)
    assert cam.ifov_rad == pytest.approx(max(cam.pixel_pitch_um, 12.0) * 1e-3 / 40.0, rel=1e-14)  # larger pixel angle
    # line of sight inverts project; a pixel step along y turns by the y pixel angle
    u = cam.line_of_sight(np.array([[x, y]]))
    assert np.allclose(u, v / np.linalg.norm(v), atol=1e-14)


@settings(max_examples=200, deadline=None)
@given(st.floats(-0.5, 1023.5), st.floats(-0.5, 1023.5))
def test_rectangular_pixels_round_trip_through_distortion(x, y):
    xy = np.array([[x, y]])
    assert np.max(np.abs(RECT.project(RECT.line_of_sight(xy)) - xy)) <= 1e-6


@pytest.mark.parametrize("cam", [
    paper_camera(),
    paper_camera(distortion=DIST, exposure_s=0.01),
    RECT,
    Camera(width=64, height=48, focal_length_mm=10.0, pixel_pitch_um=5.5, pixel_pitch_y_um=5.0, f_number=4.0,
           response_wavelengths_nm=(400.0, 700.0), response_qe_t=(0.3, 0.5)),
    paper_camera().replace(width=640, height=480),
], ids=["paper", "distorted", "rectangular", "small", "resized"])
def test_from_dict_inverts_to_dict(cam):
    import json

    d = json.loads(json.dumps(cam.to_dict()))  # through JSON as the truth files do
    back = Camera.from_dict(d)
    assert back == cam
    assert np.array_equal(back.K, cam.K)


def test_to_dict_keeps_only_optics_and_sensor():
    d = paper_camera().to_dict()
    assert not {"limiting_v_mag", "sun_exclusion_deg", "cosmic_rays_per_frame", "pixel_pitch_y_um"} & set(d)
    assert {"K", "width", "height", "focal_length_mm", "pixel_pitch_um", "f_number", "exposure_s", "bit_depth"} <= set(d)
    assert RECT.to_dict()["pixel_pitch_y_um"] == 12.0


@pytest.mark.parametrize("key, new", [("limiting_v_mag", "visibility.limiting_v_mag"),
                                      ("sun_exclusion_deg", "visibility.sun_exclusion_deg"),
                                      ("cosmic_rays_per_frame", "render.cosmic_rays_per_frame")])
def test_from_dict_names_the_new_home_of_a_moved_key(key, new):
    from skynav.scenes.errors import MovedKeyError

    d = {**paper_camera().to_dict(), key: 1.0}
    with pytest.raises(MovedKeyError, match=f"camera.{key} has moved: write it as {new}") as info:
        Camera.from_dict(d)
    assert isinstance(info.value, ValueError) and "\n" not in str(info.value)


def test_from_dict_checks_derived_copies_and_unknown_keys():
    d = paper_camera().to_dict()
    with pytest.raises(ConfigValueError, match="camera.K"):
        Camera.from_dict({**d, "K": [[1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0]]})
    with pytest.raises(ConfigValueError, match="camera.bit_depth"):
        Camera.from_dict({**d, "bit_depth": 12})
    with pytest.raises(ConfigValueError, match="camera.fov_deg"):
        Camera.from_dict({**d, "fov_deg": 20.0})
    with pytest.raises(ConfigValueError, match="camera.pixel_pitch_y_um"):
        paper_camera(pixel_pitch_y_um=0.0)


def test_camera_from_dict_does_not_load_the_config_reader():
    """No camera <-> config import cycle: Camera.from_dict is self-contained."""
    import subprocess
    import sys

    code = ("import sys; from skynav.scenes.camera import Camera, paper_camera; "
            "c = paper_camera(pixel_pitch_y_um=12.0); assert Camera.from_dict(c.to_dict()) == c; "
            "assert 'skynav.scenes.config' not in sys.modules, 'config imported'")
    subprocess.run([sys.executable, "-c", code], check=True)


def test_yaml_camera_section_with_rectangular_pixels_equals_the_python_twin():
    from skynav.scenes.config import camera_from_mapping

    cam = camera_from_mapping({"preset": "paper", "pixel_pitch_y_um": 12.0, "cx": 500.25, "cy": 530.75,
                               "distortion": {k: getattr(DIST, k) for k in ("k1", "k2", "k3", "p1", "p2")}})
    assert cam == RECT
    assert camera_from_mapping(RECT.to_dict(), "camera") == RECT
