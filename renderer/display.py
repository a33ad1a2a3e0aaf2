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


def spread_over_full_scale(electrons, facility, *, pad_px: int = 24, max_iterations: int = 3000):
    """Move the charge that a screen pixel cannot show (above its full scale) to its neighbours.

    The excess is convolved, again and again, with a normalised symmetric 3 x 3 kernel and added
    back until no pixel exceeds its limit. Convolution by such a kernel keeps the total and the first
    moment, so a source too bright for the screen keeps its electrons and its centroid (the camera,
    saturated there anyway, locates it by its wings) and only grows wider; plain clipping would
    cut its core unevenly across the pixels and shift it. The excess falls ~10x per 100 passes; it
    stops below 1e-9 of the window's charge. Returns (electrons, pixels over the limit).
    """
    from scipy import ndimage

    cam = facility.camera
    rm = facility.radiometric
    e_full = (rm.peak_w_m2 - rm.black_w_m2) * facility.electrons_per_s_per_w_m2() * cam.exposure_s
    # candidates against the flat field's lowest grid value (a spline may dip a little below it)
    f_min = 0.9 * min(min(r) for r in facility.flat_field.relative) if facility.flat_field is not None else 1.0
    over = electrons > e_full * f_min
    if not over.any():
        return electrons, 0
    out = np.array(electrons, dtype=float)
    H, W = out.shape
    k = np.array([[1.0, 2.0, 1.0], [2.0, 4.0, 2.0], [1.0, 2.0, 1.0]]) / 16.0
    n_over = 0
    lab, _ = ndimage.label(ndimage.binary_dilation(over, iterations=2))
    for sl in ndimage.find_objects(lab):
        r0, r1 = max(sl[0].start - pad_px, 0), min(sl[0].stop + pad_px, H)
        c0, c1 = max(sl[1].start - pad_px, 0), min(sl[1].stop + pad_px, W)
        yy, xx = np.mgrid[r0:r1, c0:c1].astype(float)
        lim = e_full * facility.flat(np.stack([xx, yy], -1))
        win = out[r0:r1, c0:c1]
        n_over += int((win > lim).sum())
        for _ in range(max_iterations):
            ex = np.maximum(win - lim, 0.0)
            if ex.sum() <= 1e-9 * max(win.sum(), 1.0):
                break
            win = win - ex + ndimage.convolve(ex, k, mode="constant")
        out[r0:r1, c0:c1] = win
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
    # charge beyond the screen's full scale goes to the neighbours (total and centroid kept)
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
