"""The stars of a batch of frames drawn by Dr.Jit: the Gaussian PSF's pixel-integrated stamps
along each star's streak, added into the batch's sensor input on the device.

What it computes: the stars of :func:`~skynav.renderer.expected.expected_image` for a camera
whose PSF is a :class:`~skynav.renderer.kernels.GaussianKernel` (sigma > 0) and not
polychromatic (the default camera's). The host cuts each star's path into the sub-samples of
:func:`~skynav.renderer.raster.streak_subsamples` (one point for a static star; two
Gauss-Legendre nodes per panel of ``psf.quadrature_step_px()`` along a streak), as
:func:`~skynav.renderer.raster.rasterize` does. Then one kernel runs over every (frame,
sub-sample, stamp pixel) lane: its weight is the pixel-integrated Gaussian, the product of two
erf differences (as :meth:`GaussianKernel.stamps`), in float64, times the sub-sample's
electrons, rounded to float32 and scatter-added into the (N * H * W) float32 sensor input
(the pixels off the image dropped, as the reference drops them). No per-frame image of the
stars is made on the host.

What stays per frame, in numpy (:func:`frame_optics`): every other PSF model (airy, optical,
tabulated, polychromatic: their stamps are tables, :mod:`~skynav.renderer.table_kernels`), the
bodies drawn as points, the ray-traced bodies (Mitsuba) and their blur, composited into the same
input; and the stars' truth (electrons, centre of light: the first moments of the same stamps,
from the separable 1-D erf differences on the host).

The result differs from the numpy reference by roundings: the float32 sums of the stamps (the
reference sums in float64 and rounds once), the erf differences written without the reference's
``0.5 (1 + erf)`` form (tested to 1e-5 relative per pixel, tests/renderer/test_batch_splat.py).
One Python body is traced for Dr.Jit's LLVM and CUDA backends.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from skynav.scenes.psf import GaussianPSFModel

from .expected import expected_image, source_paths
from .kernels import GaussianKernel, stamp_origin
from .optics import is_polychromatic, kernel_for
from .radiometry import Radiometry
from .raster import _touching, streak_subsamples
from .sensor_jit import _module_of

__all__ = ["StarPoints", "gaussian_stars", "star_points", "splat_stars", "frame_optics"]


@dataclasses.dataclass(frozen=True, kw_only=True, eq=False)
class StarPoints:
    """A frame's stars cut into the sub-samples the splat draws.

    Attributes
    ----------
    xy : ndarray, shape (M, 2), px
    flux_e : ndarray, shape (M,), e-
    sigma_px : float
        The Gaussian PSF's standard deviation, px.
    half : int
        The stamps' half size, px.
    """

    xy: np.ndarray
    flux_e: np.ndarray
    sigma_px: float
    half: int


def gaussian_stars(scene, options) -> GaussianKernel | None:
    """The camera's PSF if its stars can be drawn by :func:`splat_stars` (a Gaussian of sigma >
    0, not polychromatic), else None."""
    cam = scene.camera
    if not isinstance(cam.psf, GaussianPSFModel) or is_polychromatic(cam):  # before a table kernel is built
        return None
    psf = kernel_for(cam, None, options.flux_fraction_lost)
    return psf if isinstance(psf, GaussianKernel) and psf.sigma_px > 0.0 else None


def star_points(scene, options, psf: GaussianKernel):
    """A frame's stars as :class:`StarPoints`, with their electrons (N,) and centres of light
    (N, 2, px; NaN where not drawn), as :func:`~skynav.renderer.expected.expected_image`
    records them."""
    cam = scene.camera
    stars = scene.stars
    star_e = np.asarray(Radiometry.for_camera(cam).star_electrons_per_s(stars.v_mag, stars.teff_k), dtype=float)
    star_e = star_e * cam.exposure_s
    half = int(psf.half_size_px(options.flux_fraction_lost))
    centre = np.full((len(star_e), 2), np.nan)
    shape = (cam.height, cam.width)
    empty = StarPoints(xy=np.zeros((0, 2)), flux_e=np.zeros(0), sigma_px=psf.sigma_px, half=half)
    if len(star_e) == 0:
        return empty, star_e, centre
    paths = source_paths(scene, stars.u_icrs.reshape(-1, 3), options)
    ok = _touching(paths, star_e, half, shape)
    if not np.any(ok):
        return empty, star_e, centre
    xy, flux, source = streak_subsamples(paths[ok], star_e[ok], float(psf.quadrature_step_px()))
    centre[np.flatnonzero(ok)] = _centres_of_light(psf, xy, flux, source, int(np.count_nonzero(ok)), half)
    return StarPoints(xy=xy, flux_e=flux, sigma_px=psf.sigma_px, half=half), star_e, centre


def _centres_of_light(psf, xy, flux, source, n_sources, half):
    """First moments of the points' stamps per source over their zeroth (as the rasteriser's
    ``centre_of_light``), from the separable 1-D weights of each stamp's columns and rows."""
    origin = stamp_origin(xy, half)
    k = np.arange(2 * half + 2, dtype=float) - 0.5
    wx = psf.integrate_1d(origin[:, 0:1] + k[None, :] - xy[:, 0:1])
    wy = psf.integrate_1d(origin[:, 1:2] + k[None, :] - xy[:, 1:2])
    sx, sy = wx.sum(axis=1), wy.sum(axis=1)
    kk = np.arange(2 * half + 1, dtype=float)
    sw = flux * sx * sy
    m0 = np.bincount(source, weights=sw, minlength=n_sources)
    m1x = np.bincount(source, weights=flux * sy * (wx @ kk) + origin[:, 0] * sw, minlength=n_sources)
    m1y = np.bincount(source, weights=flux * sx * (wy @ kk) + origin[:, 1] * sw, minlength=n_sources)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.stack([m1x / m0, m1y / m0], axis=1)


def frame_optics(scene, rng, options, psf, support):
    """A frame's optics with its stars left to :func:`splat_stars`: the rest of its expected
    image (bodies, no background) into ``support`` and the returned image, as
    :func:`~skynav.renderer.expected.expected_image` makes it (same ``rng`` draws); returns
    ``(expected image for the truth, star points)``, the image's stars' electrons and centres
    of light filled in."""
    stars = scene.stars
    no_stars = dataclasses.replace(stars, **{f.name: getattr(stars, f.name)[:0] for f in dataclasses.fields(stars)})
    rest = expected_image(dataclasses.replace(scene, stars=no_stars), rng=rng,
                          options=dataclasses.replace(options, background_e_per_px_s=0.0),
                          with_irradiance=False, support=support)
    points, star_e, centre = star_points(scene, options, psf)
    return dataclasses.replace(rest, star_electrons=star_e, star_centre_of_light=centre), points


def splat_stars(sig, points, shape, background_e: float = 0.0):
    """Add the stars' stamps of each frame (``points``, one :class:`StarPoints` per frame, one
    sigma and half size) and ``background_e`` per pixel into the batch's sensor input ``sig``
    (a Dr.Jit Float of N * H * W, frame-major); returns the new input (lazy)."""
    # Dr.Jit only for the JIT backends: import skynav.renderer loads neither Dr.Jit nor Mitsuba
    import drjit as dr

    jt = _module_of(sig)
    if background_e:
        sig = sig + jt.Float(background_e)
    pts = [p for p in points if p.flux_e.size]
    if not pts:
        return sig
    h_img, w_img = shape
    half, sigma = pts[0].half, pts[0].sigma_px
    n_side = 2 * half + 1
    per_point = n_side * n_side
    frames = np.concatenate([np.full(p.flux_e.size, i, np.uint32) for i, p in enumerate(points) if p.flux_e.size])
    xy = np.concatenate([p.xy for p in pts])
    flux = np.concatenate([p.flux_e for p in pts])
    if flux.size == 1:  # a one-element source would be a constant of the kernel: draw it twice, each half
        xy, flux, frames = np.repeat(xy, 2, axis=0), np.repeat(0.5 * flux, 2), np.repeat(frames, 2)
    origin = stamp_origin(xy, half)
    lane = dr.arange(jt.UInt32, flux.size * per_point)
    point, cell = lane // per_point, lane % per_point
    row = dr.gather(jt.Int32, jt.Int32(origin[:, 1].astype(np.int32)), point) + jt.Int32(cell // n_side)
    col = dr.gather(jt.Int32, jt.Int32(origin[:, 0].astype(np.int32)), point) + jt.Int32(cell % n_side)
    scale = 1.0 / (math.sqrt(2.0) * sigma)
    x = dr.gather(jt.Float64, jt.Float64(xy[:, 0].copy()), point)
    y = dr.gather(jt.Float64, jt.Float64(xy[:, 1].copy()), point)
    dx = (jt.Float64(col) - 0.5 - x) * scale
    dy = (jt.Float64(row) - 0.5 - y) * scale
    wx = dr.erf(dx + scale) - dr.erf(dx)
    wy = dr.erf(dy + scale) - dr.erf(dy)
    e = dr.gather(jt.Float64, jt.Float64(flux.copy()), point) * (0.25 * wx * wy)
    inside = (row >= 0) & (row < h_img) & (col >= 0) & (col < w_img)
    frame = dr.gather(jt.UInt32, jt.UInt32(frames), point)
    index = frame * (h_img * w_img) + jt.UInt32(row) * w_img + jt.UInt32(col)
    sig = jt.Float(sig)
    dr.scatter_add(sig, jt.Float(e), index, inside)
    return sig
