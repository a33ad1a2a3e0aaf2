"""The bench display model (hardware-in-the-loop mode): a scene rendered straight into screen
pixels, mapped to the screen digital counts that make the real camera collect the electrons the
rendered source would give it.

- Geometry at the line-of-sight level: :func:`~skynav.renderer.render.expected_image` draws
  through the facility's :class:`~skynav.scenes.facility.ScreenProjection` (``own_size``), so
  every point source (and its streak) lands at the screen position whose calibrated line of
  sight is its apparent direction, and resolved bodies are ray-traced by Mitsuba along the
  screen pixels' lines of sight. Nothing is resampled from a camera image.
- The camera's own defocus and noise are left to the real camera: the screen image uses a small
  screen-space PSF (``screen_psf_sigma_px``, default 0.5 screen px) only to encode sub-pixel
  positions.
- Radiometry: intended camera electrons per screen pixel -> electrons/s -> power-meter W/m^2
  (``Facility.electrons_per_s_per_w_m2``: screen spectrum, meter responsivity, camera QE) ->
  divided by the flat field at that pixel -> inverse radiometric curve (above the black level,
  which the camera sees as a uniform pedestal) -> rounded digital counts, clipped to the screen.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class ScreenFrame:
    """A screen frame: ``dn`` (H, W) uint8/uint16 at the screen's bit depth, and what went in."""

    dn: np.ndarray
    electrons: np.ndarray          # intended camera electrons per screen pixel
    stars_xy: np.ndarray           # (N, 2) screen xy of the stars (mid-exposure)
    stars_electrons: np.ndarray    # (N,)
    stars_peak_dn: np.ndarray      # (N,)
    bodies: list                   # dicts: name, xy, electrons, peak_dn
    clipped_bright_px: int
    clipped_faint_sources: int
    black_pedestal_e_per_camera_px: float


def dn_of_electrons(facility, electrons, xy_grid=None):
    """Real-valued screen DN giving ``electrons`` (per screen pixel over the exposure) in the camera."""
    cam = facility.camera
    rate = np.asarray(electrons, dtype=float) / cam.exposure_s
    w = rate / facility.electrons_per_s_per_w_m2()
    if xy_grid is not None:
        w = w / facility.flat(xy_grid)
    rm = facility.radiometric
    return rm.digital_count(rm.black_w_m2 + np.maximum(w, 0.0)), w > (rm.peak_w_m2 - rm.black_w_m2)


def _full_scale_e(facility) -> float:
    """Camera electrons (per screen pixel over the exposure) of a screen pixel at full scale, flat field 1."""
    rm = facility.radiometric
    return (rm.peak_w_m2 - rm.black_w_m2) * facility.electrons_per_s_per_w_m2() * facility.camera.exposure_s


def _diffuse_excess(win, lim, max_iterations):
    """Iterative fallback: the excess over ``lim`` convolved with a normalised symmetric 3 x 3 kernel
    and added back until no pixel exceeds its limit (keeps the total and the first moment)."""
    from scipy import ndimage

    k = np.array([[1.0, 2.0, 1.0], [2.0, 4.0, 2.0], [1.0, 2.0, 1.0]]) / 16.0
    for _ in range(max_iterations):
        ex = np.maximum(win - lim, 0.0)
        if ex.sum() <= 1e-9 * max(win.sum(), 1.0):
            break
        win = win - ex + ndimage.convolve(ex, k, mode="constant")
    return win


def _gaussian_kernel_1d(sigma_px: float) -> np.ndarray:
    r = int(np.ceil(4.0 * sigma_px))
    g = np.exp(-0.5 * (np.arange(-r, r + 1) / sigma_px) ** 2)
    return g / g.sum()


def _blur(a, sigma_px: float):
    """``a`` convolved with a normalised, sampled 2-D Gaussian (zero outside ``a``)."""
    from scipy import ndimage

    if sigma_px <= 0.0:
        return a
    g = _gaussian_kernel_1d(sigma_px)
    b = ndimage.convolve1d(a, g, axis=0, mode="constant")
    return ndimage.convolve1d(b, g, axis=1, mode="constant")


def spread_over_full_scale(electrons, facility, *, core_dilation_px: int = 4, max_sigma_px: float = 12.0,
                           max_iterations: int = 3000):
    """Draw a source that a screen pixel cannot show (above its full scale) wider, around the same centre.

    Each connected group of pixels over the limit, with everything within ``core_dilation_px`` of
    it (the source's whole light: the screen PSF of 0.5 px falls by e^-32 over 4 px), is convolved
    with a normalised, sampled circular Gaussian of the smallest width (bisection, to 0.1 %) that
    brings every pixel to its limit (full scale times the flat field there). A symmetric kernel
    keeps the source's electrons and its first moment exactly, and, applied to a source symmetric
    about its sub-pixel position, keeps it symmetric about that position: the spot only grows
    wider, as if defocused, and stays Gaussian. The camera, saturated there anyway, locates it by
    its wings. (Plain clipping cuts the core unevenly across the pixels and shifts it; spreading
    the excess charge to the neighbours keeps the centroid but leaves a plateau whose shape
    follows the pixel grid, not the source, which biases a fit of the unsaturated wings by up to
    7 arcsec on the bench preset.) A group that would need a Gaussian wider than ``max_sigma_px``
    (a resolved disc brighter than full scale over its area: blurring cannot lower a uniform
    level) falls back to spreading its excess to the neighbouring pixels, again and again with a
    normalised symmetric 3 x 3 kernel, which also keeps the total and the first moment.

    Parameters
    ----------
    electrons : ndarray, shape (H, W), e-
        Intended camera electrons per screen pixel.
    facility : Facility
        Gives the full scale (radiometric curve, exposure) and the flat field.
    core_dilation_px : int
        Pixels around a group over the limit that are spread with it.
    max_sigma_px : float
        Widest Gaussian, screen px; wider needs fall back to the iterative spreading.

    Returns
    -------
    (ndarray, shape (H, W), e-; int)
        The electrons, and the number of pixels that were over the limit.
    """
    from scipy import ndimage

    e_full = _full_scale_e(facility)
    # candidates against the flat field's lowest grid value (a spline may dip a little below it)
    f_min = 0.9 * min(min(r) for r in facility.flat_field.relative) if facility.flat_field is not None else 1.0
    over = electrons > e_full * f_min
    if not over.any():
        return electrons, 0
    out = np.array(electrons, dtype=float)
    H, W = out.shape
    n_over = 0
    pad = core_dilation_px + int(np.ceil(4.0 * max_sigma_px)) + 2
    lab, _ = ndimage.label(ndimage.binary_dilation(over, iterations=2))
    disc = np.hypot(*np.mgrid[-core_dilation_px:core_dilation_px + 1, -core_dilation_px:core_dilation_px + 1]) <= core_dilation_px
    for n, sl in enumerate(ndimage.find_objects(lab), start=1):
        r0, r1 = max(sl[0].start - pad, 0), min(sl[0].stop + pad, H)
        c0, c1 = max(sl[1].start - pad, 0), min(sl[1].stop + pad, W)
        yy, xx = np.mgrid[r0:r1, c0:c1].astype(float)
        lim = e_full * facility.flat(np.stack([xx, yy], -1))
        win = out[r0:r1, c0:c1]
        hot = (win > lim) & (lab[r0:r1, c0:c1] == n)
        if not hot.any():
            continue
        n_over += int(hot.sum())
        core = ndimage.binary_dilation(hot, structure=disc)
        src = np.where(core, win, 0.0)
        rest = win - src
        fits = lambda s: bool(np.all(rest + _blur(src, s) <= lim))  # noqa: E731
        if fits(max_sigma_px):
            lo, hi = 0.0, max_sigma_px
            while hi - lo > 1e-3 * hi:
                mid = 0.5 * (lo + hi)
                lo, hi = (lo, mid) if fits(mid) else (mid, hi)
            new = rest + _blur(src, hi)
        else:
            new = _diffuse_excess(win, lim, max_iterations)
        out[r0:r1, c0:c1] = new
    return out, n_over


def screen_frame(scene, facility, *, rng: np.random.Generator, options=None, screen_psf_sigma_px: float = 0.5) -> ScreenFrame:
    """Render ``scene`` for the bench ``facility``'s screen (see the module docstring)."""
    from .render import RenderOptions, expected_image

    options = options or RenderOptions()
    cam = scene.camera.replace(defocus_sigma_px=screen_psf_sigma_px)
    sc_scene = dataclasses.replace(scene, camera=cam)
    proj = facility.projection
    exp = expected_image(sc_scene, projection=proj, rng=rng, options=dataclasses.replace(options, background_e_per_px_s=0.0),
                         own_size=True)
    H, W = proj.height, proj.width
    # a source beyond the screen's full scale is drawn wider about its centre (total and centroid kept)
    electrons, n_over = spread_over_full_scale(exp.electrons, facility)
    # only lit pixels need the curve: the dark sky stays at DN 0 (the black level)
    rows, cols = np.nonzero(electrons > 0)
    dn_real, bright = dn_of_electrons(facility, electrons[rows, cols], np.stack([cols, rows], -1).astype(float))
    maxdn = facility.screen.max_dn
    dn = np.zeros((H, W), dtype=np.uint8 if facility.screen.bit_depth <= 8 else np.uint16)
    dn[rows, cols] = np.clip(np.round(dn_real), 0, maxdn)
    v = np.einsum("ij,nj->ni", scene.R_cam_icrs, np.asarray(scene.stars.u_icrs, dtype=float).reshape(-1, 3))
    sxy = proj.project(v)

    def peak(xy):
        if not np.all(np.isfinite(xy)):
            return 0
        i, j = int(np.clip(np.round(xy[1]), 0, H - 1)), int(np.clip(np.round(xy[0]), 0, W - 1))
        return int(dn[max(i - 1, 0):i + 2, max(j - 1, 0):j + 2].max())

    star_peak = np.array([peak(p) for p in sxy], dtype=int)
    bodies = []
    for b in scene.bodies:
        bxy = proj.project(scene.R_cam_icrs @ np.asarray(b.u_icrs, dtype=float))
        if proj.in_screen(bxy):
            bodies.append({"name": b.name, "xy": [float(bxy[0]), float(bxy[1])], "electrons": float(exp.body_electrons.get(b.name, 0.0)),
                           "peak_dn": peak(bxy), "resolved": b.name in exp.resolved})
    on = proj.in_screen(sxy) if len(sxy) else np.zeros(0, bool)
    faint = int(((star_peak == 0) & on & (exp.star_electrons > 0)).sum())
    rm = facility.radiometric
    scale = facility.geometric.focal_length_mm / (facility.screen.pixel_pitch_um * 1e-3) / scene.camera.focal_length_px
    pedestal = rm.black_w_m2 * facility.electrons_per_s_per_w_m2() * scene.camera.exposure_s * scale ** 2
    return ScreenFrame(dn=dn, electrons=exp.electrons, stars_xy=sxy, stars_electrons=np.asarray(exp.star_electrons, dtype=float),
                       stars_peak_dn=star_peak, bodies=bodies, clipped_bright_px=int(bright.sum()) + n_over, clipped_faint_sources=faint,
                       black_pedestal_e_per_camera_px=float(pedestal))
