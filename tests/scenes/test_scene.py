"""Scene building: the default scene, its YAML twin, flags, and geometry invariants."""

from pathlib import Path

import numpy as np
import pytest

from skynav.scenes import presets, scene_files
from skynav.scenes.scene import build_from_spec

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def default_scene():
    return build_from_spec(presets.default_scene_spec())


def test_yaml_twin_gives_identical_scene(default_scene):
    spec_yaml = scene_files.load_scene_file(ROOT / "docs" / "examples" / "default_scene.yaml")
    assert spec_yaml == presets.default_scene_spec()
    s2 = build_from_spec(spec_yaml)
    assert np.array_equal(s2.R_cam_icrs, default_scene.R_cam_icrs)
    assert np.array_equal(s2.stars.xy, default_scene.stars.xy)


def test_default_scene_points_at_a_visible_planet(default_scene):
    centre = np.array([default_scene.camera.cx, default_scene.camera.cy])
    vis = [b for b in default_scene.bodies if b.visible]
    assert vis, "the default scene must show a visible planet"
    # point_at: mars centres Mars on the principal point
    target = next(b for b in vis if b.name == "mars")
    assert np.allclose(target.xy, centre, atol=1e-6)
    assert default_scene.boresight_sun_angle_rad > default_scene.visibility.sun_exclusion_rad


def test_star_pixels_are_projections_of_apparent_directions(default_scene):
    s = default_scene.stars
    cam = default_scene.camera
    xy = cam.project(s.u_icrs @ default_scene.R_cam_icrs.T)
    assert np.array_equal(xy, s.xy)
    assert np.all(cam.in_image(s.xy[s.in_fov]))
    assert len(s) > 100 and s.v_mag.max() <= 9.0


def test_body_light_time_is_distance_over_c(default_scene):
    for b in default_scene.bodies:
        assert b.light_time_s == pytest.approx(b.distance_km / 299792.458, rel=1e-12)
