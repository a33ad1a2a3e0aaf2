"""Scene -> image: the software-mode render driver.

Order of operations (all in expected electrons until the detector):

1. every point source (stars, unresolved bodies) gets electrons and in-band pupil irradiance from
   :mod:`radiometry`; its pixel path over the exposure is sampled from the attitude kinematics;
2. the pixel-integrated PSF is integrated along each path (:mod:`raster`);
3. resolved bodies are ray-traced by Mitsuba (:mod:`mitsuba_backend`) in crop windows, blurred by
   the same PSF and added;
4. a uniform sky background;
5. the sensor (:mod:`detector`) turns expected electrons into digital counts; cosmic-ray charge
   joins after shot noise and PRNU, before the full-well limit. The ``electrons`` EXR channel
   holds sources + background + cosmic-ray charge (no noise).

The random stream is one ``numpy.random.Generator``: cosmic rays draw from it first, then the
sensor; so a frame is reproduced bit for bit from its seed (per backend).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from skynav.scenes import frames
from skynav.scenes.errors import ConfigValueError
from skynav.scenes.scene import Scene


@dataclass(frozen=True, kw_only=True)
class RenderOptions:
    """Every speed/accuracy trade-off of a render in one value object.

    Attributes
    ----------
    flux_fraction_lost : float
        Largest fraction of a source's flux the PSF stamp may cut off.
    path_step_px : float
        Spacing of the samples along a curved source path, px (straight paths use 2 samples).
    background_e_per_px_s : float
        Uniform sky background (zodiacal + galactic), e-/px/s.
    cosmic_ray_mode : str
        ``"poisson"``: Poisson count with mean ``camera.cosmic_rays_per_frame``; ``"fixed"``.
    mitsuba_spp, mitsuba_time_samples : int
        Samples per pixel and sub-frame instants for resolved bodies.
    resolved : bool
        Ray-trace bodies flagged ``resolved`` (False: draw every body as a point).
    noise : bool
        Apply the sensor noise chain (False: DN of the expected signal, no randomness).
    backend : str
        ``"auto"``, ``"llvm"`` or ``"numpy"`` for the sensor.
    """

    flux_fraction_lost: float = 1e-6
    path_step_px: float = 0.5
    background_e_per_px_s: float = 0.0
    cosmic_ray_mode: str = "poisson"
    mitsuba_spp: int = 16
    mitsuba_time_samples: int = 1
    resolved: bool = True
    noise: bool = True
    backend: str = "auto"

    def __post_init__(self):
        if not 0 < self.flux_fraction_lost < 0.1:
            raise ConfigValueError("render.flux_fraction_lost", self.flux_fraction_lost, "in (0, 0.1)")
        if not self.path_step_px > 0:
            raise ConfigValueError("render.path_step_px", self.path_step_px, "> 0")
        if not self.background_e_per_px_s >= 0:
            raise ConfigValueError("render.background_e_per_px_s", self.background_e_per_px_s, ">= 0")
        if self.cosmic_ray_mode not in ("poisson", "fixed"):
            raise ConfigValueError("render.cosmic_ray_mode", self.cosmic_ray_mode, "poisson or fixed")
        if self.backend not in ("auto", "llvm", "numpy"):
            raise ConfigValueError("render.backend", self.backend, "auto, llvm or numpy")
        if self.mitsuba_spp < 1 or self.mitsuba_time_samples < 1:
            raise ConfigValueError("render.mitsuba_spp", self.mitsuba_spp, ">= 1")


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
        Ground truth, schema ``skynav.frame/1`` (CONVENTIONS.md).
    """

    dn: np.ndarray
    electrons: np.ndarray
    irradiance_w_m2: np.ndarray
    truth: dict


def sample_times(exposure_s: float, n: int) -> np.ndarray:
    """``n`` instants spread evenly over the exposure, relative to mid-exposure, s."""
    return np.linspace(-0.5 * exposure_s, 0.5 * exposure_s, n)


def source_paths(scene: Scene, u_icrs: np.ndarray, options: RenderOptions) -> np.ndarray:
    """Pixel paths (N, S, 2) of apparent directions (N, 3) over the exposure.

    Without rotation every path is two equal points. With a body rate the path is sampled every
    ``options.path_step_px`` along the largest sweep (rotation about the boresight makes arcs).
    """
    cam = scene.camera
    u = np.atleast_2d(np.asarray(u_icrs, dtype=float))
    w = np.asarray(scene.angular_velocity_rad_s, dtype=float)
    rate = float(np.linalg.norm(w))
    if rate == 0.0 or len(u) == 0:
        xy = cam.project(u @ scene.R_cam_icrs.T)
        return np.stack([xy, xy], axis=1)
    # largest sweep in px: cross-boresight rate x focal length, plus twist rate x corner radius
    sweep_px = cam.exposure_s * cam.focal_length_px * (
        math.hypot(w[0], w[1]) + abs(w[2]) * math.tan(cam.half_diagonal_fov_rad))
    n = int(min(512, max(2, math.ceil(sweep_px / options.path_step_px) + 1)))
    Rs = frames.propagate_attitude(scene.R_cam_icrs, w, sample_times(cam.exposure_s, n))
    v = np.einsum("sij,nj->nsi", Rs, u)
    return cam.project(v)


def render(scene: Scene, *, seed=None, rng: np.random.Generator | None = None,
           options: RenderOptions = RenderOptions()) -> Frame:
    """Render one frame of a scene.

    Parameters
    ----------
    scene : Scene
    seed : int or numpy.random.SeedSequence, optional
        Seed of the frame's random stream (recorded in the ground truth).
    rng : numpy.random.Generator, optional
        The random stream itself (used if given; ``seed`` is then only recorded).
    options : RenderOptions
    """
    from . import cosmic_rays as cr
    from .detector import Sensor
    from .psf import GaussianPSF
    from .radiometry import Radiometry
    from .raster import rasterize
    from .truth import frame_truth

    if rng is None:
        rng = np.random.default_rng(seed)
    cam = scene.camera
    shape = (cam.height, cam.width)
    rad = Radiometry.for_camera(cam)
    psf = GaussianPSF(cam.defocus_sigma_px)
    T = cam.exposure_s

    # --- point sources: stars + bodies not ray-traced
    stars = scene.stars
    star_e = np.asarray(rad.star_electrons_per_s(stars.v_mag, stars.teff_k), dtype=float) * T
    star_irr = np.asarray(rad.star_irradiance_w_m2(stars.v_mag, stars.teff_k), dtype=float)
    traced = [b for b in scene.bodies if b.resolved and options.resolved and _near_image(cam, b)]
    points = [b for b in scene.bodies if b not in traced and np.all(np.isfinite(b.xy)) and _near_image(cam, b)]
    body_e = {b.name: float(rad.body_electrons_per_s(b.name, b.v_mag)) * T if np.isfinite(b.v_mag) else 0.0
              for b in scene.bodies}
    body_irr = {b.name: float(rad.body_irradiance_w_m2(b.name, b.v_mag)) if np.isfinite(b.v_mag) else 0.0
                for b in scene.bodies}
    u_pts = np.concatenate([stars.u_icrs.reshape(-1, 3), np.array([b.u_icrs for b in points]).reshape(-1, 3)])
    e_pts = np.concatenate([star_e, np.array([body_e[b.name] for b in points])])
    irr_pts = np.concatenate([star_irr, np.array([body_irr[b.name] for b in points])])
    paths = source_paths(scene, u_pts, options)
    # unresolved bodies are drawn at their photocentre (far-field BRDF offset along the Sun's
    # projection), so the centroid is continuous across the resolved threshold
    from .brdf import photocentre_offset_xy

    body_photocentre = {}
    for j, b in enumerate(points):
        off = np.asarray(photocentre_offset_xy(cam, scene.R_cam_icrs, b), dtype=float)
        if np.all(np.isfinite(off)):
            paths[len(star_e) + j] += off
            body_photocentre[b.name] = np.asarray(b.xy, dtype=float) + off
    electrons = rasterize(shape, paths, e_pts, psf, flux_fraction_lost=options.flux_fraction_lost)
    irradiance = rasterize(shape, paths, irr_pts, psf, flux_fraction_lost=options.flux_fraction_lost)

    # --- resolved bodies (Mitsuba), blurred by the same PSF
    resolved_truth = {}
    for b in traced:
        from .mitsuba_backend import render_resolved_body

        img = render_resolved_body(scene, b, spp=options.mitsuba_spp, time_samples=options.mitsuba_time_samples)
        crop, pad = blur_crop(img.electrons, psf, options.flux_fraction_lost)
        _add_crop(electrons, crop, img.x0 - pad, img.y0 - pad)
        scale = body_irr[b.name] / body_e[b.name] if body_e[b.name] > 0 else 0.0
        _add_crop(irradiance, crop * scale, img.x0 - pad, img.y0 - pad)
        body_e[b.name] = float(img.electrons_total)
        resolved_truth[b.name] = img

    if options.background_e_per_px_s > 0:
        electrons += options.background_e_per_px_s * T

    # --- cosmic rays: charge added after shot noise and PRNU, before the full-well limit
    hits = cr.draw_cosmic_rays(shape, cam.cosmic_rays_per_frame, rng, mode=options.cosmic_ray_mode)
    cr_charge = cr.deposit(np.zeros(shape), hits)

    sensor = Sensor(cam.sensor, shape)
    if options.noise:
        dn = sensor.expose(electrons, T, rng, backend=options.backend, extra_charge_e=cr_charge)
    else:
        dn = sensor.expected_dn(electrons + cr_charge, T)
    signal = electrons + cr_charge
    truth = frame_truth(scene, star_electrons=star_e, body_electrons=body_e, resolved=resolved_truth,
                        hits=hits, seed=seed, options=options, body_photocentre=body_photocentre)
    return Frame(dn=dn, electrons=signal.astype(np.float32), irradiance_w_m2=irradiance.astype(np.float32), truth=truth)


def blur_crop(crop: np.ndarray, psf, flux_fraction_lost: float):
    """Convolve a pixel-binned crop with the PSF, padded so no flux is lost.

    The kernel is the PSF integrated over one pixel centred on each integer offset (separable),
    normalised to 1 so the crop's total is conserved. Returns (blurred crop, pad in px).
    """
    sigma = float(getattr(psf, "sigma_px", 0.0))
    if sigma <= 0.0:
        return crop, 0
    h = int(psf.half_size_px(flux_fraction_lost))
    k = np.asarray(psf.integrate_1d(np.arange(-h - 0.5, h + 1.0, 1.0)), dtype=float)
    k /= k.sum()
    padded = np.pad(np.asarray(crop, dtype=float), h)
    from scipy.ndimage import convolve1d

    out = convolve1d(convolve1d(padded, k, axis=0, mode="constant"), k, axis=1, mode="constant")
    return out, h


def _near_image(cam, body, margin_px: float = 50.0) -> bool:
    pts = np.array([body.xy, body.xy_start, body.xy_end], dtype=float)
    ok = np.all(np.isfinite(pts), axis=1)
    if not ok.any():
        return False
    margin = margin_px + 0.5 * body.angular_diameter_px
    return bool(cam.in_image(pts[ok], margin).any())


def _add_crop(image: np.ndarray, crop: np.ndarray, x0: int, y0: int) -> None:
    """Add a crop whose top-left pixel is (row y0, col x0), clipped to the image."""
    h, w = crop.shape
    H, W = image.shape
    ys, xs = max(0, y0), max(0, x0)
    ye, xe = min(H, y0 + h), min(W, x0 + w)
    if ye <= ys or xe <= xs:
        return
    image[ys:ye, xs:xe] += crop[ys - y0:ye - y0, xs - x0:xe - x0]

