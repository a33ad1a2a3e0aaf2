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
    # only lit pixels need the curve: the dark sky stays at DN 0 (the black level)
    rows, cols = np.nonzero(exp.electrons > 0)
    dn_real, bright = dn_of_electrons(facility, exp.electrons[rows, cols], np.stack([cols, rows], -1).astype(float))
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
                       stars_peak_dn=star_peak, bodies=bodies, clipped_bright_px=int(bright.sum()), clipped_faint_sources=faint,
                       black_pedestal_e_per_camera_px=float(pedestal))
