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
``sigma_px`` is the RMS per axis of the target's centroid error against the truth's ``xy``
(bias included). ``--sigma-px`` overrides it.

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

__all__ = ["NavInputError", "NavPlan", "CampaignResult", "load_plan", "calibrate_sigma_px", "run_campaign",
           "icrs_to_ecliptic"]


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
                       sigma_velocity_km_s: float = 0.1):
    """Measured planet-centroid error: ``(sigma_px, mean_px (2,), n)`` (module docstring)."""
    import skynav.datasets as sdat

    from . import OnboardCatalog, PredictedState, process_frame

    ds = sdat.open(plan.root)
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0xCA1]))
    cat = None
    errs = []
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
            errs.append(np.asarray(b.xy_px) - plan.target_xy_px[i])
    if not errs:
        raise NavInputError(f"{plan.root}: the image processing found no target planet on the calibration frames")
    e = np.array(errs)
    return float(np.sqrt(np.mean(e**2))), e.mean(0), len(e)


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
    sigma_px: float
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


def _run_chunk(plan: NavPlan, x0, P0, case: int, sigma_px: float, dynamics: FilterDynamics, progress_q=None):
    import skynav.datasets as sdat
    from skynav.scenes.ephemeris_jpl import default_ephemeris

    from . import OnboardCatalog, PredictedState, process_frame
    from .pairs import candidates_from_state, optimal_pair

    ds = sdat.open(plan.root)
    eph = default_ephemeris()
    t = plan.t_tdb_s
    dyn = dynamics.bind(eph, t[0] - 86400.0, t[-1] + 86400.0)
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
        ps = PredictedState(position_km=mean[:3], velocity_km_s=mean[3:6],
                            position_cov_km2=kf.P[:, :3, :3].mean(0) + spread)
        fr = process_frame(obs, catalog=cat, predicted_state=ps, previous_attitude=prev)
        prev = fr.attitude.R_cam_icrs
        status.append(fr.status)
        b = _target_beacon(fr, plan.target[i])
        c2 = time.perf_counter()
        if b is not None:
            rp, vp = eph.position_velocity(plan.target[i], t[i])
            z = np.broadcast_to(np.asarray(b.xy_px, dtype=float), (n_runs, 2))
            u = kf.update(z, rp, vp, fr.attitude.R_cam_icrs, obs.camera, sigma_px)
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
                 sigma_px: float, dynamics: FilterDynamics | None = None, progress=None) -> CampaignResult:
    """Monte Carlo EKF runs along the plan (paper 002 Eq. 45-46 initial errors, 001 Table 2 sigmas).

    ``progress``: a callable ``progress(n_frames_done)`` (in-process only) or None.
    """
    if case not in CASES:
        raise NavInputError(f"--case {case}: give 1, 2, 3, 4 or 5")
    if runs < 2:
        raise NavInputError(f"--runs {runs}: at least 2 runs are needed for sample statistics")
    dynamics = dynamics or FilterDynamics()
    P0 = initial_covariance(sigma_residual_km_s2=dynamics.sigma_residual_km_s2,
                            sigma_srp_km_s2=dynamics.sigma_srp_km_s2)
    rng = np.random.default_rng(np.random.SeedSequence([seed, 45]))
    nominal = np.concatenate([plan.position_km[0], plan.velocity_km_s[0], np.zeros(6)])
    x0 = nominal + rng.standard_normal((runs, 12)) * np.sqrt(np.diag(P0))   # paper 002 Eq. 45
    workers = max(1, min(int(workers), runs))
    chunks = np.array_split(np.arange(runs), workers)
    if workers == 1:
        outs = [_run_chunk(plan, x0, P0, case, sigma_px, dynamics, progress)]
    else:
        with ProcessPoolExecutor(workers) as ex:
            outs = list(ex.map(_chunk_worker, [(plan, x0[c], P0, case, sigma_px, dynamics, None) for c in chunks]))
    cat = lambda k: np.concatenate([o[k] for o in outs], 0)  # noqa: E731
    return CampaignResult(case=case, sigma_px=float(sigma_px), t_tdb_s=plan.t_tdb_s, error=cat("err"),
                          cov=cat("cov"), residual_px=cat("res"), accepted=cat("acc"), ip_status=outs[0]["status"],
                          measured_error_px=outs[0]["meas"], ip_time_s=max(o["ip_s"] for o in outs),
                          filter_time_s=max(o["fl_s"] for o in outs), pairs=outs[0]["pairs"])
