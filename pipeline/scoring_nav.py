"""The navigation benchmark's campaign: Monte Carlo EKF runs along a ``sequence`` dataset, scored
against its truth (``skynav bench nav``).

Scoring module (it reads ground truth; ``tests/test_architecture.py`` lets only ``pipeline/scor*``
do that). What each part sees:

- the filter (:mod:`skynav.pipeline.ekf`) sees the images through
  :func:`skynav.pipeline.process_frame` (attitude and planet centroid), the calibrated camera, the
  on-board DE421 and the commanded pointing plan (which planet each frame was pointed at: the
  dataset's leg plan, ``legs.csv`` / the frame's ``dataset.target``), never the truth;
- the truth is read here for: the Monte Carlo initial states (paper 002 Eq. 45-46: nominal state
  plus ``sqrt(P0)`` times a standard normal draw), the measurement-noise calibration (below), and
  the scores (errors, NEES, measured centroid errors).

Measurement noise ``R = sigma_px^2 I``: measured, not guessed (paper 002 Sec. 5.1 did the same
with its image-processing Monte Carlo): before the filter runs, the image processing is run on
every ``calibration_stride``-th frame (default: every frame; with every 4th the per-class sigmas
came out 10-15 % low on the reference campaign, e.g. Mars 0.061 against 0.070 px from all frames,
within their sampling error but enough to show in the NEES) with a predicted state drawn from P0
about the truth, and
the target's centroid minus the measurement model at the true state gives the errors
(:class:`CentroidNoise`): per class of measurement (target and photocentre law) with at least
:data:`MIN_CLASS_FRAMES` frames, the class's mean square per axis and the part of it constant over
a track (:func:`track_bias_sigma`); otherwise ``sigma0^2 + (kappa D)^2`` with ``D`` the planet's
apparent diameter in px, fitted on all frames by non-negative least squares. Both with iterated
99.7 % clipping of outliers such as a star blended with the planet, which the filter's innovation
gate rejects; the filter evaluates ``D`` from its own estimate. ``--sigma-px`` gives a constant
instead.

Phase: the renderer draws planets as lit discs, whose centre of light sits up to ~0.4 diameter
from the centre towards the Sun (1.8 px for the Earth early in the cruise, 0.2 px for Venus). By
default the measurement model aims at the photocentre: the Lambert one
(:func:`skynav.pipeline.measurement.lambert_photocentre_offset`), or for a resolved disc whose
spot is saturated the lit area's centroid
(:func:`skynav.pipeline.measurement.saturated_photocentre_offset`; :func:`centroid_usable`
decides from the image); ``phase_offset=False`` keeps paper 002's centre-of-planet model. A
centroid with another body predicted within :data:`BLEND_PX` is not used (the Earth and the Moon
in one spot).

The image processing runs once per frame for all the runs of a worker (the predicted state it
gets is the runs' mean, with the runs' mean covariance plus their spread); with ``workers > 1``
the runs are split into chunks and every worker processes the frames once for its chunk.
"""

from __future__ import annotations

import math
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from .ekf import NavFilter, initial_covariance
from .errors import BenchInputError
from .filter_dynamics import FilterDynamics
from .measurement import CASES, spot_saturated

__all__ = ["NavInputError", "NavPlan", "CampaignResult", "CentroidNoise", "load_plan", "calibrate_sigma_px",
           "run_campaign", "run_realisations", "check_realisations", "icrs_to_ecliptic", "centroid_usable", "track_bias_sigma", "BLEND_PX"]


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


class NavInputError(BenchInputError):
    """The dataset cannot feed a navigation campaign (not a sequence, no visible planet, missing frame)."""


def icrs_to_ecliptic() -> np.ndarray:
    """Rotation ICRS -> ecliptic J2000 (mean obliquity of J2000), shape (3, 3)."""
    from skynav.scenes.constants import OBLIQUITY_J2000_RAD as e

    c, s = math.cos(e), math.sin(e)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, s], [0.0, -s, c]])


@dataclass(frozen=True, kw_only=True, eq=False)
class NavPlan:
    """What the campaign needs of the dataset (truth columns for scoring only)."""

    root: str
    frames: int
    t_tdb_s: np.ndarray            # (F,)
    leg: np.ndarray                # (F,) int
    phase: tuple                   # (F,) str
    target: tuple                  # (F,) str: commanded pointing
    position_km: np.ndarray        # (F, 3) truth
    velocity_km_s: np.ndarray      # (F, 3) truth
    target_xy_px: np.ndarray       # (F, 2) truth xy of the target (NaN: not visible)
    plan_pairs: tuple              # per leg (A, B) of the dataset's planner
    images: str | None = None


def load_plan(path, *, images=None, limit=None) -> NavPlan:
    """Read and check a ``sequence`` dataset. Raises :class:`NavInputError` with one line."""
    import skynav.datasets as sdat
    from skynav.datasets.errors import DatasetError

    root = Path(path)
    try:
        ds = sdat.open(root)
    except (DatasetError, OSError, ValueError) as exc:
        raise NavInputError(f"{root}: not a readable dataset ({exc})") from None
    kind = ds.recipe.get("kind")
    if kind != "sequence":
        raise NavInputError(f"{root}: a {kind!r} dataset has no navigation sequence; give a 'sequence' dataset "
                            "(skynav dataset generate sequence -o DIR)")
    n = len(ds) if limit is None else min(len(ds), int(limit))
    if n < 2:
        raise NavInputError(f"{root}: {n} frame(s); a navigation campaign needs at least 2")
    try:
        rows = ds.index
    except (DatasetError, OSError, ValueError) as exc:
        raise NavInputError(f"{root}: unreadable index.csv ({exc})") from None
    if len(rows) < n:
        raise NavInputError(f"{root}: index.csv lists {len(rows)} frames, the manifest {len(ds)}")
    for i in range(n):
        for rel in rows[i].get("files", "").split(";"):
            if rel.endswith((".png", ".json")) and not (root / rel).is_file():
                raise NavInputError(f"{root}: frame {i} is missing ({rel})")
        if images is not None and not _image_path(images, i).is_file():
            raise NavInputError(f"--images {images}: frame {i} is missing ({_image_path(images, i).name})")
    t = np.empty(n)
    leg = np.empty(n, dtype=int)
    phase, target = [], []
    pos = np.empty((n, 3))
    vel = np.empty((n, 3))
    xy = np.full((n, 2), np.nan)
    any_visible = False
    for i in range(n):
        tr = ds.truth(i, validate=False)
        meta = tr.raw.get("dataset", {})
        t[i] = tr.epoch_tdb_s
        leg[i] = int(meta.get("leg", 0))
        phase.append(str(meta.get("phase", "")))
        tgt = str(meta.get("target") or "")
        target.append(tgt)
        pos[i], vel[i] = tr.position_km, tr.velocity_km_s
        for b in tr.bodies:
            if b.name == tgt and b.visible and b.in_fov:
                xy[i] = b.xy
                any_visible = True
    if not any_visible:
        raise NavInputError(f"{root}: no frame shows its target planet (no visible planet to navigate on)")
    pairs = ds.manifest.get("plan", {}).get("pairs") if isinstance(ds.manifest.get("plan"), dict) else None
    if not pairs:
        pairs = []
        for lg in sorted(set(leg.tolist())):
            a = [target[i] for i in range(n) if leg[i] == lg and phase[i] == "track_A"]
            b = [target[i] for i in range(n) if leg[i] == lg and phase[i] == "track_B"]
            pairs.append((a[0] if a else "", b[0] if b else ""))
    return NavPlan(root=str(root), frames=n, t_tdb_s=t, leg=leg, phase=tuple(phase), target=tuple(target),
                   position_km=pos, velocity_km_s=vel, target_xy_px=xy, plan_pairs=tuple(tuple(p) for p in pairs),
                   images=None if images is None else str(images))


def _image_path(images, i) -> Path:
    d = Path(images)
    p = d / f"{i:06d}.png"
    return p if p.is_file() or not (d / "frames").is_dir() else d / "frames" / f"{i:06d}.png"


def _observation(ds, plan: NavPlan, i):
    obs = ds.observation(i)
    if plan.images is None:
        return obs
    from dataclasses import replace

    from skynav.datasets.reader import read_image_dn

    dn = read_image_dn(_image_path(plan.images, i))  # the DN of scaled (sBIT) and raw PNGs alike
    if dn.shape != np.shape(obs.dn):
        raise NavInputError(f"--images {plan.images}: frame {i} is {dn.shape}, the dataset's {np.shape(obs.dn)}")
    return replace(obs, dn=dn)


def calibrate_sigma_px(plan, *, stride: int = 1, seed: int = 0, sigma_position_km: float = 1e4,
                       sigma_velocity_km_s: float = 0.1, phase_offset: bool = True):
    """Measured planet-centroid error, a :class:`CentroidNoise` (module docstring).

    The error is the image processing's target centroid minus the measurement model (case 1,
    with the Lambert photocentre offset if ``phase_offset``) evaluated at the TRUE state with the
    image processing's attitude: what the filter's R must describe.

    ``plan`` may be a list of renderings of the same cruise (``bench nav --calibrate-on``): their
    frames are pooled, each rendering's tracks kept apart, so that the track-constant part
    sigma_b is the ensemble's (over sensor and noise realisations) rather than one rendering's
    draw of it (0 to 0.07 px for the Earth's saturated disc over four renderings).
    """
    import skynav.datasets as sdat
    from skynav.scenes.ephemeris_jpl import default_ephemeris

    eph = default_ephemeris()
    plans = list(plan) if isinstance(plan, (list, tuple)) else [plan]
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0xCA1]))
    cat = None
    errs = []
    diam = []
    keys = []
    tracks = []
    for ip, plan in enumerate(plans):
        ds = sdat.open(plan.root)
        cat = _calibrate_rendering(plan, ds, ip, stride=stride, rng=rng, cat=cat, eph=eph, out=(errs, diam, keys, tracks),
                                   sigma_position_km=sigma_position_km, sigma_velocity_km_s=sigma_velocity_km_s,
                                   phase_offset=phase_offset)
    return replace(_fit_noise(plans[0], errs, diam, keys, tracks), renderings=len(plans))


def _calibrate_rendering(plan, ds, ip, *, stride, rng, cat, eph, out, sigma_position_km, sigma_velocity_km_s, phase_offset):
    from skynav.scenes.ephemeris_jpl import BODY_RADII_KM

    from . import OnboardCatalog, PredictedState, process_frame
    from .measurement import planet_pixel

    errs, diam, keys, tracks = out
    prev = None
    for i in range(0, plan.frames, max(1, stride)):
        if not np.all(np.isfinite(plan.target_xy_px[i])):
            continue
        obs = _observation(ds, plan, i)
        if cat is None:
            cat = OnboardCatalog.load(camera=obs.camera)
        ps = PredictedState(position_km=plan.position_km[i] + sigma_position_km * rng.standard_normal(3),
                            velocity_km_s=plan.velocity_km_s[i] + sigma_velocity_km_s * rng.standard_normal(3),
                            position_cov_km2=np.eye(3) * sigma_position_km**2)
        fr = process_frame(obs, catalog=cat, predicted_state=ps, previous_attitude=prev)
        prev = fr.attitude.R_cam_icrs
        b = _target_beacon(fr, plan.target[i])
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
            diam.append(diameter_px(BODY_RADII_KM[plan.target[i]], np.linalg.norm(rp - plan.position_km[i]), obs.camera))
    return cat


def _fit_noise(plan, errs, diam, keys, tracks):
    if not errs:
        raise NavInputError(f"{plan.root}: the image processing found no target planet on the calibration frames")
    from scipy.optimize import nnls

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


#: Iterated EKF update in the campaign: after the first 10-day propagation the position is known to
#: ~1e5 km only and the first Earth fix is nonlinear over that spread; with the one-step EKF 2 of 6
#: runs (seed 3, synthetic centroids) were left 4 sigma off and then gated out every later
#: measurement (final error 4e6 km); 3 iterations keep them all (tests/pipeline/test_ekf_iterated.py).
UPDATE_ITERATIONS = 3

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
    from skynav.scenes.ephemeris_jpl import BODY_RADII_KM

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
    if d_px > 4.0 * float(getattr(cam, "defocus_sigma_px", 0.5)) and spot_saturated(
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


def _target_beacon(fr, target):
    if fr.status != "ok" or fr.attitude.R_cam_icrs is None:
        return None
    for b in fr.beacons:
        if b.name == target and b.status == "found" and b.xy_px is not None:
            return b
    return None


@dataclass(frozen=True, kw_only=True, eq=False)
class CampaignResult:
    """Per-run, per-frame histories (runs R, frames F). Errors are estimate minus truth, ICRS."""

    case: int
    noise: CentroidNoise
    t_tdb_s: np.ndarray          # (F,)
    error: np.ndarray            # (R, F, 6) km, km/s (after the frame's update)
    cov: np.ndarray              # (R, F, 6, 6)
    residual_px: np.ndarray      # (R, F, 2) pre-fit innovations (NaN: no measurement)
    accepted: np.ndarray         # (R, F) bool
    ip_status: tuple             # (F,) frame status of the worker of run 0
    measured_error_px: np.ndarray  # (F, 2): centroid - truth xy (NaN: none)
    ip_time_s: float
    filter_time_s: float
    pairs: tuple                 # per leg: (leg, plan pair, optimal pair from the estimate)
    sequences: int = 1           # independent image sequences behind the runs (run_realisations)


def _run_chunk(plan: NavPlan, x0, P0, case: int, noise: CentroidNoise, dynamics: FilterDynamics, phase_offset: bool,
               progress_q=None, synthetic_seed=None):
    import skynav.datasets as sdat
    from skynav.scenes.constants import SECONDS_PER_DAY
    from skynav.scenes.ephemeris_jpl import BODY_RADII_KM, default_ephemeris

    from . import OnboardCatalog, PredictedState, process_frame
    from .measurement import planet_pixel
    from .pairs import candidates_from_state, optimal_pair

    ds = sdat.open(plan.root)
    eph = default_ephemeris()
    t = plan.t_tdb_s
    dyn = dynamics.bind(eph, t[0] - SECONDS_PER_DAY, t[-1] + SECONDS_PER_DAY)
    kf = NavFilter(dyn, x0, P0, t[0], corrections=CASES[case], iterations=UPDATE_ITERATIONS)
    n_runs, F = kf.n_runs, plan.frames
    err = np.empty((n_runs, F, 6))
    cov = np.empty((n_runs, F, 6, 6))
    res = np.full((n_runs, F, 2), np.nan)
    acc = np.zeros((n_runs, F), dtype=bool)
    meas = np.full((F, 2), np.nan)
    status = []
    cat = None
    prev = None
    ip_s = fl_s = 0.0
    track_frames = {}   # frames per (leg, phase): the commanded observation plan
    for lg, ph in zip(plan.leg, plan.phase):
        track_frames[(int(lg), ph)] = track_frames.get((int(lg), ph), 0) + 1
    pairs = []
    for i in range(F):
        c0 = time.perf_counter()
        kf.propagate(t[i])
        if i == 0 or plan.leg[i] != plan.leg[i - 1]:
            lg = int(plan.leg[i])
            mean = kf.x.mean(0)
            choice = optimal_pair(candidates_from_state(t[i], mean[:3], mean[3:6], ephemeris=eph))
            plan_pair = plan.plan_pairs[lg] if lg < len(plan.plan_pairs) else ("", "")
            pairs.append((lg, tuple(plan_pair), None if choice is None else (choice.first, choice.second)))
        c1 = time.perf_counter()
        obs = _observation(ds, plan, i)
        if cat is None:
            cat = OnboardCatalog.load(camera=obs.camera)
        mean = kf.x.mean(0)
        spread = np.cov(kf.x[:, :3].T) if n_runs > 1 else np.zeros((3, 3))
        # the image processing predicts the planet's centre; its spot is the centre of light, up to
        # 0.9 radius away (measurement.lambert_photocentre_offset): widen the search by one radius
        radius = BODY_RADII_KM.get(plan.target[i], 0.0)
        ps = PredictedState(position_km=mean[:3], velocity_km_s=mean[3:6],
                            position_cov_km2=kf.P[:, :3, :3].mean(0) + spread + radius**2 * np.eye(3))
        fr = process_frame(obs, catalog=cat, predicted_state=ps, previous_attitude=prev)
        prev = fr.attitude.R_cam_icrs
        status.append(fr.status)
        b = _target_beacon(fr, plan.target[i])
        use = None if b is None else centroid_usable(obs, fr, b, plan.target[i], t=t[i], position_km=mean[:3],
                                                     ephemeris=eph)
        c2 = time.perf_counter()
        if b is not None and use is None:
            status[-1] = "blended"
        if use is not None:
            rp, vp = eph.position_velocity(plan.target[i], t[i])
            radius = BODY_RADII_KM[plan.target[i]]
            sigma_px = noise.sigma_px(diameter_px(radius, np.linalg.norm(rp - mean[:3]), obs.camera),
                                      f"{plan.target[i]}/{use}", track_frames[(int(plan.leg[i]), plan.phase[i])])
            zxy = np.asarray(b.xy_px, dtype=float)
            if synthetic_seed is not None:
                # reference mode: the exact model (case 1, this photocentre law) at the TRUE state
                # plus white noise of exactly the filter's R; the same draw in every worker
                m_true = planet_pixel(plan.position_km[i], plan.velocity_km_s[i], rp, vp, fr.attitude.R_cam_icrs,
                                      obs.camera, corrections=CASES[1], sun_position_km=eph.position("sun", t[i]),
                                      planet_radius_km=radius if phase_offset else 0.0, photocentre=use)
                g = np.random.default_rng(np.random.SeedSequence([int(synthetic_seed), 0x5E, i]))
                zxy = m_true.xy_px + sigma_px * g.standard_normal(2)
            z = np.broadcast_to(zxy, (n_runs, 2))
            u = kf.update(z, rp, vp, fr.attitude.R_cam_icrs, obs.camera, sigma_px,
                          sun_position_km=eph.position("sun", t[i]),
                          planet_radius_km=radius if phase_offset else 0.0, photocentre=use)
            res[:, i], acc[:, i] = u.residual_px, u.accepted
        if b is not None:
            meas[i] = (zxy if use is not None else np.asarray(b.xy_px)) - plan.target_xy_px[i]
        truth = np.concatenate([plan.position_km[i], plan.velocity_km_s[i]])
        err[:, i] = kf.x[:, :6] - truth
        cov[:, i] = kf.P[:, :6, :6]
        c3 = time.perf_counter()
        ip_s += c2 - c1
        fl_s += (c1 - c0) + (c3 - c2)
        if progress_q is not None:
            progress_q(1)
    return dict(err=err, cov=cov, res=res, acc=acc, meas=meas, status=tuple(status), ip_s=ip_s, fl_s=fl_s,
                pairs=tuple(pairs))


def _chunk_worker(args):
    return _run_chunk(*args)


def run_campaign(plan: NavPlan, *, runs: int = 50, case: int = 1, seed: int = 0, workers: int = 1,
                 noise: CentroidNoise, dynamics: FilterDynamics | None = None, phase_offset: bool = True,
                 progress=None, synthetic_seed: int | None = None) -> CampaignResult:
    """Monte Carlo EKF runs along the plan (paper 002 Eq. 45-46 initial errors, 001 Table 2 sigmas).

    ``progress``: a callable ``progress(n_frames_done)`` (in-process only) or None.
    ``synthetic_seed``: reference mode; every centroid the filter would use is replaced by the
    measurement model at the true state plus white noise of the filter's own R (seeded): what a
    consistent filter shows on ONE realisation shared by the runs (``benchmarks/nav_consistency.py``).
    """
    if case not in CASES:
        raise NavInputError(f"--case {case}: give 1, 2, 3, 4 or 5")
    if runs < 1:
        raise NavInputError(f"--runs {runs}: give at least 1 run")
    dynamics = dynamics or FilterDynamics()
    P0 = initial_covariance()   # paper 001 Table 2
    rng = np.random.default_rng(np.random.SeedSequence([seed, 45]))
    nominal = np.concatenate([plan.position_km[0], plan.velocity_km_s[0], np.zeros(6)])
    x0 = nominal + rng.standard_normal((runs, 12)) * np.sqrt(np.diag(P0))   # paper 002 Eq. 45
    workers = max(1, min(int(workers), runs))
    chunks = np.array_split(np.arange(runs), workers)
    if workers == 1:
        outs = [_run_chunk(plan, x0, P0, case, noise, dynamics, phase_offset, progress, synthetic_seed)]
    else:
        with ProcessPoolExecutor(workers) as ex:
            outs = list(ex.map(_chunk_worker, [(plan, x0[c], P0, case, noise, dynamics, phase_offset, None, synthetic_seed)
                                                    for c in chunks]))
    cat = lambda k: np.concatenate([o[k] for o in outs], 0)  # noqa: E731
    return CampaignResult(case=case, noise=noise, t_tdb_s=plan.t_tdb_s, error=cat("err"),
                          cov=cat("cov"), residual_px=cat("res"), accepted=cat("acc"), ip_status=outs[0]["status"],
                          measured_error_px=outs[0]["meas"], ip_time_s=max(o["ip_s"] for o in outs),
                          filter_time_s=max(o["fl_s"] for o in outs), pairs=outs[0]["pairs"])


def _realisation_worker(args):
    plan, kw = args
    return run_campaign(plan, **kw)


def check_realisations(plans, reference: NavPlan) -> None:
    """Raise :class:`NavInputError` (one line) unless every plan renders ``reference``'s cruise."""
    for p in plans:
        if p.frames != reference.frames or not np.allclose(p.position_km, reference.position_km, rtol=0, atol=1e-6):
            raise NavInputError(f"{p.root}: not a rendering of {reference.root}'s cruise (other frames or trajectory); "
                                "realisations differ only by their --seed")


def run_realisations(plans, *, runs: int, case: int = 1, seed: int = 0, workers: int = 1, noise: CentroidNoise,
                     dynamics: FilterDynamics | None = None, phase_offset: bool = True, progress=None,
                     reference: NavPlan | None = None) -> CampaignResult:
    """The Monte Carlo with independent measurement noise: ``plans`` are renderings of ONE cruise
    (the same trajectory, another dataset seed: other image noise, cosmic rays and pointing), the
    ``runs`` are dealt round-robin over them (``runs == len(plans)``: every run has images of its
    own, a textbook Monte Carlo whose NEES band is exact), each with its own initial-error draw.
    ``noise`` is calibrated elsewhere (out of sample), e.g. on ``reference``, the dataset every
    plan must be a rendering of (same frames, same trajectory). Returns the runs concatenated in one
    :class:`CampaignResult` (per-frame fields from the first plan). ``progress(1)`` per plan done.
    """
    plans = list(plans)
    if not plans:
        raise NavInputError("--realisations: give at least one dataset")
    check_realisations(plans, reference if reference is not None else plans[0])
    counts = [len(c) for c in np.array_split(np.arange(runs), len(plans))]
    jobs = [(p, dict(runs=n, case=case, seed=int(np.random.SeedSequence([seed, 0x5EA, k]).generate_state(1)[0]),
                     noise=noise, dynamics=dynamics, phase_offset=phase_offset))
            for k, (p, n) in enumerate(zip(plans, counts)) if n > 0]
    if workers > 1 and len(jobs) > 1:
        outs = []
        with ProcessPoolExecutor(min(workers, len(jobs))) as ex:
            for r in ex.map(_realisation_worker, jobs):
                outs.append(r)
                if progress is not None:
                    progress(1)
    else:
        outs = []
        for j in jobs:
            outs.append(_realisation_worker(j))
            if progress is not None:
                progress(1)
    cat = lambda k: np.concatenate([getattr(o, k) for o in outs], 0)  # noqa: E731
    o0 = outs[0]
    return CampaignResult(case=case, noise=noise, t_tdb_s=o0.t_tdb_s, error=cat("error"), cov=cat("cov"),
                          residual_px=cat("residual_px"), accepted=cat("accepted"), ip_status=o0.ip_status,
                          measured_error_px=o0.measured_error_px, ip_time_s=sum(o.ip_time_s for o in outs),
                          filter_time_s=sum(o.filter_time_s for o in outs), pairs=o0.pairs,
                          sequences=len(outs))
