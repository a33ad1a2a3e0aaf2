"""The point sources drawn by Dr.Jit (renderer/splat_jit.py, splat_tables_jit.py) for every PSF
model but the Gaussian (tests/renderer/test_batch_splat.py): Airy, optical with coma, a measured
table, a field grid of them, a polychromatic Airy (stars at their effective wavelengths, each
body with its own spectrum's table), static and streaked, against the numpy reference
(``expected_image``): the expected image, and the truth's centres of light and fractions drawn."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from skynav.renderer.batch import _device_stars, render_batch
from skynav.renderer.expected import expected_image
from skynav.renderer.optics import airy_intensity, kernel_for
from skynav.renderer.radiometry import Radiometry
from skynav.renderer.render import RenderOptions
from skynav.scenes import build_from_spec, default_scene_spec
from tests.renderer.conftest import llvm_or_skip

#: Relative difference per pixel allowed against the reference, on the pixels above 1e-3 of the
#: frame's peak or 1 e- (as tests/renderer/test_batch_splat.py): both sum each pixel's stamps
#: in float64 (a pixel of a streak sums hundreds of sub-samples; the device in another order)
#: and round to float32 once (6e-8; measured 6e-8, where float32 sums on the device gave 4e-6).
REL_TOL = 1e-5

#: The truth's centres of light, px, against the reference's: both are float64 sums of the same
#: float64 stamp values (the same bilinear reads, in the same order), in another order (atomic
#: adds on the device); 1e-12 relative of coordinates below 1024 px is 1e-9 px.
CENTRE_TOL_PX = 1e-9

#: The fractions drawn, relative: float64 sums of the same values in another order.
FRACTION_RTOL = 1e-12

COMA = {4: 0.3, 7: 0.2, 8: -0.1}


@pytest.fixture(autouse=True)
def _llvm():
    llvm_or_skip()


def _airy_file(path, lf_px, shift=(0.0, 0.0), half_px=10, oversampling=4):
    """An Airy image (lambda F = ``lf_px``) sampled ``oversampling`` times a px, saved as .npy."""
    n = 2 * half_px * oversampling + 1
    u = (np.arange(n) - n // 2) / oversampling
    np.save(path, airy_intensity(np.hypot(u[None, :] - shift[0], u[:, None] - shift[1]), lf_px, 0.2))
    return str(path)


def _psf(name, tmp_path):
    if name in ("airy", "streaked"):
        return {"model": "airy", "obscuration": 0.2, "wavelength_nm": 550.0}
    if name == "airy-cut":
        return {"model": "airy", "obscuration": 0.2, "wavelength_nm": 550.0}
    if name == "optical":
        return {"model": "optical", "obscuration": 0.2, "wavelength_nm": 550.0, "zernike_waves": COMA}
    if name == "tabulated":
        return {"model": "tabulated", "file": _airy_file(tmp_path / "a.npy", 1.2), "oversampling": 4}
    if name == "field":
        pts = [{"x_px": x, "y_px": y, "file": _airy_file(tmp_path / f"f{x}_{y}.npy", 1.2, shift=(0.003 * x, 0.002 * y))}
               for x in (0.0, 127.0) for y in (0.0, 127.0)]
        return {"model": "tabulated", "field": pts, "oversampling": 4}
    return {"model": "airy", "obscuration": 0.1}  # polychromatic


def _scene(name, tmp_path, px=128):
    """The default scene at ``px`` (its 20 deg field; Mars in view, unresolved: drawn as a point),
    the camera stopped down to f/150 and exposed 20 s (lambda F = 0.75 px: 29 x 29 px stamps);
    for ``airy-cut`` the default camera's f-number and pitch at 256 px (a 5 deg field, lambda F =
    0.09 px), exposed 200 s: its stars' stamps are cut to 12 .. 16 px by their charge."""
    spec = default_scene_spec()
    cam = spec.camera
    if name == "airy-cut":
        px, kw = 256, {"exposure_s": 200.0}
    else:
        kw = {"f_number": 150.0, "exposure_s": 20.0, "pixel_pitch_um": cam.pixel_pitch_um * cam.width / px}
    camera = cam.replace(width=px, height=px, psf=_psf(name, tmp_path), **kw)
    scene = build_from_spec(dataclasses.replace(spec, camera=camera))
    rate = (0.0004, -0.0002, 0.001) if name == "streaked" else (0.0, 0.0, 0.0)
    return dataclasses.replace(scene, angular_velocity_rad_s=np.asarray(rate, dtype=float))


def _check_frames(scene, opts, seeds, min_bright):
    """The device's expected images and truths against the reference's (``expected_image``, and
    the batch with the stars drawn by numpy for the truth records)."""
    batch = render_batch([scene] * len(seeds), seeds, options=opts, star_splat="device")
    host = render_batch([scene] * len(seeds), seeds, options=opts, star_splat="host")
    for i, seed in enumerate(seeds):
        ref = expected_image(scene, rng=np.random.default_rng(seed), options=opts)
        got = batch.electrons[i].astype(float)
        bright = ref.electrons > min(1e-3 * ref.electrons.max(), 1.0)
        assert np.count_nonzero(bright) > min_bright
        rel = np.abs(got[bright] - ref.electrons[bright]) / ref.electrons[bright]
        assert rel.max() < REL_TOL, (rel.max(), int(bright.sum()))
        assert np.all(got[~bright] < 1.01)
        drawn = 0
        for a, b in zip(batch.truths[i]["stars"], host.truths[i]["stars"]):
            assert a["electrons"] == b["electrons"] and a["hip"] == b["hip"]
            assert (a["centre_of_light_xy"][0] is None) == (b["centre_of_light_xy"][0] is None)
            if b["centre_of_light_xy"][0] is not None:
                np.testing.assert_allclose(a["centre_of_light_xy"], b["centre_of_light_xy"], rtol=0, atol=CENTRE_TOL_PX)
                drawn += 1
            np.testing.assert_allclose(a.get("flux_fraction_drawn", np.nan), b.get("flux_fraction_drawn", np.nan),
                                       rtol=FRACTION_RTOL)
        assert drawn > 10
        for a, b in zip(batch.truths[i]["bodies"], host.truths[i]["bodies"]):
            assert a.keys() == b.keys(), (a["name"], set(a) ^ set(b))
            for k in a:
                if k in ("centre_of_light_xy", "flux_fraction_drawn"):
                    np.testing.assert_allclose(np.asarray(a[k], float), np.asarray(b[k], float), rtol=FRACTION_RTOL,
                                               atol=CENTRE_TOL_PX)
                else:
                    np.testing.assert_equal(a[k], b[k], err_msg=k)
    return batch, host


@pytest.mark.parametrize("name", ["airy", "airy-cut", "optical", "tabulated", "field", "polychromatic", "streaked"])
def test_device_table_stars_are_the_reference_expected_image(name, tmp_path):
    scene = _scene(name, tmp_path)
    opts = RenderOptions(backend="llvm", cosmic_rays_per_frame=0.0)
    batch, _ = _check_frames(scene, opts, [3, 4], 300)
    mars = [b for b in batch.truths[0]["bodies"] if b["name"] == "mars"][0]
    assert mars["rendered_as"] == "point" and 0.5 < mars["flux_fraction_drawn"] <= 1.0 + 1e-12
    if name == "airy-cut":  # the faint stars are drawn with smaller stamps than the kernel's
        k = kernel_for(scene.camera, None, opts.flux_fraction_lost)
        e = Radiometry.for_camera(scene.camera).star_electrons_per_s(scene.stars.v_mag, scene.stars.teff_k)
        assert len(np.unique(k.half_sizes_px(np.asarray(e) * scene.camera.exposure_s))) > 2


def test_a_body_forced_to_a_point_is_the_reference():
    """The default frame at 256 px with the Gaussian PSF, its bodies never ray-traced
    (``resolved=False``): Mars drawn as a point at its photocentre on the device."""
    spec = default_scene_spec()
    cam = spec.camera
    camera = cam.replace(width=256, height=256, pixel_pitch_um=cam.pixel_pitch_um * 4)
    scene = build_from_spec(dataclasses.replace(spec, camera=camera))
    opts = RenderOptions(backend="llvm", cosmic_rays_per_frame=0.0, resolved=False, background_e_per_px_s=5.0)
    batch, host = _check_frames(scene, opts, [7], 1000)
    mars = [b for b in batch.truths[0]["bodies"] if b["name"] == "mars"][0]
    assert mars["rendered_as"] == "point" and "centre_of_light_xy" in mars and "photocentre_xy" in mars


def test_every_model_may_be_drawn_on_the_device(tmp_path):
    """``star_splat="device"`` draws every model's point sources on the device, ``host`` never;
    ``auto`` on CUDA always, on LLVM a table model's point sources, its ray-traced bodies' blur
    and the Gaussian's stars left to numpy (the measured choice)."""
    opts = RenderOptions(backend="llvm")
    for name in ("airy", "optical", "tabulated", "polychromatic"):
        scene = _scene(name, tmp_path, px=64)
        assert _device_stars("device", "llvm", scene, opts) and not _device_stars("host", "cuda", scene, opts)
        assert _device_stars("auto", "cuda", scene, opts)
        assert _device_stars("auto", "llvm", scene, opts) == "points"
    gaussian = build_from_spec(default_scene_spec())
    assert not _device_stars("auto", "llvm", gaussian, opts) and _device_stars("auto", "cuda", gaussian, opts)


def test_llvm_auto_draws_an_airy_frame_s_stars_on_the_device_and_its_bodies_on_the_host():
    """The Earth-departure scene at 128 px with an Airy PSF (the Earth and the Moon ray-traced):
    ``star_splat="auto"`` on LLVM draws the stars on the device and blurs the bodies with numpy;
    the expected image and the truth are the reference's."""
    from skynav.scenes.config import scene_spec_from_mapping
    from skynav.scenes.presets import preset_mapping

    m = preset_mapping("earth_departure")
    m["camera"].update({"width": 128, "height": 128, "psf": {"model": "airy", "wavelength_nm": 550.0}})
    scene = build_from_spec(scene_spec_from_mapping(m))
    opts = RenderOptions(backend="llvm", cosmic_rays_per_frame=0.0, mitsuba_spp=4)
    assert _device_stars("auto", "llvm", scene, opts) == "points"
    batch = render_batch([scene], [5], options=opts)
    ref = expected_image(scene, rng=np.random.default_rng(5), options=opts)
    assert ref.resolved  # a body ray-traced
    got = batch.electrons[0].astype(float)
    bright = ref.electrons > min(1e-3 * ref.electrons.max(), 1.0)
    rel = np.abs(got[bright] - ref.electrons[bright]) / ref.electrons[bright]
    assert rel.max() < REL_TOL and np.all(got[~bright] < 1.01)
    host = render_batch([scene], [5], options=opts, star_splat="host")
    for a, b in zip(batch.truths[0]["bodies"], host.truths[0]["bodies"]):
        assert a == b  # the bodies drawn by numpy in both
    for a, b in zip(batch.truths[0]["stars"], host.truths[0]["stars"]):
        if b["centre_of_light_xy"][0] is not None:
            np.testing.assert_allclose(a["centre_of_light_xy"], b["centre_of_light_xy"], rtol=0, atol=CENTRE_TOL_PX)


def test_a_frame_s_device_drawn_figures_do_not_depend_on_its_batch(tmp_path):
    """Stream items are reproducible per (seed, index) whatever the batch size: the same code and
    the same seed draw a frame on the device in launches of 1, 2 or 4 frames, beside different
    frames, with the same bits in its expected image, DN and truth (its sources' moments are
    summed without atomics)."""
    still, streaked = _scene("airy", tmp_path), _scene("streaked", tmp_path)
    opts = RenderOptions(backend="llvm")
    seeds = [7, 8, 9, 10]
    runs = [render_batch([still, streaked, still, streaked], seeds, options=opts, star_splat="device",
                         frames_per_launch=n) for n in (4, 1, 2)]
    alone = render_batch([streaked], [8], options=opts, star_splat="device")
    for other in runs[1:]:
        np.testing.assert_array_equal(other.electrons, runs[0].electrons)
        np.testing.assert_array_equal(other.dn, runs[0].dn)
        for a, b in zip(other.truths, runs[0].truths):
            assert {k: v for k, v in a.items() if k != "render"} == {k: v for k, v in b.items() if k != "render"}
    np.testing.assert_array_equal(alone.electrons[0], runs[0].electrons[1])
    assert alone.truths[0]["stars"] == runs[0].truths[1]["stars"]
    assert alone.truths[0]["bodies"] == runs[0].truths[1]["bodies"] or all(
        np.testing.assert_equal(a, b) is None for a, b in zip(alone.truths[0]["bodies"], runs[0].truths[1]["bodies"]))
