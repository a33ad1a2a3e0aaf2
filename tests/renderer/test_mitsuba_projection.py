"""Mitsuba resolved bodies take their rays from the Projection, not from a built-in pinhole.

Reference: the exact quadrature of a Lambert sphere lit by the Sun
(:func:`tests.renderer.test_mitsuba_against_lambert_sphere.lambert_sphere_quadrature`, written
independently of the renderer), with every surface point mapped to the image by the SAME
``projection.project`` the renderer is given. Its photocentre is where the projection puts the
body's light; its total (a solid-angle integral) does not depend on the projection at all, so it
also checks the per-pixel solid angles the backend derives from the corner lines of sight.

Two projections that are not a pinhole:

- a :class:`Camera` with strong Brown-Conrady distortion (k1 = -0.25: ~4 % of scale change
  across the field), a crescent far off-axis. The old backend applied distortion as a
  translation of the body, so the disk kept its pinhole shape and a crescent's photocentre
  moved with the neglected scale change;
- an equidistant fisheye (``r = f theta``, 98 deg across), a small class written here that only
  implements the Projection protocol (no focal length, no K): at 33 deg off-axis a pinhole
  rendering would be 14 % too wide radially.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from skynav.renderer.brdf import BRDF
from skynav.renderer.errors import ProjectionCropError
from skynav.renderer.mitsuba_backend import crop_lines_of_sight, render_resolved_body
from skynav.scenes.camera import paper_camera
from skynav.scenes.distortion import BrownConrady
from skynav.scenes.projection import Projection
from tests.renderer.test_mitsuba_against_lambert_sphere import (
    K_550,
    _spectral_electrons_per_s_per_sr,
    lambert_sphere_quadrature,
)


class EquidistantFisheye:
    """``r = f theta`` about the principal point (an ideal fisheye), W x H pixels."""

    def __init__(self, width: int, height: int, f_px: float):
        self.width, self.height, self.f_px = width, height, f_px
        self.cx, self.cy = (width - 1) / 2.0, (height - 1) / 2.0

    def project(self, v_cam):
        v = np.asarray(v_cam, dtype=float)
        v = v / np.linalg.norm(v, axis=-1, keepdims=True)
        theta = np.arccos(np.clip(v[..., 2], -1.0, 1.0))
        phi = np.arctan2(v[..., 1], v[..., 0])
        return np.stack([self.cx + self.f_px * theta * np.cos(phi), self.cy + self.f_px * theta * np.sin(phi)], -1)

    def line_of_sight(self, xy_px):
        xy = np.asarray(xy_px, dtype=float)
        dx, dy = xy[..., 0] - self.cx, xy[..., 1] - self.cy
        theta = np.hypot(dx, dy) / self.f_px
        phi = np.arctan2(dy, dx)
        return np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], -1)


def _oracle(scene, body, project):
    """Exact electrons and photocentre (projected through ``project``) of the Lambert sphere."""
    from skynav.renderer import spectra

    cam = scene.camera
    centre = np.asarray(body.position_km)
    sun = np.asarray(body.sun_position_km) - centre
    observer = centre - body.distance_km * np.asarray(body.u_icrs)
    G, xy = lambert_sphere_quadrature(centre, body.radius_km, sun, observer,
                                      project=lambda p: project(p @ scene.R_cam_icrs.T))
    k = K_550 * spectra.reflectance_shape(body.name, spectra.WAVELENGTHS_NM)
    e = G * _spectral_electrons_per_s_per_sr(cam, k, float(np.linalg.norm(sun))) * cam.exposure_s
    return e, np.asarray(xy)


def _render_against_oracle(scene, body, projection, *, seed, label):
    """Mitsuba's render of ``body`` through ``projection`` (256 spp, Lambert) and its photocentre
    error (px) and total-electron error (relative) against :func:`_oracle`'s quadrature."""
    img = render_resolved_body(scene, body, spp=256, brdf=BRDF(kind="lambert", reflectance_550=K_550),
                               normalize="none", rng=np.random.default_rng(seed), projection=projection)
    expected_e, expected_xy = _oracle(scene, body, projection.project)
    err = float(np.hypot(*(np.asarray(img.photocentre_xy) - expected_xy)))
    rel = img.electrons_raw_total / expected_e - 1.0
    print(f"{label}: photocentre error {err:.4f} px, total rel {rel:+.2e}, radius {img.radius_px:.2f} px")
    return img, err, rel


def test_fisheye_is_a_projection():
    fish = EquidistantFisheye(64, 48, 30.0)
    assert isinstance(fish, Projection)
    xy = np.array([[3.2, 40.1], [31.5, 23.5], [60.0, 2.0]])
    assert np.allclose(fish.project(fish.line_of_sight(xy)), xy, atol=1e-9)  # the test class itself


def test_distorted_crescent_photocentre_where_projection_puts_it(mitsuba_variant, body_scene):
    """Strong distortion, 60 px crescent at 60 deg phase, 340 px off-axis: the photocentre within
    0.02 px of the quadrature through ``Camera.project``; the total within 1e-3 of it.

    0.02 px: the centroid noise of a 60 px disk at 256 spp (limb and terminator pixels) is
    ~0.003 px and the bilinear interpolation of the corner table is exact to ~1e-5 px. 1e-3:
    the total's sampling noise at 256 spp is ~1e-4 and the solid angle of a pixel from its
    corners is exact to ~1e-6 (the radiance average over a pixel is weighted by area, not by
    solid angle: a second-order term, ~1e-7 with this distortion)."""
    cam = paper_camera(distortion=BrownConrady(k1=-0.25, k2=0.05))
    scene, body = body_scene(xy=(200.3, 790.6), diameter_px=60.0, phase_deg=60.0, sun_pa_deg=35.0,
                             distance_km=4.0e5, camera=cam)
    img = render_resolved_body(scene, body, spp=256, brdf=BRDF(kind="lambert", reflectance_550=K_550),
                               normalize="none", rng=np.random.default_rng(5))
    expected_e, expected_xy = _oracle(scene, body, cam.project)
    err = float(np.hypot(*(np.asarray(img.photocentre_xy) - expected_xy)))
    rel = img.electrons_raw_total / expected_e - 1.0
    print(f"distorted crescent: photocentre error {err:.4f} px, total rel {rel:+.2e}")
    assert err < 0.02
    assert abs(rel) < 1e-3


def test_fisheye_disk_photocentre_where_projection_puts_it(mitsuba_variant, body_scene):
    """A Projection that is not a Camera: an equidistant fisheye. A 60 px (fisheye) disk 33 deg
    off-axis at 50 deg phase: photocentre within 0.02 px of the quadrature through
    ``fisheye.project`` and total within 1e-3 (tolerances as above); the centre of figure is
    ``fisheye.project`` of the body's direction, and the crop is where the fisheye puts it."""
    fish = EquidistantFisheye(1024, 1024, 600.0)
    cam = paper_camera()
    target = np.array([511.5 + 300.0, 511.5 - 180.0])  # fisheye px, theta = 0.583 rad
    v = fish.line_of_sight(target)
    pinhole_xy = cam.project(v)  # make_body_scene places bodies through the camera's pinhole
    diameter_rad = 60.0 / fish.f_px
    scene, body = body_scene(xy=tuple(pinhole_xy), diameter_px=2.0 * cam.focal_length_px * math.tan(0.5 * diameter_rad),
                             phase_deg=50.0, sun_pa_deg=-120.0, distance_km=4.0e5, camera=cam)
    img, err, rel = _render_against_oracle(scene, body, fish, seed=6, label="fisheye")
    assert np.allclose(img.centre_of_figure_xy, target, atol=1e-6)
    assert img.x0 <= target[0] - 30 and img.x0 + img.electrons.shape[1] >= target[0] + 30
    assert img.y0 <= target[1] - 30 and img.y0 + img.electrons.shape[0] >= target[1] + 30
    assert err < 0.02
    assert abs(rel) < 1e-3


def test_pinhole_corner_solid_angles_match_cos3():
    """The corner-derived pixel solid angle of a pinhole equals ``cos^3(theta) / f^2`` at the
    pixel centre (the closed form the backend used before) to 1e-6: the two differ by the
    curvature of cos^3 across one pixel, ~(1/f)^2 ~ 1e-7 relative."""
    cam = paper_camera()
    x0, y0, w, h = 900, -20, 24, 16
    _, _, omega = crop_lines_of_sight(cam, x0, y0, w, h)
    f = cam.focal_length_px
    xn = (np.arange(x0, x0 + w) - cam.cx) / f
    yn = (np.arange(y0, y0 + h) - cam.cy) / f
    closed = (1.0 + yn[:, None] ** 2 + xn[None, :] ** 2) ** -1.5 / (f * f)
    assert np.max(np.abs(omega / closed - 1.0)) < 1e-6


def test_crop_without_lines_of_sight_is_refused():
    class Blind(EquidistantFisheye):
        def line_of_sight(self, xy_px):
            v = super().line_of_sight(xy_px)
            return np.where(np.asarray(xy_px)[..., :1] > 20.0, np.nan, v)

    with pytest.raises(ProjectionCropError, match="'moon'.*finite line of sight"):
        crop_lines_of_sight(Blind(64, 64, 30.0), 10, 10, 16, 16, body="moon")


def test_screen_projection_disk_photocentre_where_the_bench_puts_it(mitsuba_variant, body_scene):
    """Screen frames (``skynav hil export``): a resolved body is ray-traced in SCREEN space, each
    screen pixel's rays from the facility's line-of-sight model (collimator distortion, screen
    tilt and roll, decentre, camera misalignment), never resampled from a camera image. A 60
    screen-px disk at 40 deg phase, 7 deg off-axis on a distorted, rolled and tilted bench:
    photocentre within 0.02 px of the quadrature through ``ScreenProjection.project`` and total
    within 1e-3 (tolerances as above: sampling noise ~0.003 px, ~1e-4)."""
    import dataclasses

    from skynav.scenes.facility import screen_small_preset
    from skynav.scenes.screen import GeometricModel

    fac = screen_small_preset()
    geo = GeometricModel(focal_length_mm=50.0, decentre_x_mm=0.3, decentre_y_mm=-0.2, tilt_x_rad=0.01, tilt_y_rad=-0.02,
                         roll_rad=0.05, k1=-0.08, k2=0.01, p1=2e-4, p2=-1e-4, misalignment_rad=(1e-3, -2e-3, 4e-3))
    proj = dataclasses.replace(fac, geometric=geo).projection
    assert isinstance(proj, Projection)
    cam = paper_camera()
    target = np.array([319.5 + 150.0, 319.5 - 90.0])   # screen px
    v = proj.line_of_sight(target)
    assert np.allclose(proj.project(v), target, atol=1e-6)
    scale_rad_per_px = float(np.arccos(np.clip(proj.line_of_sight(target + [0.5, 0]) @ proj.line_of_sight(target - [0.5, 0]).T, -1, 1)))
    diameter_rad = 60.0 * scale_rad_per_px
    scene, body = body_scene(xy=tuple(cam.project(v)), diameter_px=2.0 * cam.focal_length_px * math.tan(0.5 * diameter_rad),
                             phase_deg=40.0, sun_pa_deg=70.0, distance_km=4.0e5, camera=cam)
    img, err, rel = _render_against_oracle(scene, body, proj, seed=7, label="screen")
    assert np.allclose(img.centre_of_figure_xy, target, atol=1e-6)
    assert err < 0.02
    assert abs(rel) < 1e-3


# ----------------------------------------------------------------------------- pinhole: two sensors
@pytest.mark.parametrize("xy, diameter_px, phase_deg, sun_pa_deg", [
    ((400.3, 500.7), 60.0, 40.0, 30.0),     # a gibbous disk near the centre
    ((900.2, 100.9), 30.0, 100.0, -60.0),   # a crescent far off-axis
])
def test_pinhole_perspective_and_projection_sensors_agree(mitsuba_variant, body_scene, xy, diameter_px, phase_deg, sun_pa_deg):
    """A plain pinhole takes Mitsuba's built-in ``perspective`` sensor; the ``skynav_projection``
    table traces the same rays: the two photocentres agree within 0.001 px and the totals within
    1e-4.

    Two implementations, so a tolerance: with the same seed both draw the same film samples, and
    their rays differ by float32 rounding (~6e-8 rad, ~2e-4 px at f = 2900 px) and by the corner
    table's interpolation (~1e-5 px). A sample whose ray grazes the limb or the terminator can
    land on either side in the two, moving the photocentre by ~radius / (spp x lit pixels): at
    256 spp the differences measured are <= 4e-4 px and <= 5e-5 in the total. The sampling noise
    itself (~0.003 px) is common to both and cancels."""
    from skynav.renderer.mitsuba_backend import plain_pinhole

    scene, body = body_scene(xy=xy, diameter_px=diameter_px, phase_deg=phase_deg, sun_pa_deg=sun_pa_deg, distance_km=4.0e5)
    assert plain_pinhole(scene.camera)
    img = {s: render_resolved_body(scene, body, spp=256, rng=np.random.default_rng(11), sensor=s, normalize="none")
           for s in ("auto", "projection")}
    assert img["auto"].sensor == "perspective" and img["projection"].sensor == "projection"
    assert (img["auto"].x0, img["auto"].y0, img["auto"].electrons.shape) == (img["projection"].x0, img["projection"].y0, img["projection"].electrons.shape)
    d = np.hypot(*np.subtract(img["auto"].photocentre_xy, img["projection"].photocentre_xy))
    rel = img["auto"].electrons_raw_total / img["projection"].electrons_raw_total - 1.0
    print(f"perspective - projection: photocentre {d:.2e} px, total {rel:+.1e}")
    assert d < 1e-3
    assert abs(rel) < 1e-4


def test_sensor_choice_follows_the_projection(body_scene):
    """``auto`` keeps the table for distortion and rectangular pixels; ``perspective`` is refused
    there, in one line naming the choices (no Mitsuba scene is built for a refused request)."""
    from skynav.renderer.mitsuba_backend import _sensor_kind
    from skynav.infra.errors import ConfigValueError

    plain = paper_camera()
    distorted = paper_camera(distortion=BrownConrady(k1=-0.05))
    rectangular = paper_camera(pixel_pitch_y_um=14.0)
    assert _sensor_kind(plain, "auto") == "perspective"
    assert _sensor_kind(distorted, "auto") == _sensor_kind(rectangular, "auto") == "projection"
    assert _sensor_kind(EquidistantFisheye(64, 64, 30.0), "auto") == "projection"
    assert _sensor_kind(plain, "projection") == "projection"
    for cam in (distorted, rectangular):
        with pytest.raises(ConfigValueError, match=r"mitsuba\.sensor = .*perspective.*'projection' or 'auto'"):
            _sensor_kind(cam, "perspective")
    scene, body = body_scene(camera=distorted)
    with pytest.raises(ConfigValueError, match=r"mitsuba\.sensor = 'pinhole'.*auto, perspective, projection"):
        render_resolved_body(scene, body, sensor="pinhole")
