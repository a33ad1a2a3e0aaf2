"""The ray-traced bodies blurred and composited by Dr.Jit (renderer/bodies_jit.py) against the
numpy reference (expected_image's FFT or separable blur and crop composite), a body across the
image's edge included; the flux and centre of light of a synthetic crop against the
convolution's moment identities; and the batch's frames made so."""

from __future__ import annotations

import dataclasses
from types import SimpleNamespace

import numpy as np
import pytest

from skynav.infra.errors import ConfigValueError
from skynav.renderer.bodies_jit import body_crops, bodies_truth, composite_bodies
from skynav.renderer.expected import TracedBody, expected_image
from skynav.renderer.kernels import GaussianKernel
from skynav.renderer.optics import kernel_for
from skynav.renderer.render import RenderOptions
from skynav.scenes import build_from_spec, paper_camera
from skynav.scenes.config import scene_spec_from_mapping
from skynav.scenes.presets import preset_mapping
from tests.renderer.conftest import llvm_or_skip


@pytest.fixture(autouse=True)
def _llvm():
    llvm_or_skip()


PX = 128
AIRY = {"model": "airy", "wavelength_nm": 550.0}

#: Relative difference per pixel allowed against the reference, on the pixels above 1e-9 of the
#: frame's peak (the Earth's disc, 7e7 e- a pixel). Both are float64 sums rounded once to
#: float32 (6e-8; measured 7e-8 at most); the reference blurs a table kernel by FFT, whose
#: rounding is absolute, about 1e-16 of the peak (measured 4e-16): below the floor it is no
#: longer small beside the pixel, and those pixels are checked to 1e-14 of the peak instead.
REL_TOL = 1e-5
FLOOR = 1e-9

#: The device's centres of light against the reference's, px: both are float64 sums over the
#: same blurred crop in another order (and the reference's FFT rounding), about 1e-16 of the
#: crop's coordinates (measured 4e-14 px).
CENTRE_TOL_PX = 1e-9


def _departure(psf=None, **camera):
    """The Earth-departure scene at PX px (the Earth about 31 px across), its camera changed."""
    m = preset_mapping("earth_departure")
    m["camera"].update({"width": PX, "height": PX, **camera})
    if psf is not None:
        m["camera"]["psf"] = psf
    return build_from_spec(scene_spec_from_mapping(m))


def _device(scenes, opts, seed, backend="llvm"):
    """Each scene's expected image (its bodies left out) and the device composite of the batch
    on ``backend``: (expected images with the truth recorded, electrons (N, H, W) float32)."""
    from skynav.renderer.sensor_jit import _jit_module

    Float = _jit_module(backend).Float
    expected, crops = [], []
    for scene in scenes:
        traced = []
        expected.append(expected_image(scene, rng=np.random.default_rng(seed), options=opts, with_irradiance=False,
                                       traced_out=traced))
        crops.append(body_crops(traced, opts.flux_fraction_lost) if traced else None)
    sig = np.stack([e.electrons for e in expected]).astype(np.float32)
    out, moments = composite_bodies(Float(sig.ravel()), crops, (PX, PX))
    return bodies_truth(expected, crops, moments.numpy()), out.numpy().reshape(sig.shape)


@pytest.mark.parametrize("psf", [None, AIRY], ids=["gaussian", "airy"])
def test_device_bodies_are_the_reference_expected_image(psf, jit_backend_name):
    """Three frames in one batch: the Earth in the middle, a frame without a ray-traced body
    (pointed away), and the Earth across the image's left edge (its crop partly off the image);
    on LLVM, and on CUDA with ``-m gpu`` (the same Python body)."""
    opts = RenderOptions(mitsuba_spp=4)
    scenes = [_departure(psf), _departure(psf, cx=-200.0), _departure(psf, cx=6.0, cy=100.0)]
    truths, got = _device(scenes, opts, seed=5, backend=jit_backend_name)
    for i, scene in enumerate(scenes):
        ref = expected_image(scene, rng=np.random.default_rng(5), options=opts, with_irradiance=False)
        r = ref.electrons
        bright = r > FLOOR * r.max()
        rel = np.abs(got[i][bright] - r[bright]) / r[bright]
        assert rel.max() < REL_TOL, (i, rel.max())
        assert np.abs(got[i][~bright] - r[~bright]).max() < 1e-14 * r.max()
        assert truths[i].resolved.keys() == ref.resolved.keys() == ({"earth"} if i != 1 else set())
        for name in ref.resolved:
            np.testing.assert_allclose(truths[i].body_centre_of_light[name], ref.body_centre_of_light[name],
                                       rtol=0, atol=CENTRE_TOL_PX)
            assert truths[i].body_electrons[name] == ref.body_electrons[name]  # the crop's total, as traced
            if ref.body_fraction_drawn is not None:  # the airy's: the blurred crop's total over it
                assert abs(truths[i].body_fraction_drawn[name] - ref.body_fraction_drawn[name]) < 1e-12
        assert (ref.body_fraction_drawn is None) == (psf is None)
    off = truths[2].body_centre_of_light["earth"]
    assert off[0] < 10.0 and np.count_nonzero(got[2][:, 0] > 1e6) > 10  # the edge frame's disc is cut by the edge


def _synthetic_body(x0, y0):
    """A crop of a uniform half-lit disc (1000 e- a pixel, radius 9 px) at (x0, y0)."""
    yy, xx = np.mgrid[0:24, 0:24]
    disc = ((xx - 11.3) ** 2 + (yy - 12.1) ** 2 < 81.0) & (xx > 8)
    e = np.where(disc, 1000.0, 0.0)
    return SimpleNamespace(x0=x0, y0=y0, electrons=e, electrons_total=float(e.sum()))


@pytest.mark.parametrize("kernel", [GaussianKernel(0.7), kernel_for(paper_camera(psf=AIRY))],
                         ids=["gaussian", "airy"])
def test_a_crop_inside_the_image_keeps_its_flux_and_centre(kernel):
    """A crop wholly inside the image: the frame holds the crop's electrons times the stamp's
    sum (the total of a full convolution), and the centre of light is the crop's plus the
    stamp's (its first moments), each summed here from the inputs, not from the blurred crop."""
    from drjit.llvm import Float  # Dr.Jit only once the LLVM backend is known to work (the autouse skip)

    img = _synthetic_body(40, 50)
    body = TracedBody(name="rock", image=img, kernel=kernel, at_xy=np.array([52.0, 62.0]))
    crops = body_crops([body], 1e-6)
    stamp, pad = crops.stamps[0], crops.pads[0]
    sig, moments = composite_bodies(Float(np.zeros(2 * PX * PX, np.float32)), [None, crops], (PX, PX))
    frames = sig.numpy().reshape(2, PX, PX)
    assert frames[0].sum() == 0.0  # the other frame untouched
    total = img.electrons.sum() * stamp.sum()
    assert abs(float(frames[1].sum(dtype=float)) - total) < 1e-6 * total  # float32 pixels: 6e-8 each
    yy, xx = np.indices(img.electrons.shape)
    ky, kx = np.indices(stamp.shape)
    centre = [(img.electrons * xx).sum() / img.electrons.sum() + img.x0 + (stamp * kx).sum() / stamp.sum() - pad,
              (img.electrons * yy).sum() / img.electrons.sum() + img.y0 + (stamp * ky).sum() / stamp.sum() - pad]
    truth = bodies_truth([_ExpectedStub()], [crops], moments.numpy())[0]
    np.testing.assert_allclose(truth.body_centre_of_light["rock"], centre, rtol=0, atol=1e-9)
    assert abs(truth.body_fraction_drawn["rock"] - stamp.sum()) < 1e-12


@dataclasses.dataclass(frozen=True)
class _ExpectedStub:
    """The truth fields :func:`bodies_truth` records into."""

    body_electrons: dict = dataclasses.field(default_factory=dict)
    body_centre_of_light: dict = dataclasses.field(default_factory=dict)
    body_fraction_drawn: dict = dataclasses.field(default_factory=dict)


@pytest.mark.parametrize("kernel", [GaussianKernel(0.7), kernel_for(paper_camera(psf=AIRY))],
                         ids=["gaussian", "airy"])
def test_blur_stamp_is_what_blur_crop_convolves_with(kernel):
    """A one-pixel crop blurred by the reference is the kernel's blur stamp."""
    crop = np.zeros((5, 5))
    crop[2, 2] = 1.0
    blurred, pad = kernel.blur_crop(crop, 1e-6, at_xy=np.array([30.0, 40.0]))
    stamp = kernel.blur_stamp(1e-6, at_xy=np.array([30.0, 40.0]))
    assert pad == stamp.shape[0] // 2
    np.testing.assert_allclose(blurred[2:2 + stamp.shape[0], 2:2 + stamp.shape[1]], stamp, rtol=0, atol=1e-15)


def test_traced_out_keeps_the_draws_and_leaves_the_bodies_out():
    """With ``traced_out`` the frame's stream is drawn as by the reference (the sensor's draws
    that follow are the same) and the image holds everything but the traced bodies."""
    scene, opts = _departure(), RenderOptions(mitsuba_spp=4)
    rng_ref, rng_out, traced = np.random.default_rng(9), np.random.default_rng(9), []
    ref = expected_image(scene, rng=rng_ref, options=opts, with_irradiance=False)
    out = expected_image(scene, rng=rng_out, options=opts, with_irradiance=False, traced_out=traced)
    assert rng_ref.integers(1 << 62) == rng_out.integers(1 << 62)
    assert [t.name for t in traced] == ["earth"] and out.resolved.keys() == {"earth"}
    img = traced[0].image
    assert out.electrons.sum() < 1e-3 * ref.electrons.sum()  # the stars alone
    assert float(img.electrons.sum()) == pytest.approx(ref.body_electrons["earth"], rel=1e-12)
    with pytest.raises(ConfigValueError, match="traced_out"):
        expected_image(scene, rng=np.random.default_rng(9), options=opts, traced_out=[])


@pytest.mark.parametrize("psf", [None, AIRY], ids=["gaussian", "airy"])
def test_batch_draws_the_bodies_on_the_device(psf):
    """render_batch with the device splat: the frames' expected electrons are the reference's
    (above 1 e-: the stars' float32 stamp sums, tests/renderer/test_batch_splat.py, are in
    them too), and their truths are the host batch's, the ray-traced bodies' included."""
    from skynav.renderer.batch import render_batch

    opts = RenderOptions(backend="llvm", mitsuba_spp=4, cosmic_rays_per_frame=0.0)
    scenes, seeds = [_departure(psf), _departure(psf, cx=6.0, cy=100.0)], [3, 4]
    dev = render_batch(scenes, seeds, options=opts, star_splat="device")
    host = render_batch(scenes, seeds, options=opts, star_splat="host")
    for i, (scene, seed) in enumerate(zip(scenes, seeds)):
        ref = expected_image(scene, rng=np.random.default_rng(seed), options=opts).electrons
        bright = ref > 1.0
        rel = np.abs(dev.electrons[i][bright] - ref[bright]) / ref[bright]
        assert rel.max() < REL_TOL, (i, rel.max())
        assert np.all(dev.electrons[i][~bright] < 1.01)
        (a,), (b,) = ([d for d in t.truths[i]["bodies"] if d["name"] == "earth"] for t in (dev, host))
        assert a["electrons"] == b["electrons"] and a["resolved"]
        assert (a.get("flux_fraction_drawn") is None) == (psf is None)  # a table kernel's: the blurred crop's share
        if psf is not None:
            assert a["flux_fraction_drawn"] == pytest.approx(b["flux_fraction_drawn"], rel=1e-12)
        np.testing.assert_allclose(a["centre_of_light_xy"], b["centre_of_light_xy"], rtol=0, atol=CENTRE_TOL_PX)


def _numpy_reference(bodies, shape):
    """The reference's blur and composite of ``bodies`` (expected_image's own steps): (image,
    centres of light, fractions drawn, electrons)."""
    from skynav.renderer.expected import _draw_resolved_bodies

    image, centre, fraction = np.zeros(shape), {}, {}
    body_e = {t.name: 1.0 for t in bodies}
    _draw_resolved_bodies(bodies, RenderOptions(), (body_e, dict(body_e)), (image, None), [], centre, fraction)
    return image, centre, fraction, body_e


def test_bodies_of_different_kernels_and_a_dark_one_in_one_launch(monkeypatch):
    """Three bodies of one frame, each blurred by its own kernel (a polychromatic camera's
    per-body kernels; stamps of 9 and 33 px padded to one size on the device), one of them
    unlit and one across the bottom edge, in launches of a few lanes each (the split of a
    large convolution): the reference's image and truth."""
    from drjit.llvm import Float  # Dr.Jit only once the LLVM backend is known to work (the autouse skip)

    import skynav.renderer.bodies_jit as bodies_jit

    monkeypatch.setattr(bodies_jit, "_MAX_LANES", 5000)  # a few hundred crop pixels a launch
    dark = SimpleNamespace(x0=10, y0=10, electrons=np.zeros((8, 8)), electrons_total=0.0)
    bodies = [TracedBody(name="a", image=_synthetic_body(30, 20), kernel=GaussianKernel(0.7), at_xy=np.array([41.0, 32.0])),
              TracedBody(name="b", image=_synthetic_body(90, 110), kernel=kernel_for(paper_camera(psf=AIRY)),
                         at_xy=np.array([101.0, 122.0])),
              TracedBody(name="c", image=dark, kernel=GaussianKernel(0.7), at_xy=np.array([14.0, 14.0]))]
    ref, centre, fraction, body_e = _numpy_reference(bodies, (PX, PX))
    crops = body_crops(bodies, RenderOptions().flux_fraction_lost)
    assert sorted({s.shape[0] for s in crops.stamps}) == [9, 33]
    sig, moments = composite_bodies(Float(np.zeros(PX * PX, np.float32)), [crops], (PX, PX))
    got = sig.numpy().reshape(PX, PX)
    bright = ref > FLOOR * ref.max()
    assert (np.abs(got[bright] - ref[bright]) / ref[bright]).max() < REL_TOL
    assert np.abs(got[~bright] - ref[~bright]).max() < 1e-14 * ref.max()
    stub = _ExpectedStub(body_electrons={t.name: 1.0 for t in bodies})
    truth = bodies_truth([stub], [crops], moments.numpy())[0]
    assert truth.body_centre_of_light.keys() == centre.keys() == {"a", "b"}  # the dark body has no centre
    for name in centre:
        np.testing.assert_allclose(truth.body_centre_of_light[name], centre[name], rtol=0, atol=CENTRE_TOL_PX)
        assert abs(truth.body_fraction_drawn[name] - fraction[name]) < 1e-12
    assert truth.body_electrons == body_e and truth.body_fraction_drawn.keys() == fraction.keys()
