"""The stars drawn by Dr.Jit into the batch's sensor input (renderer/splat_jit.py) against the
numpy reference (expected_image's rasteriser), a streaked frame included, the flux against the
Gaussian's closed form, and the truth and DN statistics of the frames made so."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from scipy.special import erf

from skynav.infra.errors import ConfigValueError
from skynav.renderer.batch import _device_stars, render_batch
from skynav.renderer.expected import expected_image, source_paths
from skynav.renderer.render import RenderOptions
from skynav.renderer.kernels import GaussianKernel
from skynav.renderer.splat_jit import FramePoints, PointGroup, frame_moments, splat_points
from skynav.scenes import build_from_spec, default_scene_spec
from tests.renderer.conftest import llvm_or_skip


@pytest.fixture(autouse=True)
def _llvm():
    llvm_or_skip()


def _scene(px: int, rate_rad_s=(0.0, 0.0, 0.0)):
    spec = default_scene_spec()
    cam = spec.camera
    camera = cam.replace(width=px, height=px, pixel_pitch_um=cam.pixel_pitch_um * cam.width / px)
    scene = build_from_spec(dataclasses.replace(spec, camera=camera))
    return dataclasses.replace(scene, angular_velocity_rad_s=np.asarray(rate_rad_s, dtype=float))


#: Relative difference per pixel allowed against the reference, on the pixels above 1e-3 of the
#: frame's peak or above 1 e- (the frame's peak may be Mars, a thousand times a star's: the 1 e-
#: floor keeps the stars' stamps in the check). Both sum each pixel's stamps in float64 (the
#: device in another order) and round to float32 once (6e-8: measured 6e-8 here); the device
#: writes the erf differences without the reference's ``0.5 (1 + erf)``, whose cancellation in
#: the far tails (1e-16 of a star's electrons, absolute) is why fainter pixels are left out.
REL_TOL = 1e-5


@pytest.mark.parametrize("px, rate, background", [(1024, (0.0, 0.0, 0.0), 0.0), (256, (0.0, 0.0, 0.0), 40.0),
                                                  (256, (0.03, -0.015, 0.05), 0.0)],
                         ids=["default-1024", "background", "streaked"])
def test_device_stars_are_the_reference_expected_image(px, rate, background):
    scene = _scene(px, rate)
    opts = RenderOptions(backend="llvm", cosmic_rays_per_frame=0.0, background_e_per_px_s=background)
    seeds = [3, 4]
    batch = render_batch([scene] * 2, seeds, options=opts, star_splat="device")
    host = render_batch([scene] * 2, seeds, options=opts, star_splat="host")
    for i, seed in enumerate(seeds):
        ref = expected_image(scene, rng=np.random.default_rng(seed), options=opts).electrons
        got = batch.electrons[i].astype(float)
        bright = ref > min(1e-3 * ref.max(), 1.0)
        assert np.count_nonzero(bright) > 2000  # the stars' stamps are in the check
        rel = np.abs(got[bright] - ref[bright]) / ref[bright]
        assert rel.max() < REL_TOL, (rel.max(), int(bright.sum()))
        assert np.all(got[~bright] < 1.01)  # nothing drawn where the reference has no light
        # the stars' truth (electrons, centres of light) is the per-frame path's, to roundings
        for a, b in zip(batch.truths[i]["stars"], host.truths[i]["stars"]):
            assert a["electrons"] == b["electrons"] and a["hip"] == b["hip"]
            np.testing.assert_allclose(a["centre_of_light_xy"], b["centre_of_light_xy"], rtol=0, atol=1e-9)
        for a, b in zip(batch.truths[i]["bodies"], host.truths[i]["bodies"]):  # the bodies: numpy's in both
            assert a.keys() == b.keys()
            for k in a:
                if isinstance(a[k], (float, list)):  # a ray-traced body's centre: its crop's moments, to roundings
                    np.testing.assert_allclose(np.asarray(a[k], float), np.asarray(b[k], float), rtol=1e-12, atol=1e-9)
                else:
                    assert a[k] == b[k], k
    if rate[2]:  # the streaked frame: its stars do move
        paths = source_paths(scene, scene.stars.u_icrs, opts)
        assert np.min(np.hypot(*(paths[:, -1] - paths[:, 0]).T)) > 3.0  # px over the exposure


def test_a_star_holds_its_electrons_by_the_gaussian_closed_form():
    """One star inside the image: its stamp holds its electrons times the Gaussian's fraction
    inside the (2h+1)^2 stamp, erf(a / (sqrt 2 sigma)) erf(b / ...) per axis (closed form)."""
    from drjit.llvm import Float  # Dr.Jit only once the LLVM backend is known to work (the autouse skip)

    shape, sigma, half, flux = (32, 32), 0.7, 3, 5000.0
    xy = np.array([[12.3, 17.8]])
    group = PointGroup(kernel=GaussianKernel(sigma), half=half, xy=xy, flux_e=np.array([flux]), source=np.array([0]))
    frames = [FramePoints(groups=(), electrons=np.zeros(0), drawn=np.zeros(0, bool), n_stars=0),
              FramePoints(groups=(group,), electrons=np.array([flux]), drawn=np.array([True]), n_stars=1)]
    sig, moments = splat_points(Float(np.zeros(2 * 32 * 32, np.float32)), frames, shape)
    img = sig.numpy().reshape(2, *shape)
    assert img[0].sum() == 0.0  # the other frame untouched
    lo = np.floor(xy[0] + 0.5) - half - 0.5 - xy[0]  # the stamp's edges about the star, px
    hi = lo + 2 * half + 1
    s2 = math.sqrt(2.0) * sigma
    inside = np.prod(0.5 * (erf(hi / s2) - erf(lo / s2)))
    assert abs(float(img[1].sum(dtype=float)) - flux * inside) < 1e-6 * flux
    cy, cx = np.unravel_index(np.argmax(img[1]), shape)
    assert (cx, cy) == (12, 18)
    # its moments: the charge drawn, and the centre of light by the closed form's pixel weights
    # (the erf differences of each column and row, scipy's erf, about the pixel centres)
    m0, m1 = frame_moments(frames, moments.numpy())[1]
    assert abs(m0[0] - flux * inside) < 1e-9 * flux
    for axis in range(2):
        centres = np.floor(xy[0, axis] + 0.5) - half + np.arange(2 * half + 1)
        w = 0.5 * (erf((centres + 0.5 - xy[0, axis]) / s2) - erf((centres - 0.5 - xy[0, axis]) / s2))
        assert abs(m1[0, axis] / m0[0] - (w @ centres) / w.sum()) < 1e-9


def test_device_stars_keep_the_sensor_statistics():
    """A flat frame of the background and the same frame through the device splat: the DN's mean
    and variance agree (the input differs by roundings only)."""
    scene = _scene(128)
    opts = RenderOptions(backend="llvm", cosmic_rays_per_frame=0.0, background_e_per_px_s=500.0)
    dev = render_batch([scene] * 4, [1, 2, 3, 4], options=opts, star_splat="device")
    host = render_batch([scene] * 4, [1, 2, 3, 4], options=opts, star_splat="host")
    differ = np.count_nonzero(dev.dn.astype(int) != host.dn.astype(int))
    # same keys: a DN differs only where an input's rounding crosses a Poisson/ADC boundary
    assert differ <= 1e-3 * dev.dn.size, differ


def test_star_splat_is_checked():
    with pytest.raises(ConfigValueError, match="star_splat"):
        render_batch([_scene(64)], [1], star_splat="gpu")
