"""The render driver: identities on whole frames (flux in = flux out; determinism), the split
into the expected image and the detection, the frame-seeded Mitsuba sampling, and what the truth
records (cosmic-ray tracks, the backend that ran)."""

import math

import numpy as np
import pytest

from skynav.infra.errors import ConfigValueError
from skynav.renderer.kernels import GaussianKernel
from skynav.renderer.expected import blur_crop
from skynav.renderer.render import RenderOptions, render
from skynav.scenes import presets
from skynav.scenes.scene import build_from_spec


def test_blur_crop_conserves_flux_and_centroid():
    rng = np.random.default_rng(3)
    crop = np.zeros((16, 16))
    crop[5:9, 6:11] = rng.uniform(1, 2, (4, 5))
    out, pad = blur_crop(crop, GaussianKernel(0.5), 1e-6)
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


# ----------------------------------------------------------------------------- the split
def test_render_is_expected_image_then_detect(scene):
    """``render`` composes the two halves: the same generator through ``expected_image`` and
    ``detect`` gives the same bits (the same code with the same seed; the frame's stream feeds
    only the detection)."""
    from skynav.renderer.render import detect, expected_image

    opts = RenderOptions(backend="numpy")
    frame = render(scene, seed=21, options=opts)
    rng = np.random.default_rng(21)
    ex = expected_image(scene, rng=rng, options=opts)
    det = detect(ex, scene.camera, rng, opts)
    assert np.array_equal(frame.dn, det.dn)
    assert np.array_equal(frame.electrons, det.electrons.astype(np.float32))
    assert np.array_equal(frame.irradiance_w_m2, ex.irradiance_w_m2.astype(np.float32))


class _NotACamera:
    """A Projection that only delegates to a camera: the renderer must use no other attribute."""

    def __init__(self, camera):
        self._c = camera
        self.width, self.height = camera.width, camera.height

    def project(self, v_cam):
        return self._c.project(v_cam)

    def line_of_sight(self, xy_px):
        return self._c.line_of_sight(xy_px)


def test_point_sources_placed_through_any_projection(scene):
    """Through a Projection that is not a Camera (here one delegating to the same camera) the
    stars of a still frame are bit-identical (the same code: ``project`` is the camera's own,
    with the same seed); the unresolved Mars' photocentre offset takes the
    image scale from a finite difference of ``project`` instead of the focal length (1e-6 px
    apart: the offset is 0.014 px, the difference quotient exact to ~1e-6 relative), so its
    pixels agree to 1e-12 of the brightest. A rotating frame samples its streaks with the generic
    sweep bound (a different number of path samples), so it agrees to the streak quadrature:
    1e-4 of the frame total and 2e-3 of the brightest pixel (the pixel-level error of the
    piecewise-linear arc between samples spaced <= 0.5 px)."""
    from skynav.renderer.render import expected_image
    from skynav.scenes.scene import build_scene

    opts = RenderOptions(noise=False)
    a = expected_image(scene, rng=np.random.default_rng(0), options=opts)
    b = expected_image(scene, projection=_NotACamera(scene.camera), rng=np.random.default_rng(0), options=opts)
    assert np.array_equal(a.star_electrons, b.star_electrons)
    assert np.allclose(b.body_photocentre["mars"], a.body_photocentre["mars"], rtol=0, atol=1e-6)
    mars = (slice(500, 524), slice(500, 524))
    outside = np.ones(a.electrons.shape, bool)
    outside[mars] = False
    assert np.array_equal(a.electrons[outside], b.electrons[outside])
    assert np.max(np.abs(a.electrons - b.electrons)) < 1e-12 * a.electrons.max()
    rot = build_scene(scene.epoch_tdb_s, position_km=scene.position_km, velocity_km_s=scene.velocity_km_s,
                      R_cam_icrs=scene.R_cam_icrs, camera=scene.camera, angular_velocity_rad_s=(2e-3, -1.5e-3, 4e-3))
    a = expected_image(rot, rng=np.random.default_rng(0), options=opts)
    b = expected_image(rot, projection=_NotACamera(rot.camera), rng=np.random.default_rng(0), options=opts)
    assert abs(b.electrons.sum() / a.electrons.sum() - 1.0) < 1e-4
    assert np.max(np.abs(b.electrons - a.electrons)) < 2e-3 * a.electrons.max()


def test_projection_of_another_size_is_refused(scene):
    from skynav.renderer.render import expected_image

    class Small(_NotACamera):
        def __init__(self, camera):
            super().__init__(camera)
            self.width = camera.width // 2

    with pytest.raises(ConfigValueError, match="projection.size"):
        expected_image(scene, projection=Small(scene.camera), rng=np.random.default_rng(0))


# ----------------------------------------------------------------------------- Mitsuba seeds
@pytest.fixture(scope="module")
def departure():
    from skynav.scenes.config import scene_spec_from_mapping

    return build_from_spec(scene_spec_from_mapping(presets.preset_mapping("earth_departure")))


def _disk_windows(frame):
    """{body: electrons of the window around its ray-traced disk}, cosmic-ray pixels zeroed."""
    t = frame.truth
    img = frame.electrons.astype(np.float64).copy()
    for c in t["cosmic_rays"]:  # single-pixel hits (the default): the pixel at xy
        img[int(round(c["xy"][1])), int(round(c["xy"][0]))] = 0.0
    out = {}
    for b in t["bodies"]:
        if b.get("rendered_as") == "mitsuba":
            x, y = b["centre_of_figure_xy"]
            r = b["radius_px"] + 6  # + the PSF's reach
            out[b["name"]] = img[int(y - r):int(y + r) + 1, int(x - r):int(x + r) + 1]
    return out


def test_mitsuba_sampling_follows_the_frame_seed(departure):
    """Each frame ray-traces its disks with seeds from its own stream: two frame seeds give
    different Earth and Moon crops whose physical totals agree within the sampling noise, and
    the same seed gives identical frames (the same code). (Before, every body was traced with
    Mitsuba seed 0, so the crops of seeds 1 and 2 were bit-identical.)

    Noise: the raw (un-normalised) totals scatter by 1.0e-3 (Earth, 31 px) and 3.4e-3 (Moon,
    12 px) at 16 spp (measured over 8 seeds); a difference of two is sqrt(2) that, and the bounds
    are ~5 sigma. The phase-law-normalised totals are equal by construction."""
    opts = RenderOptions(noise=False)
    f1 = render(departure, seed=1, options=opts)
    f2 = render(departure, seed=2, options=opts)
    f1b = render(departure, seed=1, options=opts)
    w1, w2 = _disk_windows(f1), _disk_windows(f2)
    assert set(w1) == {"earth", "moon"}
    for name in w1:
        assert not np.array_equal(w1[name], w2[name]), name
        assert np.array_equal(w1[name], _disk_windows(f1b)[name]), name
        assert w1[name].sum() == pytest.approx(w2[name].sum(), rel=1e-6)  # phase-law normalised (float32 frame)
    raw = {s: {b["name"]: b["electrons_raw"] for b in f["bodies"] if b.get("rendered_as") == "mitsuba"}
           for s, f in ((1, f1.truth), (2, f2.truth))}
    assert abs(raw[1]["earth"] / raw[2]["earth"] - 1.0) < 7e-3
    assert abs(raw[1]["moon"] / raw[2]["moon"] - 1.0) < 2.4e-2
    seeds = [b["mitsuba_seeds"] for b in f1.truth["bodies"] if b.get("rendered_as") == "mitsuba"]
    assert len({s[0] for s in seeds}) == 2  # Earth and Moon draw different seeds


def test_same_seed_same_frame_with_resolved_bodies(departure):
    a = render(departure, seed=3)
    b = render(departure, seed=3)
    assert np.array_equal(a.dn, b.dn) and np.array_equal(a.electrons, b.electrons)


def test_support_holds_every_lit_pixel(scene, departure):
    """``ExpectedImage.support`` lists every nonzero pixel of the electrons and irradiance images
    (stars, point bodies, the ray-traced Earth and Moon), so the float32 images converted over
    it alone equal the full conversion: a pixel missed would be a star's charge lost from the
    frame's EXR and from the sensor's input. With a background every pixel is lit: no support,
    the full conversion."""
    from skynav.renderer.render import expected_image
    from skynav.renderer.sparse_images import float32_image

    for sc in (scene, departure):
        exp = expected_image(sc, rng=np.random.default_rng(2), options=RenderOptions())
        assert exp.support is not None
        for img in (exp.electrons, exp.irradiance_w_m2):
            lit = np.flatnonzero(img)
            assert lit.size > 1000 and np.isin(lit, exp.support).all()
            np.testing.assert_array_equal(float32_image(img, exp.support), img.astype(np.float32))
    assert expected_image(scene, rng=np.random.default_rng(2), options=RenderOptions(background_e_per_px_s=1.0)).support is None


def test_a_frame_after_others_is_the_frame_alone(scene, departure):
    """``render`` draws each frame into the float64 images of the frame before it, set back to
    zero where that one drew (``_ZERO_IMAGES``): a pixel left over would add one frame's stars,
    or the ray-traced Earth, to the next. Each frame of a run (stars; resolved bodies; a
    background, which lights every pixel and is not reused; stars again) equals the same frame
    rendered with no images kept from before."""
    import importlib

    render_module = importlib.import_module("skynav.renderer.sparse_images")
    runs = [(departure, 3, RenderOptions()), (scene, 4, RenderOptions()), (departure, 5, RenderOptions(noise=False)),
            (scene, 6, RenderOptions(background_e_per_px_s=2.0)), (scene, 7, RenderOptions()),
            (scene, 8, RenderOptions(backend="numpy"))]
    alone = []
    for sc, seed, options in runs:
        render_module._ZERO_IMAGES.clear()
        alone.append(render(sc, seed=seed, options=options))
    kept = 0
    for (sc, seed, options), ref in zip(runs, alone):
        kept += bool(render_module._ZERO_IMAGES)
        got = render(sc, seed=seed, options=options)
        for name in ("dn", "electrons", "irradiance_w_m2"):
            assert np.array_equal(getattr(got, name), getattr(ref, name)), (seed, name)
    assert kept >= 3  # the images were reused


# ----------------------------------------------------------------------------- truth
def _with_cosmic_rays(scene, options, rate):
    """The scene and options with ``rate`` cosmic rays per frame, wherever the rate lives."""
    import dataclasses

    if "cosmic_rays_per_frame" in {f.name for f in dataclasses.fields(RenderOptions)}:
        return scene, dataclasses.replace(options, cosmic_rays_per_frame=rate)
    return dataclasses.replace(scene, camera=scene.camera.replace(cosmic_rays_per_frame=rate)), options


@pytest.mark.parametrize("track_prob", [0.0, 0.5])
def test_truth_carries_every_cosmic_ray_track(scene, track_prob):
    """Every hit reaches the truth with its whole track, and the charge is conserved: the truth's
    per-pixel charges rebuild the deposited image, each hit's electrons are the sum of its
    pixels, and the hits' electrons sum to the charge the frame holds beyond its sources.

    Reference: the same hits drawn directly (cosmic rays are the first draws of the frame's
    stream), and the frame without cosmic rays. Tolerance: 2 float32 ulps of the frame's
    ``electrons`` per pixel (the frames are stored in float32)."""
    from skynav.renderer.cosmic_rays import draw_cosmic_rays

    tracks = {"cosmic_ray_track_prob": track_prob} if track_prob else {}  # the default: single-pixel hits
    opts = RenderOptions(cosmic_ray_mode="fixed", **tracks)  # the electrons image holds no sensor noise
    sc, opts = _with_cosmic_rays(scene, opts, 12)
    sc0, opts0 = _with_cosmic_rays(scene, opts, 0)
    frame = render(sc, seed=4, options=opts)
    bare = render(sc0, seed=4, options=opts0)
    hits = draw_cosmic_rays((sc.camera.height, sc.camera.width), 12, np.random.default_rng(4), mode="fixed",
                            track_prob=track_prob)
    truth = frame.truth["cosmic_rays"]
    assert len(truth) == len(hits) == 12
    if track_prob:
        assert 0 < sum(c["track"] for c in truth) < 12
    rebuilt = np.zeros(frame.electrons.shape)
    for i, c in enumerate(truth):
        assert c["xy"] == hits.xy[i].tolist() and c["electrons"] == hits.electrons[i]
        assert c["track"] == bool(hits.is_track[i])
        assert c["track_start_xy"] == hits.track_start_xy[i].tolist()
        assert c["track_end_xy"] == hits.track_end_xy[i].tolist()
        assert c["length_px"] == pytest.approx(math.hypot(*np.subtract(c["track_end_xy"], c["track_start_xy"])), abs=1e-12)
        px = np.array(c["pixels"], dtype=float).reshape(-1, 3)
        assert px[:, 2].sum() == pytest.approx(c["electrons"], rel=1e-12)
        if not c["track"]:
            assert c["track_start_xy"] == c["track_end_xy"] == c["xy"] and c["length_px"] == 0.0
            assert px[:, :2].tolist() == [[c["xy"][1], c["xy"][0]]]
        np.add.at(rebuilt, (px[:, 0].astype(int), px[:, 1].astype(int)), px[:, 2])
    deposited = frame.electrons.astype(np.float64) - bare.electrons.astype(np.float64)
    assert np.all(np.abs(deposited - rebuilt) <= 2 * np.spacing(frame.electrons).astype(np.float64))
    assert sum(c["electrons"] for c in truth) == pytest.approx(rebuilt.sum(), rel=1e-12)


def test_truth_records_the_backend_that_ran(scene, departure):
    """``render.backend`` is what was asked, ``render.backend_used`` what ran, and rendering
    again with the backend that ran gives the same bits (the same code with the same seed);
    ``render.mitsuba_variant`` names the
    variant that ray-traced the bodies (None when none was)."""
    from skynav.renderer import jit_backend, mitsuba_backend

    auto = render(scene, seed=8, options=RenderOptions(backend="auto"))
    r = auto.truth["render"]
    assert r["backend"] == "auto"
    assert r["backend_used"] == jit_backend.auto_sensor_backend()
    again = render(scene, seed=8, options=RenderOptions(backend=r["backend_used"]))
    assert np.array_equal(auto.dn, again.dn)
    assert r["mitsuba_variant"] is None
    assert render(scene, seed=8, options=RenderOptions(backend="numpy")).truth["render"]["backend_used"] == "numpy"
    assert render(scene, seed=8, options=RenderOptions(noise=False)).truth["render"]["backend_used"] == "numpy"
    traced = render(departure, seed=8, options=RenderOptions(backend="numpy"))
    assert traced.truth["render"]["mitsuba_variant"] == mitsuba_backend.current_variant()


def test_llvm_and_numpy_paths_agree_on_the_default_frame(scene):
    """The two sensor paths of one frame: what is not random, exactly; the noise, as statistics.

    Expectations: electrons (with the cosmic-ray charge), irradiance and truth come from the same
    numpy code before the sensor, and the cosmic rays are drawn from the frame's stream before
    it, so they are equal to the bit (same code, same seed) whatever the sensor backend.
    DN: two implementations of the same distributions (numpy's Generator against per-pixel PCG32
    streams in a Dr.Jit kernel) cannot be compared pixel by pixel. Dark pixels (no source: PRNU,
    dark current and read noise, most DN at the offset) by a chi-square homogeneity test of
    their DN histograms (p > 1e-4; each pixel draws once in each path from the same distribution,
    so the test is conservative). Bright star pixels (expected > 2000 e-, unsaturated): their DN
    sums differ by less than 5 standard deviations of the difference of two independent frames,
    sd^2 = 2 sum (K^2 (mu_e + sigma_d^2) + 1/12) DN^2 (EMVA 1288 variance with quantisation)."""
    from scipy import stats

    from tests.renderer.conftest import llvm_or_skip

    llvm_or_skip()
    a = render(scene, seed=31, options=RenderOptions(backend="numpy"))
    b = render(scene, seed=31, options=RenderOptions(backend="llvm"))
    assert np.array_equal(a.electrons, b.electrons) and np.array_equal(a.irradiance_w_m2, b.irradiance_w_m2)
    ta, tb = dict(a.truth), dict(b.truth)
    ra, rb = ta.pop("render"), tb.pop("render")
    assert ta == tb and (ra["backend_used"], rb["backend_used"]) == ("numpy", "llvm")
    assert {k: v for k, v in ra.items() if "backend" not in k} == {k: v for k, v in rb.items() if "backend" not in k}

    p = scene.camera.sensor
    dark = a.electrons == 0
    da, db = a.dn[dark].astype(int), b.dn[dark].astype(int)
    levels = np.arange(min(da.min(), db.min()), max(da.max(), db.max()) + 1)
    table = np.array([[np.sum(d == v) for v in levels] for d in (da, db)])
    table = table[:, table.sum(axis=0) >= 10]
    assert stats.chi2_contingency(table).pvalue > 1e-4

    bright = (a.electrons > 2000) & (a.dn < p.max_dn) & (b.dn < p.max_dn)
    mu = a.electrons[bright].astype(float)
    K, s2 = p.gain_dn_per_e, p.read_noise_e ** 2 + p.reset_noise_e ** 2
    sd = math.sqrt(2.0 * np.sum(K * K * (mu + s2) + 1.0 / 12.0))
    diff = float(np.sum(b.dn[bright].astype(float)) - np.sum(a.dn[bright].astype(float)))
    assert bright.sum() > 100 and abs(diff) < 5.0 * sd, (int(bright.sum()), diff, sd)


def test_no_noise_frames_of_two_seeds_are_identical(scene):
    """``noise=False`` (``skynav render --no-noise``) has no random part: no sensor noise and no
    cosmic rays, so frames of seeds 1 and 2 are equal, pixel for pixel (with noise they differ,
    by their cosmic rays among others): a determinism test of one code path."""
    opts = RenderOptions(noise=False, cosmic_rays_per_frame=3.0)
    a, b = render(scene, seed=1, options=opts), render(scene, seed=2, options=opts)
    assert np.array_equal(a.dn, b.dn) and np.array_equal(a.electrons, b.electrons)
    assert a.truth["cosmic_rays"] == b.truth["cosmic_rays"] == []
    noisy = [render(scene, seed=s, options=RenderOptions(cosmic_rays_per_frame=3.0, cosmic_ray_mode="fixed")) for s in (1, 2)]
    assert not np.array_equal(noisy[0].electrons, noisy[1].electrons)


def test_no_noise_command_line_frames_of_two_seeds_are_identical(tmp_path):
    """``skynav render --no-noise`` with seeds 1 and 2 (cosmic rays asked for): the same PNG bytes."""
    from skynav.cli import main

    small = ["--set", "camera.width=128", "--set", "camera.height=128", "--set", "render.cosmic_rays_per_frame=5"]
    for seed in (1, 2):
        assert main(["render", "-o", str(tmp_path / str(seed)), "--no-noise", "-q", "--seed", str(seed), *small]) == 0
    assert (tmp_path / "1" / "frame.png").read_bytes() == (tmp_path / "2" / "frame.png").read_bytes()
