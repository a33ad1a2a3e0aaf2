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
every ``calibration_stride``-th frame with a predicted state drawn from P0 about the truth, and
the target's centroid minus the measurement model at the true state gives the errors; their
mean square per axis is fitted as ``sigma0^2 + (kappa D)^2`` with ``D`` the planet's apparent
diameter in px (:class:`CentroidNoise`; non-negative least squares with iterated 99.7 % clipping of
outliers such as a star blended with the planet, which the filter's innovation gate rejects); the filter evaluates ``D`` from its own estimate.
``--sigma-px`` gives a constant instead.

Phase: the renderer draws planets as lit discs, whose centre of light sits up to ~0.4 diameter
from the centre towards the Sun (1.5 px for the Earth early in the cruise, 0.2 px for Venus). By
default the measurement model aims at the Lambert photocentre
(:func:`skynav.pipeline.measurement.lambert_photocentre_offset`); ``phase_offset=False`` keeps
paper 002's centre-of-planet model.

The image processing runs once per frame for all the runs of a worker (the predicted state it
gets is the runs' mean, with the runs' mean covariance plus their spread); with ``workers > 1``
the runs are split into chunks and every worker processes the frames once for its chunk.
"""

from __future__ import annotations

import math
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .ekf import NavFilter, initial_covariance
from .errors import BenchInputError
from .filter_dynamics import FilterDynamics
from .measurement import CASES

__all__ = ["NavInputError", "NavPlan", "CampaignResult", "CentroidNoise", "load_plan", "calibrate_sigma_px",
           "run_campaign", "icrs_to_ecliptic"]


@dataclass(frozen=True, kw_only=True)
class CentroidNoise:
    """Measurement noise per axis, ``sigma^2 = sigma0_px^2 + (kappa D)^2`` with ``D`` the planet's
    predicted apparent diameter in px (a lit disc's centroid is noisier and its phase model less
    exact the larger it is). Fitted on the calibration frames by non-negative least squares."""

    sigma0_px: float
    kappa: float = 0.0
    mean_px: tuple = (0.0, 0.0)
    frames: int = 0
    clipped: int = 0

    def sigma_px(self, diameter_px: float) -> float:
        return math.sqrt(self.sigma0_px**2 + (self.kappa * diameter_px) ** 2)

    def describe(self) -> str:
        return (f"sigma = sqrt({self.sigma0_px:.3f}^2 + ({self.kappa:.3f} D)^2) px, measured on {self.frames} frames "
                f"({self.clipped} clipped as outliers; mean error {np.round(self.mean_px, 3).tolist()} px)") if self.frames else f"{self.sigma0_px:g} px (given)"


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

    from PIL import Image

    with Image.open(_image_path(plan.images, i)) as im:
        dn = np.array(im)
    if dn.shape != np.shape(obs.dn):
        raise NavInputError(f"--images {plan.images}: frame {i} is {dn.shape}, the dataset's {np.shape(obs.dn)}")
    return replace(obs, dn=dn)


def calibrate_sigma_px(plan: NavPlan, *, stride: int = 8, seed: int = 0, sigma_position_km: float = 1e4,
                       sigma_velocity_km_s: float = 0.1, phase_offset: bool = True):
    """Measured planet-centroid error, a :class:`CentroidNoise` (module docstring).

    The error is the image processing's target centroid minus the measurement model (case 1,
    with the Lambert photocentre offset if ``phase_offset``) evaluated at the TRUE state with the
    image processing's attitude: what the filter's R must describe.
    """
    import skynav.datasets as sdat
    from skynav.scenes.ephemeris_jpl import BODY_RADII_KM, default_ephemeris

    from . import OnboardCatalog, PredictedState, process_frame
    from .measurement import planet_pixel

    eph = default_ephemeris()

    ds = sdat.open(plan.root)
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0xCA1]))
    cat = None
    errs = []
    diam = []
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
        if b is not None:
            t = plan.t_tdb_s[i]
            rp, vp = eph.position_velocity(plan.target[i], t)
            m = planet_pixel(plan.position_km[i], plan.velocity_km_s[i], rp, vp, fr.attitude.R_cam_icrs, obs.camera,
                             corrections=CASES[1], sun_position_km=eph.position("sun", t),
                             planet_radius_km=BODY_RADII_KM[plan.target[i]] if phase_offset else 0.0)
            errs.append(np.asarray(b.xy_px) - m.xy_px)
            diam.append(diameter_px(BODY_RADII_KM[plan.target[i]], np.linalg.norm(rp - plan.position_km[i]), obs.camera))
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
    return CentroidNoise(sigma0_px=float(np.sqrt(coef[0])), kappa=float(np.sqrt(coef[1])), mean_px=tuple(e[keep].mean(0)),
                         frames=int(keep.sum()), clipped=int((~keep).sum()))


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


def _run_chunk(plan: NavPlan, x0, P0, case: int, noise: CentroidNoise, dynamics: FilterDynamics, phase_offset: bool,
               progress_q=None):
    import skynav.datasets as sdat
    from skynav.scenes.constants import SECONDS_PER_DAY
    from skynav.scenes.ephemeris_jpl import BODY_RADII_KM, default_ephemeris

    from . import OnboardCatalog, PredictedState, process_frame
    from .pairs import candidates_from_state, optimal_pair

    ds = sdat.open(plan.root)
    eph = default_ephemeris()
    t = plan.t_tdb_s
    dyn = dynamics.bind(eph, t[0] - SECONDS_PER_DAY, t[-1] + SECONDS_PER_DAY)
    kf = NavFilter(dyn, x0, P0, t[0], corrections=CASES[case])
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
        c2 = time.perf_counter()
        if b is not None:
            rp, vp = eph.position_velocity(plan.target[i], t[i])
            radius = BODY_RADII_KM[plan.target[i]]
            sigma_px = noise.sigma_px(diameter_px(radius, np.linalg.norm(rp - mean[:3]), obs.camera))
            z = np.broadcast_to(np.asarray(b.xy_px, dtype=float), (n_runs, 2))
            u = kf.update(z, rp, vp, fr.attitude.R_cam_icrs, obs.camera, sigma_px,
                          sun_position_km=eph.position("sun", t[i]),
                          planet_radius_km=radius if phase_offset else 0.0)
            res[:, i], acc[:, i] = u.residual_px, u.accepted
            meas[i] = np.asarray(b.xy_px) - plan.target_xy_px[i]
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
                 progress=None) -> CampaignResult:
    """Monte Carlo EKF runs along the plan (paper 002 Eq. 45-46 initial errors, 001 Table 2 sigmas).

    ``progress``: a callable ``progress(n_frames_done)`` (in-process only) or None.
    """
    if case not in CASES:
        raise NavInputError(f"--case {case}: give 1, 2, 3, 4 or 5")
    if runs < 2:
        raise NavInputError(f"--runs {runs}: at least 2 runs are needed for sample statistics")
    dynamics = dynamics or FilterDynamics()
    P0 = initial_covariance()   # paper 001 Table 2
    rng = np.random.default_rng(np.random.SeedSequence([seed, 45]))
    nominal = np.concatenate([plan.position_km[0], plan.velocity_km_s[0], np.zeros(6)])
    x0 = nominal + rng.standard_normal((runs, 12)) * np.sqrt(np.diag(P0))   # paper 002 Eq. 45
    workers = max(1, min(int(workers), runs))
    chunks = np.array_split(np.arange(runs), workers)
    if workers == 1:
        outs = [_run_chunk(plan, x0, P0, case, noise, dynamics, phase_offset, progress)]
    else:
        with ProcessPoolExecutor(workers) as ex:
            outs = list(ex.map(_chunk_worker, [(plan, x0[c], P0, case, noise, dynamics, phase_offset, None)
                                                    for c in chunks]))
    cat = lambda k: np.concatenate([o[k] for o in outs], 0)  # noqa: E731
    return CampaignResult(case=case, noise=noise, t_tdb_s=plan.t_tdb_s, error=cat("err"),
                          cov=cat("cov"), residual_px=cat("res"), accepted=cat("acc"), ip_status=outs[0]["status"],
                          measured_error_px=outs[0]["meas"], ip_time_s=max(o["ip_s"] for o in outs),
                          filter_time_s=max(o["fl_s"] for o in outs), pairs=outs[0]["pairs"])
