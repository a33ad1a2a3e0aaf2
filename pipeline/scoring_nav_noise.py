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
from dataclasses import replace

import numpy as np
from scipy.optimize import nnls

import skynav.datasets as sdat
from skynav.scenes.ephemeris_jpl import BODY_RADII_KM, default_ephemeris

from .flight import DEFAULT_PIPELINE, measure_target
from .measurement import CASES, planet_pixel
from .plugins import load_image_processor
from .planet_centroid import CentroidNoise, diameter_px
from .results import PredictedState
from .scoring_nav_plan import NavInputError, observation

__all__ = ["MIN_CLASS_FRAMES", "calibrate_sigma_px", "centroid_errors", "track_bias_sigma"]


#: A class of measurements needs this many calibration frames for its own sigma (18 degrees of
#: freedom per 9 frames: the sigma is then known to ~ +-17 %, 1 sigma).
MIN_CLASS_FRAMES = 9


def calibrate_sigma_px(plan, *, stride: int = 1, seed: int = 0, sigma_position_km: float = 1e4,
                       sigma_velocity_km_s: float = 0.1, phase_offset: bool = True, observations=None,
                       pipeline: str = DEFAULT_PIPELINE, frame_timeout_s: float | None = None):
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

    ``pipeline``: the image processor whose centroids are measured, ``MODULE:FACTORY`` (the
    flight's, :mod:`skynav.pipeline.flight`); a new one per rendering, made with its first frame's camera;
    ``frame_timeout_s`` its time limit per frame (None: none; a frame past it is not measured).
    """
    eph = default_ephemeris()
    plans = list(plan) if isinstance(plan, (list, tuple)) else [plan]
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0xCA1]))
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
        _calibrate_rendering(plan, get, ip, stride=stride, rng=rng, pipeline=pipeline, timeout_s=frame_timeout_s, eph=eph,
                             out=(errs, diam, keys, tracks),
                             sigma_position_km=sigma_position_km, sigma_velocity_km_s=sigma_velocity_km_s,
                             phase_offset=phase_offset)
    return replace(_fit_noise(plans[0], errs, diam, keys, tracks), renderings=len(plans))


def centroid_errors(plan, *, seed: int = 0, sigma_position_km: float = 1e4, sigma_velocity_km_s: float = 0.1,
                    phase_offset: bool = True, pipeline: str = DEFAULT_PIPELINE) -> tuple[np.ndarray, tuple]:
    """Frame by frame, the centroid error :func:`calibrate_sigma_px` measures on ``plan``'s frames
    (its predicted states drawn from ``seed`` as it draws them, so that two plans of one cruise
    with different images see the same ones): ``(errors (F, 2) px, NaN where the target's centroid
    is not used; class keys (F,), "" there)``. For comparing two renderings frame by frame."""
    eph = default_ephemeris()
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0xCA1]))
    ds = sdat.open(plan.root)
    out = ([], [], [], [], [])
    _calibrate_rendering(plan, lambda i: observation(ds, plan, i), 0, stride=1, rng=rng, pipeline=pipeline, timeout_s=None,
                         eph=eph, out=out,
                         sigma_position_km=sigma_position_km, sigma_velocity_km_s=sigma_velocity_km_s,
                         phase_offset=phase_offset)
    errs, _, keys, _, idx = out
    e = np.full((plan.frames, 2), np.nan)
    k = [""] * plan.frames
    for j, i in enumerate(idx):
        e[i], k[i] = errs[j], keys[j]
    return e, tuple(k)


def _calibrate_rendering(plan, get, ip, *, stride, rng, pipeline, timeout_s, eph, out, sigma_position_km, sigma_velocity_km_s,
                         phase_offset):
    errs, diam, keys, tracks = out[:4]
    proc = None
    for i in range(0, plan.frames, max(1, stride)):
        if not np.all(np.isfinite(plan.target_xy_px[i])):
            continue
        obs = get(i)
        if proc is None:
            proc = load_image_processor(pipeline, obs.camera)
        ps = PredictedState(position_km=plan.position_km[i] + sigma_position_km * rng.standard_normal(3),
                            velocity_km_s=plan.velocity_km_s[i] + sigma_velocity_km_s * rng.standard_normal(3),
                            position_cov_km2=np.eye(3) * sigma_position_km**2)
        # the flight step's image part (pipeline.flight); the filter's view (an estimate drawn about
        # the truth) decides blends and the photocentre law
        sight = measure_target(obs, plan.target[i], t=plan.t_tdb_s[i], predicted_state=ps, processor=proc, ephemeris=eph,
                               timeout_s=timeout_s)
        b, use = sight.beacon, sight.use
        if use is not None:
            t = plan.t_tdb_s[i]
            rp, vp = eph.position_velocity(plan.target[i], t)
            m = planet_pixel(plan.position_km[i], plan.velocity_km_s[i], rp, vp, sight.R_cam_icrs, obs.camera,
                             corrections=CASES[1], sun_position_km=eph.position("sun", t),
                             planet_radius_km=BODY_RADII_KM[plan.target[i]] if phase_offset else 0.0,
                             photocentre=use)
            errs.append(np.asarray(b.xy_px) - m.xy_px)
            keys.append(f"{plan.target[i]}/{use}")
            tracks.append((ip, int(plan.leg[i]), plan.phase[i]))
            if len(out) > 4:
                out[4].append(i)
            diam.append(diameter_px(BODY_RADII_KM[plan.target[i]], np.linalg.norm(rp - plan.position_km[i]), obs.camera))


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

