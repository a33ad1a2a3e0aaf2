"""The batched frame program against the per-frame path: the same expected images, electrons
and truth (same code), the sensor's statistics by the EMVA 1288 checks of the sensor tests and
scipy's Poisson pmf, and the DN of the same seed equal but for the rare rounding of the Poisson
inversion's cumulative sums."""

from __future__ import annotations

import dataclasses
import gc

import numpy as np
import pytest

import tests.renderer.test_detector_emva1288 as emva
from skynav.infra.errors import ConfigValueError
from skynav.renderer.batch import expose_batch, render_batch
from skynav.renderer.detector import PixelCharge, Sensor
from skynav.renderer.render import RenderOptions, render
from skynav.renderer.sensor_jit import frame_key
from skynav.scenes import build_from_spec, default_scene_spec
from tests.renderer.conftest import llvm_or_skip


@pytest.fixture(autouse=True)
def _llvm():
    llvm_or_skip()


class BatchedSensor(Sensor):
    """A Sensor whose exposures run through :func:`expose_batch` (one frame per launch, its key
    drawn from the frame's stream as the per-frame sensor draws it)."""

    def expose(self, electrons, exposure_s, rng, *, backend="llvm", extra_charge_e=None):
        charge = extra_charge_e
        if isinstance(charge, np.ndarray):
            nz = np.flatnonzero(charge)
            charge = PixelCharge(index=nz, electrons=charge.reshape(-1)[nz])
        e = np.asarray(electrons, dtype=np.float32)[None]
        dn = expose_batch(self.params, e, exposure_s, [frame_key(rng)], backend="llvm",
                          charges=None if charge is None else [charge])
        return dn.numpy().reshape(self.shape).astype(self.dtype)


@pytest.mark.parametrize("check", [emva.test_photon_transfer_gain_read_noise_dark_current,
                                   emva.test_prnu_and_dsnu_from_averaged_stacks,
                                   emva.test_per_pixel_variance_chi_square,
                                   emva.test_saturation_and_full_well], ids=lambda f: f.__name__[5:])
def test_batch_sensor_passes_the_emva_checks(check, monkeypatch):
    monkeypatch.setattr(emva, "Sensor", BatchedSensor)
    check("llvm")


@pytest.mark.parametrize("lam", [0.3, 2.5, 7.9, 9.9, 10.0, 150.0])
def test_batch_poisson_against_scipy_pmf(lam, monkeypatch):
    """The batch's inversion (its first terms unrolled) draws scipy's Poisson pmf."""
    monkeypatch.setattr(emva, "Sensor", BatchedSensor)
    emva.test_shot_noise_against_scipy_poisson_pmf("llvm", lam)


def test_frames_of_one_launch_are_independent_with_the_emva_variance():
    """Eight flat frames in one launch: each frame's temporal variance is K^2 (mu_e + sigma_d^2)
    + 1/12 (EMVA 1288 linear model; PRNU and DSNU cancel in frame differences), and two frames'
    noise is uncorrelated (each frame has its own key)."""
    p = emva.PTC
    shape, t, level = (128, 128), 0.05, 3000.0
    keys = [frame_key(np.random.default_rng(s)) for s in range(8)]
    e = np.full((8, *shape), level, np.float32)
    dn = expose_batch(p, e, t, keys, backend="llvm").numpy().reshape(8, *shape).astype(float)
    s = Sensor(p, shape)
    mu_e = level * s.prnu_gain.astype(float) + s.dark_e_per_s.astype(float) * t
    var = p.gain_dn_per_e ** 2 * (float(mu_e.mean()) + s.dark_noise_e ** 2) + 1.0 / 12.0
    diffs = dn[1:] - dn[:-1]  # var(y_i - y_j) = 2 var
    got = diffs.var(axis=(1, 2)) / 2
    assert np.all(np.abs(got / var - 1) < 0.05), (got, var)  # 16384 px: sd of a variance ~1.1 %
    resid = dn - dn.mean(axis=0)
    r = np.corrcoef(resid.reshape(8, -1))[np.triu_indices(8, 1)]
    assert np.all(np.abs(r + 1 / 7) < 0.04), r  # residuals about the mean of 8 correlate by -1/7


@pytest.fixture(scope="module")
def scene256():
    spec = default_scene_spec()
    camera = spec.camera.replace(width=256, height=256, pixel_pitch_um=spec.camera.pixel_pitch_um * 4)
    return build_from_spec(dataclasses.replace(spec, camera=camera))


def test_batch_frames_are_the_per_frame_frames(scene256):
    opts = RenderOptions(backend="llvm", cosmic_rays_per_frame=4)
    seeds = [11, 12, 13, 14, 15]
    batch = render_batch([scene256] * 5, seeds, options=opts, frames_per_launch=2)
    again = render_batch([scene256] * 5, seeds, options=opts, frames_per_launch=5)
    np.testing.assert_array_equal(batch.dn, again.dn)  # same code, same seeds: the launches do not matter
    dn = batch.dn
    differ = 0
    for i, seed in enumerate(seeds):
        frame = render(scene256, seed=seed, options=opts)
        # the expected image (and the cosmic-ray charge) is the per-frame path's, to the bit
        np.testing.assert_array_equal(batch.electrons[i], frame.electrons)
        truth = dict(batch.truths[i])
        render_rec = truth.pop("render")
        assert render_rec["sensor_program"] == "batch" and render_rec["backend_used"] == "llvm"
        assert truth == {k: v for k, v in frame.truth.items() if k != "render"}
        d = dn[i].astype(int) - frame.dn.astype(int)
        differ += int(np.count_nonzero(d))
    # two implementations of one chain: the Poisson draws differ only where u falls within a
    # rounding of a cumulative sum (~1e-16 relative): far below one pixel in 10^4
    assert differ <= 5 * dn[0].size * 1e-4


def test_without_electrons_the_inputs_go_and_the_frames_stay(scene256):
    """electrons=False lets the sensor's inputs go every few launches: the same DN and truths."""
    spec = default_scene_spec()
    small = build_from_spec(dataclasses.replace(spec, camera=spec.camera.replace(
        width=64, height=64, pixel_pitch_um=spec.camera.pixel_pitch_um * 16)))
    opts = RenderOptions(backend="llvm")
    seeds = list(range(20))  # 20 one-frame launches: the inputs are let go after 16
    kept = render_batch([small] * 20, seeds, options=opts, frames_per_launch=1)
    gone = render_batch([small] * 20, seeds, options=opts, frames_per_launch=1, electrons=False)
    assert gone.electrons is None and kept.electrons.shape == (20, 64, 64)
    np.testing.assert_array_equal(gone.dn, kept.dn)
    assert gone.truths == kept.truths


def test_render_batch_leaves_the_garbage_collector_as_it_found_it():
    """The batch keeps the collector off the warm heap while it runs (infra/heap.py), and gives
    it back: nothing frozen, the thresholds as they were; a caller's frozen heap is left alone."""
    spec = default_scene_spec()
    small = build_from_spec(dataclasses.replace(spec, camera=spec.camera.replace(
        width=64, height=64, pixel_pitch_um=spec.camera.pixel_pitch_um * 16)))
    opts = RenderOptions(backend="llvm")
    before = gc.get_threshold()
    assert gc.get_freeze_count() == 0
    render_batch([small] * 3, [1, 2, 3], options=opts, frames_per_launch=1)
    assert gc.get_freeze_count() == 0 and gc.get_threshold() == before
    gc.freeze()
    try:
        render_batch([small] * 2, [1, 2], options=opts, frames_per_launch=1)
        assert gc.get_freeze_count() > 0 and gc.get_threshold() == before  # still the caller's
    finally:
        gc.unfreeze()


def test_render_batch_refuses_what_it_cannot_do(scene256):
    for kwargs, words in (({"options": RenderOptions(backend="numpy")}, "options.backend"),
                          ({"options": RenderOptions(backend="llvm", noise=False)}, "options.noise"),
                          ({"frames_per_launch": 0}, "frames_per_launch")):
        with pytest.raises(ConfigValueError, match=words):
            render_batch([scene256], [1], **kwargs)
    with pytest.raises(ConfigValueError, match="one seed per scene"):
        render_batch([scene256, scene256], [1])
    blooming = dataclasses.replace(emva.PTC, blooming=True)
    with pytest.raises(ConfigValueError, match="sensor.blooming"):
        expose_batch(blooming, np.zeros((1, 4, 4), np.float32), 1.0, [(1, 2, 3, 4)])
