"""Geometric calibration of a bench from pattern captures.

Reads only files: the facility (nominal model and camera), ``patterns.json`` and the captures.
Dots are detected (:mod:`.detect`) and identified (:mod:`.identify`) per capture; the physical
model of :class:`~skynav.scenes.screen.GeometricModel` is fitted by Levenberg-Marquardt
minimising the line-of-sight error (chord between unit vectors ~ angle, rad), then a smooth
residual field (least-squares bicubic spline) absorbs what the physical model misses. A random
20 % of the dots (by dot, over all phases) are held out of both fits and give the honest residuals
(p50/p99/max, arcsec). The flat captures, seen through the fitted model, give the flat field.
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass

import numpy as np
from scipy.interpolate import LSQBivariateSpline
from scipy.optimize import least_squares

from skynav.scenes.constants import ARCSEC_RAD
from skynav.scenes.facility import Facility, FlatField
from skynav.scenes.screen import GeometricModel, ResidualField

from .detect import detect_dots, relative_response
from .errors import CalibrationInputError, CaptureMismatchError, IdentificationError
from .identify import identify
from .patterns import Pattern

#: the largest held-out fraction (the fit needs the rest) and the fewest held-out dots (a p99)
MAX_HOLDOUT = 0.9
MIN_HELD_OUT = 10


@dataclass(frozen=True)
class Observations:
    screen_xy: np.ndarray   # (N, 2)
    camera_xy: np.ndarray   # (N, 2)
    dot_id: np.ndarray      # (N,) pattern * 1e6 + dot index
    per_pattern: dict       # file -> (n identified, n fiducials)


@dataclass(frozen=True)
class GeometricResult:
    facility: Facility
    holdout_arcsec: np.ndarray
    fit_arcsec: np.ndarray
    physical_only_holdout_arcsec: np.ndarray
    n_fit: int
    n_holdout: int
    seconds: float
    per_pattern: dict

    def summary(self) -> dict:
        h = self.holdout_arcsec
        return {"p50": float(np.percentile(h, 50)), "p99": float(np.percentile(h, 99)), "max": float(h.max()),
                "n_fit": self.n_fit, "n_holdout": self.n_holdout}


def observe(facility: Facility, pats: list[Pattern], images: dict) -> Observations:
    cam = facility.camera
    sc = facility.screen
    cam_per_screen = cam.focal_length_px / (facility.geometric.focal_length_mm / (sc.pixel_pitch_um * 1e-3))
    dark = next((images[p.file].astype(float) for p in pats if p.kind == "dark"), None)
    bg = float(np.median(dark)) if dark is not None else None
    # the flats' full relative response (PRNU, vignetting, screen non-uniformity): divided out
    # before detection, so a dot's image is the plain image of a disc
    gain = None
    if bg is not None:
        gain = relative_response([images[p.file] for p in pats if p.kind == "flat"], bg, max_dn=cam.sensor.max_dn)
    S, C, ids, per = [], [], [], {}
    for k, p in enumerate(pats):
        if p.kind != "dots":
            continue
        blobs = detect_dots(images[p.file], background=bg, gain=gain)
        m = identify(p.dots, p.fiducials, blobs, step_screen_px=p.grid_step_px, cam_per_screen_px=cam_per_screen,
                     image_size=(cam.width, cam.height), name=p.file)
        S.append(p.dots[m.dot_index])
        C.append(m.xy_px)
        ids.append(k * 1_000_000 + m.dot_index)
        per[p.file] = (len(m.dot_index), m.fiducials_found, len(blobs.xy_px))
    if not S:
        raise CaptureMismatchError("no dot patterns in the pattern set")
    return Observations(np.concatenate(S), np.concatenate(C), np.concatenate(ids), per)


def _initial(facility: Facility, s, v):
    """Initial physical parameters from a linear fit screen px -> camera tangent plane."""
    sc = facility.screen
    t = v[:, :2] / v[:, 2:]
    c = np.array([(sc.width_px - 1) / 2, (sc.height_px - 1) / 2])
    A = np.c_[s - c, np.ones(len(s))]
    coef, *_ = np.linalg.lstsq(A, t, rcond=None)
    L = coef[:2].T  # dt/ds
    t0 = coef[2]
    p_mm = sc.pixel_pitch_um * 1e-3
    scale = math.sqrt(abs(np.linalg.det(L)))
    f = p_mm / scale
    roll = math.atan2(L[1, 0] - L[0, 1], L[0, 0] + L[1, 1])
    g = facility.geometric
    return GeometricModel(focal_length_mm=f, decentre_x_mm=t0[0] * f, decentre_y_mm=t0[1] * f, roll_rad=roll,
                          k1=g.k1, k2=g.k2, p1=g.p1, p2=g.p2)


# parameters fitted (misalignment about z is the screen roll; about x/y it trades with the decentre,
# kept fixed at 0)
_FREE = np.array([True, True, True, True, True, True, True, True, True, True, False, False, False])


def _fit_physical(facility: Facility, s, v, g0: GeometricModel) -> GeometricModel:
    sc = facility.screen
    p0 = g0.vector()

    def resid(q):
        p = p0.copy()
        p[_FREE] = q
        m = GeometricModel.from_vector(p)
        t = m.tangent(sc, s, residual=False)
        u = np.concatenate([t, np.ones((len(t), 1))], -1)
        u /= np.linalg.norm(u, axis=-1, keepdims=True)
        return (u - v).ravel()

    scale = np.array([1.0, 0.01, 0.01, 0.01, 0.01, 0.01, 0.01, 0.01, 1e-3, 1e-3])
    r = least_squares(resid, p0[_FREE], x_scale=scale, method="lm", xtol=1e-14, ftol=1e-14, max_nfev=2000)
    p = p0.copy()
    p[_FREE] = r.x
    return GeometricModel.from_vector(p)


def _residual_field(sc, s, dt, n_nodes: int = 41, n_knots: int = 10) -> ResidualField:
    """Least-squares bicubic spline of tangent-plane residuals over the screen, sampled on a grid."""
    x0, x1 = s[:, 0].min(), s[:, 0].max()
    y0, y1 = s[:, 1].min(), s[:, 1].max()
    tx = np.linspace(x0, x1, n_knots + 2)[1:-1]
    ty = np.linspace(y0, y1, n_knots + 2)[1:-1]
    # the grid spans the data only (the field is clamped beyond it): a grid over the whole screen
    # would carry the clamped edge back into the data region through the bicubic interpolation
    gx = np.linspace(x0, x1, n_nodes)
    gy = np.linspace(y0, y1, n_nodes)
    GX, GY = np.meshgrid(gx, gy)
    out = []
    for c in range(2):
        spl = LSQBivariateSpline(s[:, 0], s[:, 1], dt[:, c], tx, ty, bbox=[x0, x1, y0, y1], kx=3, ky=3)
        out.append(spl.ev(GX.ravel(), GY.ravel()).reshape(GX.shape))
    return ResidualField(x_px=gx, y_px=gy, dx_rad=out[0], dy_rad=out[1])


def _angles_arcsec(model, sc, s, v):
    t = model.tangent(sc, s)
    u = np.concatenate([t, np.ones((len(t), 1))], -1)
    u /= np.linalg.norm(u, axis=-1, keepdims=True)
    return np.linalg.norm(np.cross(u, v), axis=-1) / ARCSEC_RAD


def _flat_field(facility: Facility, pats, images, n_nodes: int = 17, block: int = 8) -> FlatField | None:
    flats = [p for p in pats if p.kind == "flat"]
    dark = next((images[p.file].astype(float) for p in pats if p.kind == "dark"), None)
    if not flats:
        return None
    cam = facility.camera
    sc = facility.screen
    bg = dark if dark is not None else cam.sensor.offset_dn
    # relative signal per unit screen level, per camera pixel
    sig = np.mean([(images[p.file].astype(float) - bg) / max(p.level_dn, 1) ** 1.0 for p in flats[-1:]], axis=0)
    H, W = cam.height, cam.width
    b = block
    h2, w2 = H // b, W // b
    m = sig[:h2 * b, :w2 * b].reshape(h2, b, w2, b).mean(axis=(1, 3))
    yy, xx = np.mgrid[0:h2, 0:w2].astype(float) * b + (b - 1) / 2
    cxy = np.stack([xx, yy], -1).reshape(-1, 2)
    proj = facility.projection
    s = proj.project(cam.line_of_sight(cxy))
    # divide out the solid angle (screen px per camera px) so only transmission remains
    ds = 0.5
    sx = proj.project(cam.line_of_sight(cxy + [ds, 0])) - s
    sy = proj.project(cam.line_of_sight(cxy + [0, ds])) - s
    area = np.abs(sx[:, 0] * sy[:, 1] - sx[:, 1] * sy[:, 0]) / ds ** 2
    val = m.ravel() / area
    ok = np.isfinite(val) & (val > 0)
    s, val = s[ok], val[ok]
    x0, x1, y0, y1 = s[:, 0].min(), s[:, 0].max(), s[:, 1].min(), s[:, 1].max()
    spl = LSQBivariateSpline(s[:, 0], s[:, 1], val, np.linspace(x0, x1, 7)[1:-1], np.linspace(y0, y1, 7)[1:-1],
                             bbox=[x0, x1, y0, y1], kx=3, ky=3)
    gx = np.linspace(-0.5, sc.width_px - 0.5, n_nodes)
    gy = np.linspace(-0.5, sc.height_px - 0.5, n_nodes)
    GX, GY = np.meshgrid(np.clip(gx, x0, x1), np.clip(gy, y0, y1))
    grid = spl.ev(GX.ravel(), GY.ravel()).reshape(GX.shape)
    c = float(spl.ev((sc.width_px - 1) / 2, (sc.height_px - 1) / 2))
    return FlatField(x_px=gx, y_px=gy, relative=np.maximum(grid / c, 1e-3))


def fit_geometric(facility: Facility, pats, images: dict, *, holdout: float = 0.2, seed: int = 0,
                  t0: float | None = None, source: tuple = ("", "")) -> GeometricResult:
    """The geometric (and flat-field) fit from the patterns and their captures (``{file: image}``,
    as :func:`skynav.calibration.bench_files.read_captures` returns them); ``t0``: when the work
    began (``time.perf_counter()``) for the result's ``seconds``; ``source``: the patterns' and
    the captures' folders, for the facility's provenance record."""
    t0 = time.perf_counter() if t0 is None else t0
    if not (isinstance(holdout, (int, float)) and 0 < holdout <= MAX_HOLDOUT):
        raise CalibrationInputError(f"holdout = {holdout!r}: expected a fraction in (0, {MAX_HOLDOUT:g}] of the dots held "
                                    "out of the fit to measure its error")
    obs = observe(facility, pats, images)
    cam, sc = facility.camera, facility.screen
    v = cam.line_of_sight(obs.camera_xy)
    # hold out by dot position on the screen (the same dot in every phase is a different point)
    rng = np.random.default_rng(seed)
    test = rng.random(len(v)) < holdout
    fit = ~test
    if fit.sum() < 50:
        raise IdentificationError(f"{len(v)} dots identified over all captures, {int(fit.sum())} of them left for the fit "
                                  f"after holding out {holdout:g}; need >= 50 for a fit (hold out less, or use more patterns)")
    if test.sum() < MIN_HELD_OUT:
        raise IdentificationError(f"{int(test.sum())} of {len(v)} dots held out (holdout {holdout:g}); need >= {MIN_HELD_OUT} "
                                  "to measure the fit's error (hold out more)")
    g0 = _initial(facility, obs.screen_xy[fit], v[fit])
    g = _fit_physical(facility, obs.screen_xy[fit], v[fit], g0)
    # robust pass: drop gross outliers (> 10x the median error and > 2 arcsec, e.g. a dot cut by an
    # obstruction or merged with a cosmic ray) from the fit and from the held-out set (counted)
    e = _angles_arcsec(g, sc, obs.screen_xy, v)
    good = e < max(10 * np.median(e[fit]), 2.0)
    fit &= good
    n_test_outliers = int((test & ~good).sum())
    test &= good  # the same rule for held-out dots (a dot cut by a cosmic ray or an obstruction)
    g = _fit_physical(facility, obs.screen_xy[fit], v[fit], g)
    phys_holdout = _angles_arcsec(g, sc, obs.screen_xy[test], v[test])
    t = g.tangent(sc, obs.screen_xy[fit], residual=False)
    tm = v[fit, :2] / v[fit, 2:]
    g = dataclasses.replace(g, residual=_residual_field(sc, obs.screen_xy[fit], tm - t))
    hold = _angles_arcsec(g, sc, obs.screen_xy[test], v[test])
    fit_e = _angles_arcsec(g, sc, obs.screen_xy[fit], v[fit])
    new = facility.replace(geometric=g)
    new = new.replace(flat_field=_flat_field(new, pats, images))
    res = GeometricResult(facility=new, holdout_arcsec=hold, fit_arcsec=fit_e, physical_only_holdout_arcsec=phys_holdout,
                          n_fit=int(fit.sum()), n_holdout=int(test.sum()), seconds=time.perf_counter() - t0, per_pattern=obs.per_pattern)
    s = res.summary()
    report = {
        "fit": {"holdout_arcsec": {k: round(s[k], 4) for k in ("p50", "p99", "max")},
                "fit_arcsec": {"p50": round(float(np.percentile(fit_e, 50)), 4), "p99": round(float(np.percentile(fit_e, 99)), 4),
                               "max": round(float(fit_e.max()), 4)},
                "physical_model_only_holdout_arcsec": {"p50": round(float(np.percentile(phys_holdout, 50)), 4),
                                                       "p99": round(float(np.percentile(phys_holdout, 99)), 4)},
                "n_fit": s["n_fit"], "n_holdout": s["n_holdout"], "excluded_outliers": int((~good).sum()),
                "excluded_holdout_outliers": n_test_outliers},
        "provenance": {"patterns": str(source[0]), "captures": str(source[1]), "captures_used": len(obs.per_pattern),
                       "date_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()), "holdout_fraction": holdout, "seed": seed},
    }
    return dataclasses.replace(res, facility=new.replace(calibrated_geometric=report))
