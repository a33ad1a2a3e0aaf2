"""Closed loop on the virtual bench: a Monte Carlo dataset exported for the bench, each screen
frame shown on the virtual screen and captured by the virtual camera, then measured exactly like
the dataset's own software frames.

Driver module. What goes in is only what a lab would have: the dataset folder (software frames,
ground truth), the export folder written by :func:`skynav.datasets.hil_export.export_dataset`
(``skynav hil export``) with the *calibrated* facility, and a bench that shows PNGs. The virtual
bench's true parameters are used only to make the captures (like the real hardware would).

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

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from skynav.scenes.facility import ARCSEC

from .errors import CalibrationInputError
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


def _select(truth: dict, cam, v_max: float, skipped: dict):
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


def _angle_arcsec(cam, xy, v_cam):
    u = cam.line_of_sight(np.where(np.isfinite(xy), xy, 0.0))
    v = v_cam / np.linalg.norm(v_cam, axis=-1, keepdims=True)
    a = np.arctan2(np.linalg.norm(np.cross(u, v), axis=-1), np.einsum("ij,ij->i", u, v)) / ARCSEC
    return np.where(np.all(np.isfinite(xy), axis=1), a, np.nan)


def closed_loop_dataset(bench, dataset_dir, export_dir, *, seed: int = 0, v_max: float = 6.0, frames=None,
                        progress=None) -> ClosedLoopResult:
    """Capture every exported screen frame of ``export_dir`` (written from ``dataset_dir`` with the
    calibrated facility) on ``bench`` (a :class:`~skynav.calibration.virtual_bench.VirtualBench`)
    and compare with the dataset's software frames (see the module docstring). Frame k's camera
    noise draws from ``SeedSequence([seed, k])``."""
    from skynav.datasets import open_dataset
    from skynav.datasets.frame_files import read_png
    from skynav.renderer.detector import Sensor
    from skynav.scenes.camera import Camera

    ds = open_dataset(dataset_dir)
    todo = range(len(ds)) if frames is None else range(min(int(frames), len(ds)))
    cols = {k: [] for k in ("frame", "kind", "name", "v_mag")}
    err = {"noisy": [], "noise_free": []}
    sw_err = {"noisy": [], "noise_free": []}
    pc_err = {"noisy": [], "noise_free": []}
    clipped = []
    dmag = {"noisy": [], "noise_free": []}
    skipped: dict = {}
    sensor = None
    for n_done, k in enumerate(todo):
        rec = ds[k]
        truth = rec.truth
        cam = Camera.from_dict(truth["camera"])
        if cam != bench.facility.camera:
            raise CalibrationInputError(f"{dataset_dir}: frame {k}'s camera differs from the bench's; export a dataset made with the facility's camera")
        src = _select(truth, cam, v_max, skipped)
        screen_png = Path(export_dir) / "frames" / f"{k:06d}.png"
        hil = json.loads((Path(export_dir) / "frames" / f"{k:06d}.json").read_text())
        if hil["source"]["frame"] != k:
            raise CalibrationInputError(f"{screen_png}: exported from frame {hil['source']['frame']}, not {k}")
        if not src:
            continue
        sp = cam.sensor
        if sensor is None:
            sensor = Sensor(sp, (cam.height, cam.width))
        cap_e = bench.expected_electrons(read_png(screen_png).astype(float))
        rng = np.random.default_rng(np.random.SeedSequence([seed, k]))
        cap_dn = sensor.expose(cap_e, cam.exposure_s, rng, backend="numpy")
        sw_e = np.asarray(rec.electrons, dtype=float)
        to_e = lambda dn: (dn.astype(float) - sp.offset_dn) / sp.gain_dn_per_e  # noqa: E731
        full = sp.full_well_e
        images = {"cap_noisy": (to_e(cap_dn), cap_dn >= sp.max_dn), "sw_noisy": (to_e(rec.dn), rec.dn >= sp.max_dn),
                  "cap_noise_free": (np.minimum(cap_e, full), cap_e >= full), "sw_noise_free": (np.minimum(sw_e, full), sw_e >= full)}
        xy = np.array([s[4] for s in src])
        v_cam = np.array([s[3] for s in src])
        meas = measure_pair(cam, images, xy)
        ref = meas["sw_noise_free"].xy_px
        ref_cam = cam.line_of_sight(np.where(np.isfinite(ref), ref, 0.0))
        ref_cam[~np.all(np.isfinite(ref), axis=1)] = np.nan
        maxdn = (1 << int(hil["facility"]["screen"]["bit_depth"])) - 1
        peaks = {s["hip"]: s["peak_dn"] for s in hil["stars"]} | {b["name"]: b["peak_dn"] for b in hil["bodies"]}
        clipped += [peaks.get(int(s[1]) if s[0] == "star" else s[1], 0) >= maxdn for s in src]
        for label in ("noisy", "noise_free"):
            c, s = meas[f"cap_{label}"], meas[f"sw_{label}"]
            err[label].append(_angle_arcsec(cam, c.xy_px, v_cam))
            pc_err[label].append(_angle_arcsec(cam, c.xy_px, ref_cam))
            sw_err[label].append(_angle_arcsec(cam, s.xy_px, v_cam))
            phot = c.ok & s.ok & ~c.saturated & ~s.saturated & (c.flux_e > 0) & (s.flux_e > 0)
            with np.errstate(invalid="ignore", divide="ignore"):
                dmag[label].append(np.where(phot, -2.5 * np.log10(c.flux_e / s.flux_e), np.nan))
        cols["frame"] += [k] * len(src)
        cols["kind"] += [s[0] for s in src]
        cols["name"] += [s[1] for s in src]
        cols["v_mag"] += [s[2] for s in src]
        if progress:
            progress(n_done + 1, len(todo))
    cat = lambda parts: np.concatenate(parts) if parts else np.zeros(0)  # noqa: E731
    rows = LoopRows(frame=np.array(cols["frame"], dtype=int), kind=np.array(cols["kind"], dtype=str),
                    name=np.array(cols["name"], dtype=str), v_mag=np.array(cols["v_mag"], dtype=float),
                    err_arcsec={k: cat(v) for k, v in err.items()}, sw_err_arcsec={k: cat(v) for k, v in sw_err.items()},
                    photocentre_err_arcsec={k: cat(v) for k, v in pc_err.items()}, dmag={k: cat(v) for k, v in dmag.items()},
                    screen_clipped=np.array(clipped, dtype=bool), skipped=skipped)
    return ClosedLoopResult(rows=rows, frames=len(todo), v_max=v_max)


def run_closed_loop(facility, calibrated, work_dir, *, scenario_name: str = "realistic", frames: int = 100,
                    dataset_seed: int = 20260101, seed: int = 0, v_max: float = 6.0, progress=False) -> ClosedLoopResult:
    """The whole loop in ``work_dir``: a ``montecarlo`` dataset of ``frames`` frames made with the
    facility's camera (as ``skynav dataset generate montecarlo --count N --seed S``), exported for
    the bench with the ``calibrated`` facility (as ``skynav hil export``), captured on the
    virtual bench ``scenario_name`` of the nominal ``facility`` and measured
    (:func:`closed_loop_dataset`). Both folders resume if already there."""
    from skynav.datasets import generate
    from skynav.datasets.hil_export import export_dataset
    from skynav.datasets.recipes import preset_recipe

    from .virtual_bench import VirtualBench, scenario

    work = Path(work_dir)
    recipe = preset_recipe("montecarlo")
    recipe.update(frames=int(frames), seed=int(dataset_seed), camera=facility.camera.to_dict())
    generate(recipe, work / "dataset", workers=1, progress=progress)
    export_dataset(calibrated, work / "dataset", work / "screen", workers=1)
    bench = VirtualBench(facility, scenario(scenario_name, facility))
    return closed_loop_dataset(bench, work / "dataset", work / "screen", seed=seed, v_max=v_max)
