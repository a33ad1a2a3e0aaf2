"""Scene -> image: the software-mode render driver, in two steps a bench can separate.

:func:`~skynav.renderer.expected.expected_image` (the optics, :mod:`skynav.renderer.expected`):
sources -> noise-free electrons and in-band pupil irradiance per pixel, through any projection.

:func:`detect` (the sensor): cosmic-ray charge and the sensor chain (:mod:`detector`: PRNU, dark
current, shot noise, full well, read noise, gain, quantisation) turn expected electrons into
digital counts. Cosmic-ray charge joins after shot noise and PRNU, before the full-well limit.
A hardware-in-the-loop bench puts its display model where :func:`detect` is.

:func:`render` composes the two and writes the ground truth (:mod:`truth`); the options of both
are :class:`~skynav.renderer.options.RenderOptions`.

Randomness: the frame's ``numpy.random.Generator`` feeds the detection: cosmic rays draw from it
first, then the sensor, so a frame is reproduced bit for bit from its seed (per backend). The
Mitsuba seeds of resolved bodies come from a child stream, ``rng.spawn(1)[0]``, which leaves the
frame's stream untouched: every frame samples its disks differently, and the cosmic rays and
sensor noise are the draws they were before.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from skynav.infra.errors import ConfigValueError
from skynav.scenes.camera import Camera
from skynav.scenes.scene import Scene

from . import cosmic_rays as cr
from . import jit_backend
from .detector import JIT_BACKENDS, PixelCharge, Sensor
from .expected import ExpectedImage, expected_image
from .options import RenderOptions
from .sparse_images import float32_image, keep_zero_images, take_zero_images
from .truth import frame_truth


@dataclass(frozen=True, kw_only=True, eq=False)
class Frame:
    """One rendered frame.

    Attributes
    ----------
    dn : ndarray, shape (H, W), uint8 or uint16
        Digital counts at the camera's bit depth.
    electrons : ndarray, shape (H, W), float32
        Noise-free expected signal per pixel (sources + background + cosmic rays), e-.
    irradiance_w_m2 : ndarray, shape (H, W), float32
        In-band irradiance at the pupil per pixel from the sources, W/m^2.
    truth : dict
        Ground truth, schema ``skynav.frame/2`` (docs/conventions.md).

    Examples
    --------
    >>> import dataclasses
    >>> from skynav.renderer import RenderOptions, render
    >>> from skynav.scenes import build_from_spec, default_scene_spec
    >>> spec = default_scene_spec()   # the paper camera, pointing at Mars
    >>> camera = spec.camera.replace(width=64, height=64, pixel_pitch_um=spec.camera.pixel_pitch_um * 16)
    >>> scene = build_from_spec(dataclasses.replace(spec, camera=camera))   # 64 px, 20 deg
    >>> frame = render(scene, seed=1, options=RenderOptions(backend="numpy"))
    >>> frame.dn.shape, frame.dn.dtype.name, frame.electrons.dtype.name
    ((64, 64), 'uint8', 'float32')
    >>> frame.truth["schema"], frame.truth["seeds"]["frame"]
    ('skynav.frame/2', 1)
    """

    dn: np.ndarray
    electrons: np.ndarray
    irradiance_w_m2: np.ndarray
    truth: dict


@dataclass(frozen=True, kw_only=True, eq=False)
class Detection:
    """What the sensor made of an expected image.

    Attributes
    ----------
    dn : ndarray, shape (H, W), uint8 or uint16
        Digital counts.
    electrons : ndarray, shape (H, W), float32
        Expected electrons plus the cosmic-ray charge (no noise), e-: each pixel's float64 sum
        rounded to float32 (the frame's EXR channel).
    hits : CosmicRayHits
        The cosmic-ray hits of the frame.
    backend : str
        The sensor backend that ran: ``"llvm"``, ``"cuda"`` or ``"numpy"`` (the noise-free chain,
        ``RenderOptions(noise=False)``, is numpy).

    Examples
    --------
    >>> import dataclasses
    >>> from skynav.renderer import RenderOptions, render
    >>> from skynav.scenes import build_from_spec, default_scene_spec
    >>> spec = default_scene_spec()   # the paper camera, pointing at Mars
    >>> camera = spec.camera.replace(width=64, height=64, pixel_pitch_um=spec.camera.pixel_pitch_um * 16)
    >>> scene = build_from_spec(dataclasses.replace(spec, camera=camera))   # 64 px, 20 deg
    >>> from skynav.renderer import detect, expected_image
    >>> rng = np.random.default_rng(1)
    >>> det = detect(expected_image(scene, rng=rng), scene.camera, rng, RenderOptions(backend="numpy"))
    >>> det.backend, det.dn.dtype.name, int(det.dn.max()) <= scene.camera.sensor.max_dn
    ('numpy', 'uint8', True)
    """

    dn: np.ndarray
    electrons: np.ndarray
    hits: object
    backend: str


def sensor_backend(requested: str) -> str:
    """The sensor backend a request resolves to here: ``"auto"`` is
    :func:`~skynav.renderer.jit_backend.auto_sensor_backend` (``"llvm"``, else ``"cuda"``, else
    ``"numpy"``)."""
    if requested == "auto":
        return jit_backend.auto_sensor_backend()
    return requested


def detect(expected: ExpectedImage, camera: Camera, rng: np.random.Generator, options: RenderOptions = RenderOptions()) -> Detection:
    """The camera sensor's reading of an expected image: cosmic rays, noise, quantisation.

    Parameters
    ----------
    expected : ExpectedImage
        From :func:`expected_image` (or any image of the camera's size in ``electrons``).
    camera : Camera
        Sensor parameters (``camera.sensor``), exposure (dark current) and cosmic-ray rate.
    rng : numpy.random.Generator
        The frame's stream: cosmic rays draw first, then the sensor.
    options : RenderOptions
        ``cosmic_ray_mode``, ``cosmic_ray_track_prob``, ``noise`` and ``backend``.

    Returns
    -------
    Detection
        DN, the noise-free electrons plus cosmic-ray charge, the hits, the backend that ran.

    References
    ----------
    EMVA Standard 1288 (release 4.0, 2021), the linear camera model of the sensor chain.

    Examples
    --------
    The same expected image read twice from the same seed gives the same DN:

    >>> import dataclasses
    >>> from skynav.renderer import RenderOptions, render
    >>> from skynav.scenes import build_from_spec, default_scene_spec
    >>> spec = default_scene_spec()   # the paper camera, pointing at Mars
    >>> camera = spec.camera.replace(width=64, height=64, pixel_pitch_um=spec.camera.pixel_pitch_um * 16)
    >>> scene = build_from_spec(dataclasses.replace(spec, camera=camera))   # 64 px, 20 deg
    >>> from skynav.renderer import detect, expected_image
    >>> ex = expected_image(scene, rng=np.random.default_rng(1))
    >>> opts = RenderOptions(backend="numpy")
    >>> a = detect(ex, scene.camera, np.random.default_rng(7), opts)
    >>> b = detect(ex, scene.camera, np.random.default_rng(7), opts)
    >>> bool(np.array_equal(a.dn, b.dn))
    True
    """
    cam = camera
    electrons = expected.electrons
    shape = (cam.height, cam.width)
    if electrons.shape != shape:
        raise ConfigValueError("expected.electrons.shape", electrons.shape, f"the camera's (H, W) = {shape}")
    T = cam.exposure_s
    # --- cosmic rays: charge added after shot noise and PRNU, before the full-well limit; none
    # without noise (a noise-free frame has no random part: the same for every seed)
    if options.noise:
        hits = cr.draw_cosmic_rays(shape, options.cosmic_rays_per_frame, rng, mode=options.cosmic_ray_mode,
                                   track_prob=options.cosmic_ray_track_prob)
    else:
        hits = cr.draw_cosmic_rays(shape, 0, rng, mode="fixed")  # no hit, no draw
    # the charge of the few pixels hit, never a full image: electrons + charge is the image
    # cr.deposit(np.zeros(shape), hits) would give, added to the electrons, to the bit
    charge = PixelCharge(index=np.asarray(hits.pixel_rows, dtype=np.int64) * shape[1] + hits.pixel_cols,
                         electrons=hits.pixel_electrons)
    hit, hit_e = charge.per_pixel()
    sensor = Sensor(cam.sensor, shape)
    support = getattr(expected, "support", None)
    if options.noise:
        backend = sensor_backend(options.backend)
        # the Dr.Jit sensor reads float32 electrons: converted once, and the same array, with the
        # pixels hit set below, is the frame's electrons image (no float64 copy goes through)
        e_in = float32_image(electrons, support) if backend in JIT_BACKENDS else electrons
        dn = sensor.expose(e_in, T, rng, backend=backend, extra_charge_e=charge)
    else:
        backend = "numpy"
        e_in = electrons
        with_hits = electrons.copy()
        with_hits.reshape(-1)[hit] += hit_e
        dn = sensor.expected_dn(with_hits, T)
    total = e_in if e_in.dtype == np.float32 else float32_image(electrons, support)
    total.reshape(-1)[hit] = electrons.reshape(-1)[hit] + hit_e  # summed in float64, rounded once
    return Detection(dn=dn, electrons=total, hits=hits, backend=backend)


def render(scene: Scene, *, seed=None, rng: np.random.Generator | None = None,
           options: RenderOptions = RenderOptions(), projection=None) -> Frame:
    """Render one frame of a scene: :func:`expected_image`, then :func:`detect`, then the truth.

    Parameters
    ----------
    scene : Scene
        What is in view and how it is seen (:func:`skynav.scenes.build_from_spec`).
    seed : int or numpy.random.SeedSequence, optional
        Seed of the frame's random stream (recorded in the ground truth).
    rng : numpy.random.Generator, optional
        The random stream itself (used if given; ``seed`` is then only recorded).
    options : RenderOptions
        Accuracy, cosmic rays, noise and the sensor backend.
    projection : Projection, optional
        Pixel <-> line of sight (default ``scene.camera``).

    Returns
    -------
    Frame
        ``dn`` (H, W) uint8 or uint16, DN at the camera's bit depth; ``electrons`` (H, W)
        float32, e- (noise-free, with the cosmic rays); ``irradiance_w_m2`` (H, W) float32,
        W/m^2 at the pupil; ``truth``, the ``skynav.frame/2`` ground truth. In memory: files
        are :func:`skynav.datasets.write_frame`'s business.

    References
    ----------
    Andreis et al. (2023b): the rendering engine this reproduces; Andreis et al. (2024),
    Table 4: the default camera.

    Examples
    --------
    >>> import dataclasses
    >>> from skynav.renderer import RenderOptions, render
    >>> from skynav.scenes import build_from_spec, default_scene_spec
    >>> spec = default_scene_spec()   # the paper camera, pointing at Mars
    >>> camera = spec.camera.replace(width=64, height=64, pixel_pitch_um=spec.camera.pixel_pitch_um * 16)
    >>> scene = build_from_spec(dataclasses.replace(spec, camera=camera))   # 64 px, 20 deg
    >>> frame = render(scene, seed=1, options=RenderOptions(backend="numpy"))
    >>> frame.dn.shape, frame.dn.dtype.name
    ((64, 64), 'uint8')
    >>> mars = next(b for b in frame.truth["bodies"] if b["name"] == "mars")
    >>> mars["in_fov"], [round(c, 3) for c in mars["xy"]]   # the boresight, px
    (True, [31.5, 31.5])
    >>> again = render(scene, seed=1, options=RenderOptions(backend="numpy"))
    >>> bool(np.array_equal(again.dn, frame.dn))   # same seed, same backend: same DN
    True
    """
    if rng is None:
        rng = np.random.default_rng(seed)
    zeros = take_zero_images((scene.camera.height, scene.camera.width))
    expected = expected_image(scene, projection=projection, rng=rng, options=options, zeros=zeros)
    detection = detect(expected, scene.camera, rng, options)
    truth = frame_truth(scene, expected, detection, seed=seed, options=options)
    frame = Frame(dn=detection.dn, electrons=detection.electrons,
                  irradiance_w_m2=float32_image(expected.irradiance_w_m2, expected.support), truth=truth)
    keep_zero_images(expected)
    return frame
