"""Closed loop on the virtual bench: a Monte Carlo dataset exported for the bench, each screen
frame shown on the virtual screen and captured by the virtual camera, then measured exactly like
the dataset's own software frames.

Core module: the source selection, the paired measurement and the statistics. The loop over a
dataset and its bench export (reading the frames, capturing them on the virtual bench) is
:func:`skynav.calibration.bench_files.closed_loop_dataset`, the file side. What goes in is only what
a lab would have: the dataset folder (software frames, ground truth), the export folder written by
:func:`skynav.datasets.hil_export.export_dataset` (``skynav hil export``) with the *calibrated*
facility, and a bench that shows PNGs. The virtual bench's true parameters are used only to make
the captures (like the real hardware would).

For every frame and every selected source (stars brighter than ``v_max``, and the unresolved,
visible planets in the field), both images are measured by the same
:func:`~skynav.calibration.measure.measure_sources` (PSF-fit centroid, aperture photometry):

- **direction**: the capture's centroid through the camera model (its line of sight) against the
  source's true apparent direction from the ground truth (``u_icrs`` rotated by ``R_cam_icrs``);
  the software frame's own error is reported beside it (the measurement's floor);
- **photometry**: capture electrons against software-frame electrons for the same source, as a
  magnitude difference, for sources unsaturated in both.

Each comparison is made twice: ``noisy`` (one exposure of the camera, with the dataset's own noisy
software frame: what a lab measures) and ``noise_free`` (the capture's expected electrons against
the software frame's noise-free ``electrons`` channel: the bench's systematic error alone).

Sources left out, with the reason counted: too near the image edge for the measurement windows,
or blended (another catalogued star within 10 px and less than 4 mag fainter, a planet or moon
within 20 px whatever its brightness: next to a saturated planet even a faint moon sits in the
wings that locate it; or a cosmic-ray hit of the software frame within 6 px).

The truth decides the selection and the scoring; in the measurement, its pixel position only seeds
the window (on the brightest pixel within 2 px of it, as a predicted position from the attitude
and the catalogue would), and the fitted centre does not depend on it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from skynav.scenes.constants import ARCSEC_RAD

from .measure import measure_sources

#: blend rules (px, mag): see the module docstring
STAR_NEIGHBOUR_PX, STAR_NEIGHBOUR_DMAG = 10.0, 4.0
PLANET_NEIGHBOUR_PX = 20.0
COSMIC_RAY_PX = 6.0
EDGE_MARGIN_PX = 18.0


@dataclass(frozen=True, kw_only=True, eq=False)
class LoopRows:
    """One row per measured source of every frame (arrays of the same length)."""

    frame: np.ndarray
    kind: np.ndarray            # "star" / "planet"
    name: np.ndarray            # HIP number or planet name, as str
    v_mag: np.ndarray
    err_arcsec: dict            # {"noisy": (N,), "noise_free": (N,)}: capture vs truth
    sw_err_arcsec: dict         # software frame vs truth
    photocentre_err_arcsec: dict  # capture vs the noise-free software frame's centroid (the rendered photocentre)
    dmag: dict                  # capture - software, mag; NaN where saturated or not measured
    screen_clipped: np.ndarray  # the source's brightest screen pixel is at the screen's full scale
    skipped: dict = field(default_factory=dict)


def _err_stats(err, prefix=""):
    e = err[np.isfinite(err)]
    out = {}
    if len(err):
        # a source that could not be measured counts as outside 5 arcsec
        out[prefix + "within_5_arcsec"] = float(np.sum(e < 5.0) / len(err))
    if len(e):
        out.update({prefix + "rms_arcsec": float(np.sqrt(np.mean(e ** 2))), prefix + "p99_arcsec": float(np.percentile(e, 99)),
                    prefix + "max_arcsec": float(e.max())})
    return out


def _stats(err, dmag):
    d = dmag[np.isfinite(dmag)]
    out = {"n": int(len(err)), "measured": int(np.isfinite(err).sum())}
    out.update(_err_stats(err))
    out["n_photometry"] = int(len(d))
    if len(d):
        out.update(dmag_rms=float(np.sqrt(np.mean(d ** 2))), dmag_bias=float(np.mean(d)))
    return out


@dataclass(frozen=True, kw_only=True, eq=False)
class ClosedLoopResult:
    rows: LoopRows
    frames: int
    v_max: float

    def summary(self) -> dict:
        r = self.rows
        out = {"frames": self.frames, "v_max": self.v_max, "skipped": dict(r.skipped)}
        for label in ("noisy", "noise_free"):
            out[label] = {}
            for kind in ("star", "planet"):
                sel = r.kind == kind
                s = _stats(r.err_arcsec[label][sel], r.dmag[label][sel])
                s.update(_err_stats(r.photocentre_err_arcsec[label][sel], "vs_photocentre_"))
                s["screen_clipped"] = int(r.screen_clipped[sel].sum())
                sw = r.sw_err_arcsec[label][sel]
                sw = sw[np.isfinite(sw)]
                if len(sw):
                    s["software_rms_arcsec"] = float(np.sqrt(np.mean(sw ** 2)))
                out[label][kind] = s
        return out


def select_sources(truth: dict, cam, v_max: float, skipped: dict):
    """(kind, name, v_mag, v_cam (3,), xy) of the sources to score in one frame."""
    R = np.asarray(truth["attitude"]["R_cam_icrs"], dtype=float)
    stars = truth["stars"]
    s_xy = np.array([s["xy"] for s in stars], dtype=float).reshape(-1, 2)
    s_v = np.array([s["v_mag"] for s in stars], dtype=float)
    in_fov = [b for b in truth["bodies"] if b["in_fov"]]
    planets = [b for b in in_fov if b["visible"]]
    p_xy = np.array([b["xy"] for b in planets], dtype=float).reshape(-1, 2)
    b_xy = np.array([b["xy"] for b in in_fov], dtype=float).reshape(-1, 2)
    cr_xy = np.array([c["xy"] for c in truth.get("cosmic_rays", [])], dtype=float).reshape(-1, 2)
    out = []

    def crowded(xy, own=None, v=None):
        if own is not None and len(s_xy):
            d = np.hypot(*(s_xy - xy).T)
            d[own] = np.inf
            if np.any((d < STAR_NEIGHBOUR_PX) & (s_v < v + STAR_NEIGHBOUR_DMAG)):
                return True
        if len(b_xy) and np.any(np.hypot(*(b_xy - xy).T) < PLANET_NEIGHBOUR_PX) and own is not None:
            return True
        return bool(len(cr_xy) and np.any(np.hypot(*(cr_xy - xy).T) < COSMIC_RAY_PX))

    for k in np.flatnonzero(s_v < v_max):
        xy = s_xy[k]
        if not cam.in_image(xy[None], margin_px=-EDGE_MARGIN_PX)[0]:
            skipped["star_edge"] = skipped.get("star_edge", 0) + 1
        elif crowded(xy, own=k, v=s_v[k]):
            skipped["star_blended"] = skipped.get("star_blended", 0) + 1
        else:
            out.append(("star", str(stars[k]["hip"]), float(s_v[k]), R @ np.asarray(stars[k]["u_icrs"], float), xy))
    for b, xy in zip(planets, p_xy):
        d_p = np.hypot(*(b_xy - xy).T)
        d_p[d_p == 0.0] = np.inf  # itself
        if b["resolved"]:
            skipped["planet_resolved"] = skipped.get("planet_resolved", 0) + 1
        elif not cam.in_image(xy[None], margin_px=-EDGE_MARGIN_PX)[0]:
            skipped["planet_edge"] = skipped.get("planet_edge", 0) + 1
        elif (len(s_xy) and np.any((np.hypot(*(s_xy - xy).T) < STAR_NEIGHBOUR_PX) & (s_v < b["v_mag"] + STAR_NEIGHBOUR_DMAG))) \
                or np.any(d_p < PLANET_NEIGHBOUR_PX) or crowded(xy):
            skipped["planet_blended"] = skipped.get("planet_blended", 0) + 1
        else:
            out.append(("planet", b["name"], float(b["v_mag"]), R @ np.asarray(b["u_icrs"], float), xy))
    return out


def measure_pair(cam, images: dict, guess_xy):
    """Measure the same sources in several images of one camera. ``images``: {label: (image_e,
    saturated mask)}; returns {label: SourceMeasurements}."""
    s = cam.sensor
    noise = math.sqrt(s.read_noise_e ** 2 + s.reset_noise_e ** 2 + (1.0 / s.gain_dn_per_e) ** 2 / 12.0)
    return {k: measure_sources(img, guess_xy, saturated=sat, read_noise_e=noise) for k, (img, sat) in images.items()}


def angle_arcsec(cam, xy, v_cam):
    u = cam.line_of_sight(np.where(np.isfinite(xy), xy, 0.0))
    v = v_cam / np.linalg.norm(v_cam, axis=-1, keepdims=True)
    a = np.arctan2(np.linalg.norm(np.cross(u, v), axis=-1), np.einsum("ij,ij->i", u, v)) / ARCSEC_RAD
    return np.where(np.all(np.isfinite(xy), axis=1), a, np.nan)
