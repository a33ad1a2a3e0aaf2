"""Measurement-noise calibration of the navigation campaign: the planet-centroid error, measured.

Scoring module. ``R = sigma_px^2 I`` is measured, not guessed (Andreis et al. (2024), Sec. 5.1 did the same
with its image-processing Monte Carlo): the image processing runs on calibration frames with a
predicted state drawn about the truth, and the target's centroid minus the measurement model at
the true state gives the errors; per class of measurement (target and photocentre law) with at
least :data:`MIN_CLASS_FRAMES` frames, the class's mean square per axis and the part of it
constant over a track (:func:`track_bias_sigma`); otherwise ``sigma0^2 + (kappa D)^2`` with ``D``
the planet's apparent diameter in px, by non-negative least squares; both with iterated 99.7 %
clipping (the chi-square 2-dof point 11.6).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from scipy.optimize import nnls

import skynav.datasets as sdat
from skynav.scenes.ephemeris_jpl import BODY_RADII_KM, default_ephemeris

from .catalog import OnboardCatalog
from .measurement import CASES, planet_pixel, spot_saturated
from .process import process_frame
from .results import PredictedState
from .scoring_nav_plan import NavInputError, observation

__all__ = ["CentroidNoise", "MIN_CLASS_FRAMES", "BLEND_PX", "calibrate_sigma_px", "centroid_errors", "centroid_usable",
           "diameter_px", "target_beacon", "track_bias_sigma"]


@dataclass(frozen=True, kw_only=True)
class CentroidNoise:
    """Measurement noise per axis. Per class of measurement (``"<target>/<photocentre law>"``, e.g.
    ``"earth/saturated"``, ``"mars/lambert"``) with enough calibration frames: the class's measured
    sigma (the planets' centroids differ: Venus's 0.04 px against the Earth's 0.11 px, both
    saturated points); else ``sigma^2 = sigma0_px^2 + (kappa D)^2`` with ``D`` the planet's
    predicted apparent diameter in px, fitted on all calibration frames by non-negative least squares."""

    sigma0_px: float
    kappa: float = 0.0
    mean_px: tuple = (0.0, 0.0)
    frames: int = 0
    clipped: int = 0
    classes: tuple = ()     # ((key, sigma_px, frames, track_bias_sigma_px), ...)
    track_bias_in_r: bool = True
    renderings: int = 1     # renderings of the cruise the frames were pooled from

    def sigma_px(self, diameter_px: float, key: str | None = None, track_frames: int = 1) -> float:
        """Per-frame sigma: the class's measured RMS per axis (its track-constant part included
        once). With ``track_bias_in_r`` (the default) a class whose error has a part constant over a
        track (sigma_b) gets ``sigma^2 + n sigma_b^2`` for a track of ``n`` frames, so that the
        filter, which takes the frames as independent, gives the track's MEAN at least the variance
        ``sigma^2 / n + sigma_b^2``. Measured over independent renderings held out of the
        calibration (docs/navigation.md): with it and R pooled from six renderings, mean NEES 6.66
        over 27 runs on 21 renderings; without it (R from one rendering) the filter was optimistic
        on held-out renderings (NEES 10.3 on ten of them)."""
        for k, sig, _, sig_b in self.classes:
            if k == key:
                n = max(1, int(track_frames)) if self.track_bias_in_r else 0
                return math.sqrt(sig**2 + n * sig_b**2)
        return math.sqrt(self.sigma0_px**2 + (self.kappa * diameter_px) ** 2)

    def describe(self) -> str:
        if not self.frames:
            return f"{self.sigma0_px:g} px (given)"
        per = "; ".join(f"{k} {sig:.3f} px, track bias {sb:.3f} px ({n})" for k, sig, n, sb in self.classes)
        return (f"sigma = sqrt({self.sigma0_px:.3f}^2 + ({self.kappa:.3f} D)^2) px, measured on {self.frames} frames"
                + (f" of {self.renderings} renderings" if self.renderings > 1 else "")
                + f" ({self.clipped} clipped as outliers; mean error {np.round(self.mean_px, 3).tolist()} px)"
                + (f"; per class: {per}" if per else "")
                + ("; track biases added to R (n sigma_b^2)" if self.track_bias_in_r and per else ""))


#: A class of measurements needs this many calibration frames for its own sigma (18 degrees of
#: freedom per 9 frames: the sigma is then known to ~ +-17 %, 1 sigma).
MIN_CLASS_FRAMES = 9


def diameter_px(radius_km: float, distance_km: float, camera) -> float:
    """Apparent diameter of a body, px."""
    return 2.0 * math.asin(min(1.0, radius_km / distance_km)) / camera.ifov_rad


#: A class of measurements needs this many calibration frames for its own sigma (18 degrees of
#: freedom per 9 frames: the sigma is then known to ~ +-17 %, 1 sigma).
MIN_CLASS_FRAMES = 9


def calibrate_sigma_px(plan, *, stride: int = 1, seed: int = 0, sigma_position_km: float = 1e4,
                       sigma_velocity_km_s: float = 0.1, phase_offset: bool = True, observations=None):
    """Measured planet-centroid error, a :class:`CentroidNoise` (module docstring).

    The error is the image processing's target centroid minus the measurement model (case 1,
    with the Lambert photocentre offset if ``phase_offset``) evaluated at the TRUE state with the
    image processing's attitude: what the filter's R must describe.

    ``plan`` may be a list of renderings of the same cruise (``bench nav --calibrate-on``): their
    frames are pooled, each rendering's tracks kept apart, so that the track-constant part
    sigma_b is the ensemble's (over sensor and noise realisations) rather than one rendering's
    draw of it (0 to 0.07 px for the Earth's saturated disc over four renderings).

    ``observations``: where the frames come from when they are not a dataset's files (the closed
    loop asks the render service for them): a callable ``(rendering, i) -> Observation`` for frame
    ``i`` of ``plan[rendering]``; default: frame ``i`` of the dataset at ``plan.root``.
    """
    eph = default_ephemeris()
    plans = list(plan) if isinstance(plan, (list, tuple)) else [plan]
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0xCA1]))
    cat = None
    errs = []
    diam = []
    keys = []
    tracks = []
    for ip, plan in enumerate(plans):
        if observations is None:
            ds = sdat.open(plan.root)

            def get(i, ds=ds, plan=plan):
                return observation(ds, plan, i)
        else:
            def get(i, ip=ip):
                return observations(ip, i)
        cat = _calibrate_rendering(plan, get, ip, stride=stride, rng=rng, cat=cat, eph=eph, out=(errs, diam, keys, tracks),
                                   sigma_position_km=sigma_position_km, sigma_velocity_km_s=sigma_velocity_km_s,
                                   phase_offset=phase_offset)
    return replace(_fit_noise(plans[0], errs, diam, keys, tracks), renderings=len(plans))


def centroid_errors(plan, *, seed: int = 0, sigma_position_km: float = 1e4, sigma_velocity_km_s: float = 0.1,
                    phase_offset: bool = True) -> tuple[np.ndarray, tuple]:
    """Frame by frame, the centroid error :func:`calibrate_sigma_px` measures on ``plan``'s frames
    (its predicted states drawn from ``seed`` as it draws them, so that two plans of one cruise
    with different images see the same ones): ``(errors (F, 2) px, NaN where the target's centroid
    is not used; class keys (F,), "" there)``. For comparing two renderings frame by frame."""
    eph = default_ephemeris()
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0xCA1]))
    ds = sdat.open(plan.root)
    out = ([], [], [], [], [])
    _calibrate_rendering(plan, lambda i: observation(ds, plan, i), 0, stride=1, rng=rng, cat=None, eph=eph, out=out,
                         sigma_position_km=sigma_position_km, sigma_velocity_km_s=sigma_velocity_km_s,
                         phase_offset=phase_offset)
    errs, _, keys, _, idx = out
    e = np.full((plan.frames, 2), np.nan)
    k = [""] * plan.frames
    for j, i in enumerate(idx):
        e[i], k[i] = errs[j], keys[j]
    return e, tuple(k)


def _calibrate_rendering(plan, get, ip, *, stride, rng, cat, eph, out, sigma_position_km, sigma_velocity_km_s, phase_offset):
    errs, diam, keys, tracks = out[:4]
    prev = None
    for i in range(0, plan.frames, max(1, stride)):
        if not np.all(np.isfinite(plan.target_xy_px[i])):
            continue
        obs = get(i)
        if cat is None:
            cat = OnboardCatalog.load(camera=obs.camera)
        ps = PredictedState(position_km=plan.position_km[i] + sigma_position_km * rng.standard_normal(3),
                            velocity_km_s=plan.velocity_km_s[i] + sigma_velocity_km_s * rng.standard_normal(3),
                            position_cov_km2=np.eye(3) * sigma_position_km**2)
        fr = process_frame(obs, catalog=cat, predicted_state=ps, previous_attitude=prev)
        prev = fr.attitude.R_cam_icrs
        b = target_beacon(fr, plan.target[i])
        # the filter's view (estimate drawn about the truth) decides blends and the photocentre law
        use = None if b is None else centroid_usable(obs, fr, b, plan.target[i], t=plan.t_tdb_s[i],
                                                     position_km=ps.position_km, ephemeris=eph)
        if use is not None:
            t = plan.t_tdb_s[i]
            rp, vp = eph.position_velocity(plan.target[i], t)
            m = planet_pixel(plan.position_km[i], plan.velocity_km_s[i], rp, vp, fr.attitude.R_cam_icrs, obs.camera,
                             corrections=CASES[1], sun_position_km=eph.position("sun", t),
                             planet_radius_km=BODY_RADII_KM[plan.target[i]] if phase_offset else 0.0,
                             photocentre=use)
            errs.append(np.asarray(b.xy_px) - m.xy_px)
            keys.append(f"{plan.target[i]}/{use}")
            tracks.append((ip, int(plan.leg[i]), plan.phase[i]))
            if len(out) > 4:
                out[4].append(i)
            diam.append(diameter_px(BODY_RADII_KM[plan.target[i]], np.linalg.norm(rp - plan.position_km[i]), obs.camera))
    return cat


def _fit_noise(plan, errs, diam, keys, tracks):
    if not errs:
        raise NavInputError(f"{plan.root}: the image processing found no target planet on the calibration frames")
    e = np.array(errs)
    d = np.array(diam)
    e2 = 0.5 * np.sum(e * e, 1)                       # mean square per axis, one per frame
    keep = np.ones(len(e), dtype=bool)
    A = np.column_stack([np.ones_like(d), d * d])
    for _ in range(10):  # fit, then clip outliers (blends, misidentified spots) at the 2-dof 99.7 % point
        coef, _ = nnls(A[keep], e2[keep])
        coef[0] = max(coef[0], 1e-6)
        new = 2.0 * e2 / (A @ coef) <= 11.6
        if np.array_equal(new, keep) or new.sum() < 3:
            break
        keep = new
    classes = []
    keys = np.array(keys)
    for k in sorted(set(keys.tolist())):
        sel = keys == k
        if sel.sum() < MIN_CLASS_FRAMES:
            continue
        ck = np.ones(int(sel.sum()), dtype=bool)
        for _ in range(10):   # the same 99.7 % clipping, within the class
            s2 = float(np.mean(e2[sel][ck]))
            new = 2.0 * e2[sel] / s2 <= 11.6
            if np.array_equal(new, ck) or new.sum() < MIN_CLASS_FRAMES:
                break
            ck = new
        sb = track_bias_sigma(e[sel][ck], [tracks[j] for j in np.flatnonzero(sel)[ck]], s2)
        classes.append((str(k), math.sqrt(s2), int(ck.sum()), sb))
    return CentroidNoise(sigma0_px=float(np.sqrt(coef[0])), kappa=float(np.sqrt(coef[1])), mean_px=tuple(e[keep].mean(0)),
                         frames=int(keep.sum()), clipped=int((~keep).sum()), classes=tuple(classes))


#: A centroid is not used when another body is predicted closer than this to the target: the two
#: make one spot (the IP's ``ProcessOptions.blend_px``). Measured: the Earth with the Moon 3.6 px
#: away (leg 8 of the reference campaign) is off by 0.9 px, with the Moon 12 px away by 0.05 px.
BLEND_PX = 8.0


def centroid_usable(obs, fr, beacon, target, *, t, position_km, ephemeris):
    """How the filter may use the target's centroid: None (not at all: another body is predicted
    within :data:`BLEND_PX`), else the photocentre law of
    :func:`skynav.pipeline.measurement.planet_pixel` (``"saturated"`` when the disc is resolved,
    wider than four PSF sigmas, and its spot has pixels at full scale; else ``"lambert"``).
    On-board knowledge only: the image, the estimate ``position_km``, the ephemeris, the camera.
    """
    cam = obs.camera
    R = fr.attitude.R_cam_icrs
    r = np.asarray(position_km, dtype=float)

    def pixel(name):
        u = R @ (ephemeris.position(name, t) - r)
        return None if u[2] <= 0 else cam.project(u.reshape(1, 3))[0]

    xy_t = pixel(target)
    if xy_t is None:
        return None
    for name in BODY_RADII_KM:
        if name in (target, "sun"):
            continue
        xy = pixel(name)
        if xy is not None and np.all(np.isfinite(xy)) and float(np.hypot(*(xy - xy_t))) < BLEND_PX:
            return None
    d_px = diameter_px(BODY_RADII_KM.get(target, 0.0), float(np.linalg.norm(ephemeris.position(target, t) - r)), cam)
    if d_px > 4.0 * cam.psf.equivalent_sigma_px(cam) and spot_saturated(
            obs.dn, beacon.xy_px, 0.5 * d_px + 1.0, float(cam.sensor.max_dn)):
        return "saturated"
    return "lambert"


def track_bias_sigma(errors_px, tracks, mean_square_px2: float) -> float:
    """The part of a class's centroid error that is constant over a track, px (per axis).

    Method of moments: the track means' mean square beyond the ``mean_square / n`` that
    independent frames would give them; 0 when negative or with fewer than 2 tracks of 2+ frames.
    ``errors_px`` (M, 2), ``tracks`` M hashable track labels, ``mean_square_px2`` the class's
    total mean square per axis.
    """
    e = np.asarray(errors_px, dtype=float).reshape(-1, 2)
    groups = {}
    for j, tr in enumerate(tracks):
        groups.setdefault(tr, []).append(j)
    excess = [float(np.mean(e[g].mean(0) ** 2)) - mean_square_px2 / len(g) for g in groups.values() if len(g) >= 2]
    return math.sqrt(max(0.0, float(np.mean(excess)))) if len(excess) >= 2 else 0.0


def target_beacon(fr, target):
    """The frame's beacon result for ``target`` when found (and the attitude solved), else None."""
    if fr.status != "ok" or fr.attitude.R_cam_icrs is None:
        return None
    for b in fr.beacons:
        if b.name == target and b.status == "found" and b.xy_px is not None:
            return b
    return None
