"""The render driver: identities on whole frames (flux in = flux out; determinism)."""

import numpy as np
import pytest

from skynav.renderer.psf import GaussianPSF
from skynav.renderer.render import RenderOptions, blur_crop, render
from skynav.scenes import presets
from skynav.scenes.scene import build_from_spec


def test_blur_crop_conserves_flux_and_centroid():
    rng = np.random.default_rng(3)
    crop = np.zeros((16, 16))
    crop[5:9, 6:11] = rng.uniform(1, 2, (4, 5))
    out, pad = blur_crop(crop, GaussianPSF(0.5), 1e-6)
    assert out.sum() == pytest.approx(crop.sum(), rel=1e-12)  # kernel normalised, padded
    yy, xx = np.indices(crop.shape)
    c0 = np.array([(crop * xx).sum(), (crop * yy).sum()]) / crop.sum()
    yy, xx = np.indices(out.shape)
    c1 = np.array([(out * xx).sum(), (out * yy).sum()]) / out.sum() - pad
    assert np.allclose(c0, c1, atol=1e-12)  # symmetric kernel: centroid unchanged


@pytest.fixture(scope="module")
def scene():
    return build_from_spec(presets.default_scene_spec())


def test_frame_flux_equals_sum_of_source_electrons(scene):
    # Conservation: electrons image = stars + bodies + cosmic rays, for sources well inside
    frame = render(scene, seed=5, options=RenderOptions(noise=False))
    t = frame.truth
    cam = scene.camera
    inner = [s for s in t["stars"] if 6 < s["xy"][0] < cam.width - 7 and 6 < s["xy"][1] < cam.height - 7]
    expected = sum(s["electrons"] for s in t["stars"]) + sum(b["electrons"] for b in t["bodies"] if b["in_fov"])
    expected += sum(c["electrons"] for c in t["cosmic_rays"])
    edge = sum(s["electrons"] for s in t["stars"] if s not in inner)  # stars near the border lose some flux
    total = float(frame.electrons.astype(np.float64).sum())
    assert expected - edge - 1e-4 * expected <= total <= expected * (1 + 1e-4)


def test_same_seed_same_bits(scene):
    a = render(scene, seed=11, options=RenderOptions(backend="numpy"))
    b = render(scene, seed=11, options=RenderOptions(backend="numpy"))
    assert np.array_equal(a.dn, b.dn) and np.array_equal(a.electrons, b.electrons)
    c = render(scene, seed=12, options=RenderOptions(backend="numpy"))
    assert not np.array_equal(a.dn, c.dn)
