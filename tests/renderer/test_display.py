"""The bench display model: scenes drawn straight into screen pixels through the facility's
line-of-sight model, and electrons mapped to screen digital counts."""

import dataclasses

import numpy as np
import pytest

from skynav.scenes import config, presets
from skynav.scenes.facility import FlatField, screen_small_preset
from skynav.scenes.scene import build_from_spec


@pytest.fixture(scope="module")
def scene():
    return build_from_spec(config.scene_spec_from_mapping(presets.preset_mapping("default")))


def test_expected_image_at_the_projection_size(scene):
    from skynav.renderer.render import RenderOptions, expected_image

    fac = screen_small_preset()
    opts = RenderOptions(resolved=False)
    img = expected_image(scene, projection=fac.projection, rng=np.random.default_rng(0), options=opts, own_size=True)
    assert img.electrons.shape == (640, 640)
    # same sources, same electrons (the screen covers the camera's field and more)
    ref = expected_image(scene, rng=np.random.default_rng(0), options=opts)
    assert img.electrons.sum() >= 0.99 * ref.electrons.sum()


def test_stars_land_where_their_line_of_sight_is(scene):
    from skynav.renderer.display import screen_frame

    fac = screen_small_preset()
    sf = screen_frame(scene, fac, rng=np.random.default_rng(0))
    assert sf.dn.shape == (640, 640) and sf.dn.dtype == np.uint16
    e = sf.electrons
    k = int(np.argmax(sf.stars_electrons))
    x, y = sf.stars_xy[k]
    i, j = int(round(y)), int(round(x))
    w = e[i - 4:i + 5, j - 4:j + 5]
    yy, xx = np.mgrid[i - 4:i + 5, j - 4:j + 5]
    assert abs((w * xx).sum() / w.sum() - x) < 0.05 and abs((w * yy).sum() / w.sum() - y) < 0.05
    v = scene.R_cam_icrs @ scene.stars.u_icrs[k]
    assert np.allclose(fac.projection.project(v), sf.stars_xy[k])


def test_flat_field_is_corrected(scene):
    from skynav.renderer.display import dn_of_electrons

    fac = screen_small_preset()
    flat = FlatField(x_px=[0, 319.5, 639], y_px=[0, 319.5, 639], relative=[[0.7, 0.8, 0.7], [0.8, 1.0, 0.8], [0.7, 0.8, 0.7]])
    vf = fac.replace(flat_field=flat)
    e = np.full(3, 2000.0)
    xy = np.array([[319.5, 319.5], [0.0, 0.0], [639.0, 319.5]])
    d0, _ = dn_of_electrons(fac, e, xy)
    d1, _ = dn_of_electrons(vf, e, xy)
    assert d1[0] == pytest.approx(d0[0])
    rm = fac.radiometric
    got = (rm.irradiance_w_m2(d1) - rm.black_w_m2) * flat(xy)
    assert np.allclose(got, rm.irradiance_w_m2(d0[0]) - rm.black_w_m2, rtol=1e-9)
