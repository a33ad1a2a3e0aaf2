"""Frames in batches: the sensor chain of many frames as one Dr.Jit program, the frames kept on
the device until asked for.

What is batched, and why: in the default frame (1024^2, stars to V 9) the sensor chain takes
the larger part of a render's CPU time (docs/performance.md, "Batched frames"), the optics
(star splat with the PSF models and streaks, resolved bodies) most of the rest. This module runs
the optics of each frame as :func:`~skynav.renderer.render.render` does
(:func:`~skynav.renderer.expected.expected_image`, the numpy reference), draws each frame's
cosmic rays and sensor key from the frame's stream at the same point as the per-frame path, and
then runs the sensor chain of the whole batch (PRNU and dark current, Poisson charge, cosmic-ray
charge, full well, read noise, gain, ADC) as one kernel over N x H x W lanes: one Python body
traced for Dr.Jit's LLVM and CUDA backends (:func:`_batch_exposure`), as the per-frame sensor
kernel is (:mod:`skynav.renderer.sensor_jit`).

The kernel is the per-frame chain with one change: the Poisson inversion for means below
:data:`~skynav.renderer.sensor_jit.POISSON_INVERSION_MAX_MEAN` makes its first eight terms with
constant reciprocals, ``p(j) = p(j - 1) * (lam * (1 / j))``, unrolled before the loop, instead of
eight float64 divisions in every lane (the loop then runs only in the packets that need more
terms: for the dark sky's 2 e- means one pixel in four thousand). The pmf terms differ from the
per-frame kernel's by a rounding, so a frame's DN equal the per-frame path's DN of the same seed
except where ``u`` falls within a rounding of a cumulative sum (tested as statistics, with the
EMVA 1288 checks of the sensor tests, and as that rare difference). The expected images, the
cosmic rays and the truth are the per-frame path's.

The point sources may be drawn on the device too (``star_splat``; CUDA's default): for every
PSF model :mod:`~skynav.renderer.splat_jit` scatter-adds the stamps of the stars and of the
bodies drawn as points, streaks included, into the sensor's input, and their moments (the
truth's centres of light and fractions drawn) into small arrays brought back with the launch;
the ray-traced bodies, traced per frame by Mitsuba on the host, are blurred and composited
there too (:mod:`~skynav.renderer.bodies_jit`: a direct convolution with the PSF's blur stamp,
their moments brought back likewise), so that the host only ray-traces. The expected images
then equal the per-frame path's to roundings (a float64 sum in another order, rounded to
float32 once), not to the bit; a launch's truths are made once the next launch is under way.
"""

from __future__ import annotations

import dataclasses
import functools
import time
from dataclasses import dataclass

import numpy as np

from skynav.infra.errors import ConfigValueError
from skynav.infra.heap import WarmHeap

from . import cosmic_rays as cr
from . import jit_backend
from .detector import JIT_BACKENDS, PixelCharge, fixed_patterns
from .expected import expected_image
from .options import RenderOptions
from .render import Detection, sensor_backend
from .sensor_jit import (
    POISSON_INVERSION_MAX_MEAN,
    _INVERSION_MAX_K,
    _INVERSION_TERMS_PER_TRIP,
    _jit_module,
    _jit_poisson_ptrs,
    _jit_readout,
    _module_of,
    frame_key,
    pixel_stream_seeds,
)
from .batch_paths import batch_source_paths
from .bodies_jit import bodies_truth, body_crops, composite_bodies
from .splat_jit import frame_moments, frame_optics, splat_points, with_moments
from .truth import frame_truth

__all__ = ["FrameBatch", "render_batch", "expose_batch"]


def _poisson_small(u, lam64, small):
    """Poisson(lam) by sequential inversion in the ``small`` lanes (float64, lazy): the first
    :data:`_INVERSION_TERMS_PER_TRIP` terms unrolled with constant reciprocals, then the
    per-frame kernel's loop from there for the lanes whose ``u`` lies beyond them."""
    # Dr.Jit only for the JIT backends: import skynav.renderer loads neither Dr.Jit nor Mitsuba
    import drjit as dr

    Float64 = _module_of(u).Float64
    p = dr.exp(-lam64)
    f, k = Float64(p), Float64(0.0)
    for j in range(1, _INVERSION_TERMS_PER_TRIP + 1):  # k counts the F(0 .. j - 1) below u
        k = k + dr.select(u > f, 1.0, 0.0)
        p = p * (lam64 * (1.0 / j))
        f = f + p

    def cond(k, p, f):
        return small & (u > f) & (k < _INVERSION_MAX_K)

    def body(k, p, f):  # a lane here has k = the terms made so far, all below u
        step = Float64(0.0)
        for j in range(1, _INVERSION_TERMS_PER_TRIP + 1):
            step = step + dr.select(u > f, 1.0, 0.0)
            p = p * (lam64 / (k + float(j)))
            f = f + p
        return k + step, p, f

    return dr.while_loop((k, p, f), cond, body, labels=("k", "p", "f"), label="poisson_inversion_batch")[0]


def _batch_charge(mean, extra, key, pixel):
    """Poisson(mean) + extra over the batch's lanes, lazy, and the advanced PCG32 streams: lane j
    draws from the stream of pixel ``pixel[j]`` under its frame's key ``key`` (four UInt32 per
    lane), as the per-frame kernel's pixel does under that frame's key."""
    # Dr.Jit only for the JIT backends: import skynav.renderer loads neither Dr.Jit nor Mitsuba
    import drjit as dr

    jt = _module_of(mean)
    initstate, initseq = pixel_stream_seeds(key, pixel)
    pcg = jt.PCG32(dr.width(mean))
    pcg.seed(initstate, initseq)
    lam = dr.maximum(mean, 0.0)
    small = lam < POISSON_INVERSION_MAX_MEAN
    u = pcg.next_float64()
    k_small = _poisson_small(u, jt.Float64(lam), small)
    pcg, k_big = _jit_poisson_ptrs(pcg, lam, small)
    n = dr.select(small, jt.Float(k_small), k_big)
    return (n if extra is None else n + extra), pcg


def _batch_exposure(sig, gain, dark, extra, t, key, full_well, readout, pixel, small_dn):
    """The sensor chain (without blooming) over the batch's lanes: lazy DN."""
    # Dr.Jit only for the JIT backends: import skynav.renderer loads neither Dr.Jit nor Mitsuba
    import drjit as dr

    n, pcg = _batch_charge(dr.fma(sig, gain, dark * t), extra, key, pixel)
    return _jit_readout(dr.minimum(n, full_well), pcg, *readout, small_dn=small_dn)


@functools.lru_cache(maxsize=8)
def _patterns(params, shape, backend):
    """The PRNU and dark-current images of a sensor on a Dr.Jit backend (one copy per process)."""
    Float = _jit_module(backend).Float
    gain, dark = fixed_patterns(params, shape)
    return Float(gain.ravel()), Float(dark.ravel())


def expose_batch(params, electrons, exposure_s: float, keys, *, backend: str = "llvm", charges=None, stars=None,
                 background_e: float = 0.0):
    """Digital numbers of a batch of exposures of one sensor, as a lazy Dr.Jit array.

    Parameters
    ----------
    params : SensorParams
        The sensor.
    electrons : ndarray, shape (N, H, W), float32
        Expected electrons of each frame, e-.
    exposure_s : float
    keys : sequence of N tuples of 4 int
        Each frame's sensor key (:func:`~skynav.renderer.sensor_jit.frame_key` of its stream).
    backend : {"llvm", "cuda"}
    charges : sequence of N PixelCharge or None, optional
        Each frame's cosmic-ray charge (added after the shot noise, before the full well).
    stars : sequence of N FramePoints or None, optional
        Each frame's point sources (stars, bodies drawn as points), drawn into ``electrons`` on
        the device with ``background_e`` e- per pixel (:func:`~skynav.renderer.splat_jit.splat_points`).
    background_e : float

    Returns
    -------
    drjit UInt8 or UInt32 array, shape (N * H * W,)
        DN in frame-major, row-major order, on ``backend``'s device (``.numpy()`` brings them over).

    Raises
    ------
    ConfigValueError
        ``electrons`` is not (N, H, W), ``keys`` not N keys, or the sensor blooms (its column
        spreading is numpy's, per frame: :func:`~skynav.renderer.render.render`).
    """
    return _expose(params, electrons, exposure_s, keys, backend, charges, stars, background_e)[0]


def _expose(params, electrons, exposure_s, keys, backend, charges, stars, background_e, bodies=None):
    """:func:`expose_batch`'s DN, the sensor's input on the device (the expected electrons with
    the point sources and the ray-traced ``bodies`` drawn, before the cosmic rays) and the
    moments ``(point sources', bodies')`` (:func:`~skynav.renderer.splat_jit.splat_points`,
    :func:`~skynav.renderer.bodies_jit.composite_bodies`; each None without), all lazy."""
    # Dr.Jit only for the JIT backends: import skynav.renderer loads neither Dr.Jit nor Mitsuba
    import drjit as dr

    e = np.asarray(electrons)
    if e.ndim != 3 or len(keys) != e.shape[0]:
        raise ConfigValueError("electrons", f"shape {e.shape} with {len(keys)} keys", "(N, H, W) with N keys")
    if params.blooming:
        raise ConfigValueError("sensor.blooming", True, "False in a batch (a blooming sensor's frames: render())")
    jit_backend.require(backend)
    jt = _jit_module(backend)
    n_frames, shape = e.shape[0], e.shape[1:]
    hw = shape[0] * shape[1]
    lanes = dr.arange(jt.UInt32, n_frames * hw)
    frame, pixel = lanes // hw, lanes % hw
    key_cols = np.asarray(keys, dtype=np.uint32).reshape(n_frames, 4)
    if n_frames == 1:  # a one-element source would be gathered as a constant of the kernel: opaque
        key = tuple(dr.opaque(jt.UInt32, int(k)) for k in key_cols[0])
    else:
        key = tuple(dr.gather(jt.UInt32, jt.UInt32(key_cols[:, i].copy()), frame) for i in range(4))
    gain_img, dark_img = _patterns(params, tuple(shape), backend)
    gain, dark = dr.gather(jt.Float, gain_img, pixel), dr.gather(jt.Float, dark_img, pixel)
    # the cosmic-ray charge: an image in memory even without a hit (one kernel for every batch,
    # whether its frames were hit or not), the few pixels hit scattered into it on the device
    extra = dr.opaque(jt.Float, 0.0, n_frames * hw)
    if charges is not None and any(c is not None and len(c.index) for c in charges):
        idx = [np.asarray(c.index, np.int64) + i * hw for i, c in enumerate(charges) if c is not None]
        val = [np.asarray(c.electrons, np.float64) for c in charges if c is not None]
        u, total = PixelCharge(index=np.concatenate(idx), electrons=np.concatenate(val)).per_pixel()
        if u.size == 1:  # a one-element array would be a constant of the kernel: write the pixel twice
            u, total = np.repeat(u, 2), np.repeat(total, 2)
        dr.scatter(extra, jt.Float(total.astype(np.float32)), jt.UInt32(u.astype(np.uint32)))
    op = functools.partial(dr.opaque, jt.Float)
    readout = (op(float(np.hypot(params.read_noise_e, params.reset_noise_e))), op(params.gain_dn_per_e),
               op(params.offset_dn + 0.5), op(float(params.max_dn)))
    sig = jt.Float(np.ascontiguousarray(e, dtype=np.float32).ravel())
    moments = None
    if stars is not None or background_e:
        sig, moments = splat_points(sig, [] if stars is None else stars, tuple(shape), background_e)
    sig, body_moments = composite_bodies(sig, [] if bodies is None else bodies, tuple(shape))
    dn = _batch_exposure(sig, gain, dark, extra, op(float(exposure_s)), key, op(params.full_well_e), readout,
                         pixel, params.bit_depth <= 8)
    return dn, sig, (moments, body_moments)


@dataclass(frozen=True, kw_only=True, eq=False)
class FrameBatch:
    """A batch of rendered frames; the DN stay on the device until asked for.

    Attributes
    ----------
    dn_device : tuple of drjit arrays
        Digital counts on the device (UInt8 for bit depths <= 8, else UInt32), one array per
        launch of :func:`expose_batch` (``frames_per_launch`` frames each, frame-major).
    shape : tuple of int
        ``(N, H, W)``.
    electrons : ndarray, shape (N, H, W), float32, or None
        Expected electrons plus cosmic-ray charge per frame (the per-frame path's), e-; None
        when not asked for.
    truths : list of dict
        Each frame's ground truth (``skynav.frame/2``; ``render.sensor_program`` = ``"batch"``).
    backend : str
        The Dr.Jit backend of the sensor chain.
    timings_s : dict
        ``optics`` (expected images, cosmic rays, truths: numpy, this thread), ``launch`` (the
        sensor's inputs to the device and its kernel launched) and ``sensor_wait`` (the wait for
        the last launches once the optics are done), s.
    dtype : numpy dtype
        The DN's type on the host (uint8 or uint16).
    """

    dn_device: tuple
    shape: tuple
    electrons: np.ndarray | None
    truths: list
    backend: str
    timings_s: dict
    dtype: object = np.uint8

    @property
    def dn(self) -> np.ndarray:
        """The DN as a numpy array (N, H, W) of the camera's type (copied from the device)."""
        return np.concatenate([d.numpy() for d in self.dn_device]).reshape(self.shape).astype(self.dtype, copy=False)


def render_batch(scenes, seeds, *, rngs=None, options: RenderOptions = RenderOptions(),
                 frames_per_launch: int = 4, electrons: bool = True, star_splat: str = "auto") -> FrameBatch:
    """Render a batch of frames of one camera: the optics per frame, the sensor as one program.

    Frame i draws from ``numpy.random.default_rng(seeds[i])`` as :func:`render` does (the
    expected image's draws, the cosmic rays, then the sensor key), so its expected image,
    electrons, cosmic rays and truth are :func:`render`'s, and its DN are its sensor's statistics.

    Parameters
    ----------
    scenes : sequence of Scene
        The frames' scenes; every one with the same camera size and sensor.
    seeds : sequence
        Each frame's seed (int or ``numpy.random.SeedSequence``), recorded in its truth.
    rngs : sequence of numpy.random.Generator, optional
        Each frame's stream (used if given, as :func:`render`'s ``rng``; ``seeds`` are then only
        recorded).
    options : RenderOptions
        As :func:`render`'s; ``backend`` names the Dr.Jit backend (``auto``: the one
        :func:`render` would use; ``numpy`` is refused: the per-frame path is numpy's program).
    frames_per_launch : int
        Frames of one sensor launch: their optics are made, the kernel over their N x H x W
        lanes is launched, and the next frames' optics are made while the device runs it (the
        CPU's optics and the device's sensor overlap). The frames do not depend on it.
    electrons : bool
        Keep the frames' electrons (``FrameBatch.electrons``); False: None, and the sensor's
        inputs are let go every :data:`_FRAMES_IN_FLIGHT` frames (a large batch's memory stays
        that of a few frames but for its DN).
    star_splat : {"auto", "device", "host"}
        Where the point sources (stars, bodies drawn as points) and the ray-traced bodies' blur
        are drawn: ``device``, by Dr.Jit (:mod:`~skynav.renderer.splat_jit`, every PSF model;
        :mod:`~skynav.renderer.bodies_jit`); ``host``, per frame by numpy (:func:`expected_image`);
        ``auto``: ``device`` on CUDA; on LLVM the table models' point sources on the device, the
        bodies' blur and the Gaussian's stars on the host (docs/performance.md, "Batched frames").

    Returns
    -------
    FrameBatch

    Raises
    ------
    ConfigValueError
        No scene, scenes and seeds of different lengths, cameras of different sensors or sizes,
        ``noise=False``, a backend that is not a Dr.Jit one.

    Examples
    --------
    >>> import dataclasses
    >>> from skynav.renderer import RenderOptions, jit_backend
    >>> from skynav.renderer.batch import render_batch
    >>> from skynav.scenes import build_from_spec, default_scene_spec
    >>> spec = default_scene_spec()
    >>> camera = spec.camera.replace(width=64, height=64, pixel_pitch_um=spec.camera.pixel_pitch_um * 16)
    >>> scene = build_from_spec(dataclasses.replace(spec, camera=camera))
    >>> if jit_backend.llvm_available():
    ...     batch = render_batch([scene, scene], [1, 2])
    ...     print(batch.dn.shape, batch.electrons.dtype.name, batch.truths[1]["seeds"]["frame"])
    ... else:
    ...     print((2, 64, 64), "float32", 2)
    (2, 64, 64) float32 2
    """
    scenes, seeds, rngs, backend = _checked_batch(scenes, seeds, rngs, options, frames_per_launch)
    device = _device_stars(star_splat, backend, scenes[0], options)
    with WarmHeap() as heap:
        return _render_launches(scenes, seeds, rngs, options, frames_per_launch, electrons, backend, device, heap)


def _render_launches(scenes, seeds, rngs, options, frames_per_launch, electrons, backend, device, heap):
    """:func:`render_batch`'s launches, its arguments checked; ``heap`` (a :class:`WarmHeap`)
    is warmed once the first launch is under way. The frames' truths are thousands of small
    containers each, kept until the batch returns: the garbage collector would otherwise walk
    them, and everything a warm process holds, again and again as they pile up."""
    # Dr.Jit only for the JIT backends: import skynav.renderer loads neither Dr.Jit nor Mitsuba
    import drjit as dr

    cam = scenes[0].camera
    t0 = time.perf_counter()
    shape = (cam.height, cam.width)
    chunks, truths, launched, pending, t_launch, waiting = [], [], [], [], 0.0, None
    hold = max(1, _FRAMES_IN_FLIGHT // frames_per_launch)  # launches between waits, without electrons
    for first in range(0, len(scenes), frames_per_launch):
        ks = range(first, min(first + frames_per_launch, len(scenes)))
        sig = np.zeros((len(ks), *shape), np.float32)  # the sensor's input, read in place by the device
        paths = _star_paths([scenes[i] for i in ks], options) if device else [None] * len(ks)
        made = [_frame_optics(scenes[i], rngs[i], options, sig[j], device, paths[j]) for j, i in enumerate(ks)]
        # the last launch's moments, before this launch: reading waits for all the work queued
        fetched = None if waiting is None else _fetched(waiting[2])
        t = time.perf_counter()
        dn, sig_d, moments = _launch(cam, sig, made, backend, options, device, electrons)
        launched.append(dn)
        t_launch += time.perf_counter() - t
        if waiting is not None:  # the last launch's truths, while the device runs this one
            truths += _truths(scenes, seeds, options, backend, frames_per_launch, waiting[0], waiting[1], fetched)
        waiting = (ks, made, moments)
        heap.warm()
        chunks.append(sig_d if device else sig)
        pending.append([m[2] for m in made])
        if not electrons and len(chunks) >= hold:  # the inputs read: let them go
            dr.sync_thread()
            chunks.clear()
    truths += _truths(scenes, seeds, options, backend, frames_per_launch, waiting[0], waiting[1],
                      _fetched(waiting[2]))
    t1 = time.perf_counter()
    dr.sync_thread()  # the launches are done
    t2 = time.perf_counter()
    return FrameBatch(dn_device=tuple(launched), shape=(len(scenes), *shape),
                      electrons=_electrons(chunks, pending, device, shape) if electrons else None,
                      truths=truths, backend=backend,
                      timings_s={"optics": t1 - t0 - t_launch, "launch": t_launch, "sensor_wait": t2 - t1},
                      dtype=np.uint8 if cam.sensor.bit_depth <= 8 else np.uint16)


def _launch(cam, sig, made, backend, options, device, electrons):
    """One launch of :func:`render_batch`: the sensor (and with ``device`` the point sources and
    the bodies) of the frames ``made`` evaluated on the device, asynchronously; returns
    :func:`_expose`'s ``(dn, sensor input, moments)``."""
    # Dr.Jit only for the JIT backends: import skynav.renderer loads neither Dr.Jit nor Mitsuba
    import drjit as dr

    keys, charges, points, bodies = ([m[k] for m in made] for k in (0, 1, 5, 6))
    dn, sig_d, moments = _expose(cam.sensor, sig, cam.exposure_s, keys, backend, charges, points if device else None,
                                 options.background_e_per_px_s * cam.exposure_s if device else 0.0, bodies)
    points, bodies = moments
    lazy = ([] if points is None else points.arrays()) + ([] if bodies is None else [bodies])
    dr.eval(dn, *([sig_d] if device and electrons else []), *lazy)  # launched: the device works on it
    return dn, sig_d, moments


def _fetched(moments):
    """A launch's moments (:func:`_expose`'s: the point sources' PointMoments, the bodies') as
    numpy arrays, or None where there are none. Bringing them over waits for the work queued on
    this thread's device stream, the launch's sensor kernel included."""
    points, bodies = moments
    return (None if points is None else points.numpy()), (None if bodies is None else bodies.numpy())


def _truths(scenes, seeds, options, backend, frames_per_launch, ks, made, fetched):
    """The truths of one launch's frames ``ks`` (their optics ``made``); with the point sources
    and the ray-traced bodies drawn on the device, their centres of light and fractions drawn
    from the launch's moments (``fetched``: :func:`_fetched`'s)."""
    figures = None if fetched[0] is None else frame_moments([m[5] for m in made], fetched[0])
    expecteds = bodies_truth([m[3] for m in made], [m[6] for m in made], fetched[1])
    out = []
    for j, i in enumerate(ks):
        expected, hits, points = expecteds[j], made[j][4], made[j][5]
        if points is not None:
            n = points.n_sources
            m0, m1 = figures[j] if figures is not None else (np.zeros(n), np.zeros((n, 2)))
            expected = with_moments(expected, points, m0, m1)
        det = Detection(dn=None, electrons=None, hits=hits, backend=backend)
        truth = frame_truth(scenes[i], expected, det, seed=seeds[i], options=options)
        truth["render"] = {**truth["render"], "sensor_program": "batch", "frames_per_launch": frames_per_launch}
        out.append(truth)
    return out


def _electrons(chunks, pending, on_device, shape):
    """The frames' electrons (N, H, W), float32: the sensor's inputs (``on_device``: brought
    from the device, where the stars were drawn into them) with each frame's cosmic-ray charge
    (``pending``: per launch, per frame, (hit pixels, electrons there with the charge; on the
    device, the charge alone)). Only once the launches are done: the device read the inputs in
    place."""
    if on_device:
        chunks = [np.array(c.numpy(), np.float32).reshape(-1, *shape) for c in chunks]
    for sig, hits_e in zip(chunks, pending):
        for j, (hit, value) in enumerate(hits_e):
            flat = sig[j].reshape(-1)
            flat[hit] = flat[hit] + value if on_device else value
    return np.concatenate(chunks)


#: The PSF models whose point sources ``star_splat="auto"`` draws on the device on LLVM too:
#: the table kernels', whose batches were faster so (docs/performance.md, "Batched frames");
#: not the Gaussian's small stamps.
_LLVM_DEVICE_MODELS = frozenset({"airy", "optical", "tabulated"})


def _device_stars(star_splat, backend, scene, options):
    """What the device draws (:func:`render_batch`'s ``star_splat``): ``"all"`` (the point
    sources and the ray-traced bodies' blur), ``"points"`` (the point sources; the bodies on the
    host: on LLVM their direct convolution does not pay) or False (nothing: numpy's frames)."""
    if star_splat not in ("auto", "device", "host"):
        raise ConfigValueError("star_splat", star_splat, "auto, device or host")
    if star_splat != "auto":
        return "all" if star_splat == "device" else False
    psf = scene.camera.psf
    if backend == "cuda":
        return "all"
    return "points" if psf.model in _LLVM_DEVICE_MODELS else False


def _checked_batch(scenes, seeds, rngs, options, frames_per_launch):
    """``(scenes, seeds, rngs, backend)`` of a batch :func:`render_batch` can make, as lists;
    else the :class:`ConfigValueError` naming what is not."""
    scenes, seeds = list(scenes), list(seeds)
    if isinstance(frames_per_launch, bool) or not isinstance(frames_per_launch, int) or frames_per_launch < 1:
        raise ConfigValueError("frames_per_launch", frames_per_launch, "an integer >= 1")
    rngs = [np.random.default_rng(seed) for seed in seeds] if rngs is None else list(rngs)
    if not scenes or len(scenes) != len(seeds) or len(rngs) != len(seeds):
        raise ConfigValueError("scenes", f"{len(scenes)} scenes and {len(seeds)} seeds", "one seed per scene, >= 1")
    cam = scenes[0].camera
    if any((s.camera.width, s.camera.height, s.camera.sensor) != (cam.width, cam.height, cam.sensor) for s in scenes):
        raise ConfigValueError("scenes", "cameras of different sizes or sensors", "one camera size and sensor per batch")
    if not options.noise:
        raise ConfigValueError("options.noise", False, "True (the batch program draws the noise; "
                               "noise-free frames: render())")
    backend = sensor_backend(options.backend)
    if backend not in JIT_BACKENDS:
        raise ConfigValueError("options.backend", options.backend, "llvm, cuda or auto on a machine with one of them")
    return scenes, seeds, rngs, backend


#: Frames whose sensor inputs are kept in memory at once when the electrons are not asked for
#: (render_batch waits for the device after that many, then lets the inputs go).
_FRAMES_IN_FLIGHT = 16


def _star_paths(scenes, options):
    """The stars' paths of a launch's frames, px, projected in one pass (the device draws them)."""
    return batch_source_paths(scenes, [s.stars.u_icrs for s in scenes], options)


def _frame_optics(scene, rng, options, sig, device=False, paths=None):  # device: _device_stars's
    """One frame's optics as :func:`render` makes them: its expected electrons rounded to
    float32 into ``sig`` (the sensor's input), its cosmic rays and sensor key from ``rng`` where
    the per-frame path draws them. Returns ``(key, charge, (hit pixels, electrons there with the
    charge), expected image without its images, hits, point sources, ray-traced bodies)``. With
    ``device``, the point sources (stars, bodies drawn as points), the ray-traced bodies (with
    ``"all"``) and the background are left out of ``sig`` for the device
    (:func:`~skynav.renderer.splat_jit.frame_optics`: FramePoints and
    :class:`~skynav.renderer.bodies_jit.BodyCrops`, else None; the expected image then lacks
    their centres of light), and the hit pixels' electrons are the charge alone (the device's
    input is added to it). ``paths``: the stars' paths with ``device``, px (default: projected
    for this frame alone)."""
    shape = sig.shape
    support = []  # the pixels drawn: a dark frame's stamps are a few per cent of it
    points = crops = None
    if not device:
        expected = expected_image(scene, rng=rng, options=options, with_irradiance=False, support=support)
    else:
        traced = [] if device == "all" else None  # else the bodies blurred on the host, into sig
        expected, points = frame_optics(scene, rng, options, support, paths=paths, traced_out=traced)
        crops = body_crops(traced, options.flux_fraction_lost) if traced else None
    hits = cr.draw_cosmic_rays(shape, options.cosmic_rays_per_frame, rng, mode=options.cosmic_ray_mode,
                               track_prob=options.cosmic_ray_track_prob)
    key = frame_key(rng)  # where the per-frame sensor draws it
    charge = PixelCharge(index=np.asarray(hits.pixel_rows, dtype=np.int64) * shape[1] + hits.pixel_cols,
                         electrons=hits.pixel_electrons)
    drawn = np.concatenate(support) if support else np.zeros(0, np.int64)
    sig.reshape(-1)[drawn] = expected.electrons.reshape(-1)[drawn]  # zero off the pixels drawn
    hit, hit_e = charge.per_pixel()
    if points is None:
        hits_e = (hit, expected.electrons.reshape(-1)[hit] + hit_e)  # summed in float64, as detect()
    else:
        hits_e = (hit, hit_e)
    # the truth needs the sources' figures, not the float64 images: let them go
    expected = dataclasses.replace(expected, electrons=None, irradiance_w_m2=None)
    return key, charge, hits_e, expected, hits, points, crops
