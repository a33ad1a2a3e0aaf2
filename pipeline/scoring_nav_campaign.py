"""The navigation campaign: Monte Carlo EKF runs along a ``sequence`` dataset (``skynav bench nav``).

Scoring module. The filter (:mod:`skynav.pipeline.ekf`) sees the images through
:func:`skynav.pipeline.process_frame` (attitude and planet centroid), the calibrated camera, the
on-board DE421 and the commanded pointing plan, never the truth; the truth gives the initial
states (Andreis et al. (2024), Eq. 45-46) and the scores. The image processing runs once per frame for all the
runs of a worker (the predicted state it gets is the runs' mean, with the runs' mean covariance
plus their spread); with ``workers > 1`` the runs are split into chunks over the house's process
pool (:func:`skynav.infra.pool.process_pool_map`) and every worker processes the frames once
for its chunk.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

import skynav.datasets as sdat
from skynav.infra.pool import process_pool_map
from skynav.scenes.constants import SECONDS_PER_DAY
from skynav.scenes.ephemeris_jpl import BODY_RADII_KM, default_ephemeris

from .catalog import OnboardCatalog
from .ekf import NavFilter, initial_covariance
from .filter_dynamics import FilterDynamics
from .measurement import CASES, planet_pixel
from .pairs import candidates_from_state, optimal_pair
from .process import process_frame
from .results import PredictedState
from .scoring_nav_noise import CentroidNoise, centroid_usable, diameter_px, target_beacon
from .scoring_nav_plan import NavInputError, NavPlan, observation

__all__ = ["UPDATE_ITERATIONS", "CampaignResult", "ChunkResult", "run_campaign", "run_realisations",
           "check_realisations"]


#: Iterated EKF update in the campaign: after the first 10-day propagation the position is known to
#: ~1e5 km only and the first Earth fix is nonlinear over that spread; with the one-step EKF 2 of 6
#: runs (seed 3, synthetic centroids) were left 4 sigma off and then gated out every later
#: measurement (final error 4e6 km); 3 iterations keep them all (tests/pipeline/test_ekf_iterated.py).
UPDATE_ITERATIONS = 3

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


@dataclass(frozen=True, kw_only=True, eq=False)
class ChunkResult:
    """One worker's share of a campaign: the fields of :class:`CampaignResult` for its runs."""

    error: np.ndarray
    cov: np.ndarray
    residual_px: np.ndarray
    accepted: np.ndarray
    measured_error_px: np.ndarray
    ip_status: tuple
    ip_time_s: float
    filter_time_s: float
    pairs: tuple


def _run_chunk(plan: NavPlan, x0, P0, case: int, noise: CentroidNoise, dynamics: FilterDynamics, phase_offset: bool,
               progress_q=None, synthetic_seed=None):
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
        obs = observation(ds, plan, i)
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
        b = target_beacon(fr, plan.target[i])
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
    return ChunkResult(error=err, cov=cov, residual_px=res, accepted=acc, measured_error_px=meas,
                       ip_status=tuple(status), ip_time_s=ip_s, filter_time_s=fl_s, pairs=tuple(pairs))


def _chunk_worker(args):
    return _run_chunk(*args)


def run_campaign(plan: NavPlan, *, runs: int = 50, case: int = 1, seed: int = 0, workers: int = 1,
                 noise: CentroidNoise, dynamics: FilterDynamics | None = None, phase_offset: bool = True,
                 progress=None, synthetic_seed: int | None = None) -> CampaignResult:
    """Monte Carlo EKF runs along the plan (Andreis et al. (2024), Eq. 45-46 initial errors; Andreis et al. (2023b), Table 2 sigmas).

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
    P0 = initial_covariance()   # Andreis et al. (2023b), Table 2
    rng = np.random.default_rng(np.random.SeedSequence([seed, 45]))
    nominal = np.concatenate([plan.position_km[0], plan.velocity_km_s[0], np.zeros(6)])
    x0 = nominal + rng.standard_normal((runs, 12)) * np.sqrt(np.diag(P0))   # Andreis et al. (2024), Eq. 45
    workers = max(1, min(int(workers), runs))
    chunks = np.array_split(np.arange(runs), workers)
    if workers == 1:
        outs = [_run_chunk(plan, x0, P0, case, noise, dynamics, phase_offset, progress, synthetic_seed)]
    else:
        outs = process_pool_map(_chunk_worker, [(plan, x0[c], P0, case, noise, dynamics, phase_offset, None,
                                                 synthetic_seed) for c in chunks], workers)
    cat = lambda k: np.concatenate([getattr(o, k) for o in outs], 0)  # noqa: E731
    return CampaignResult(case=case, noise=noise, t_tdb_s=plan.t_tdb_s, error=cat("error"),
                          cov=cat("cov"), residual_px=cat("residual_px"), accepted=cat("accepted"),
                          ip_status=outs[0].ip_status, measured_error_px=outs[0].measured_error_px,
                          ip_time_s=max(o.ip_time_s for o in outs), filter_time_s=max(o.filter_time_s for o in outs),
                          pairs=outs[0].pairs)


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
        outs = process_pool_map(_realisation_worker, jobs, min(workers, len(jobs)),
                                accept=None if progress is None else (lambda _: progress(1)))
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
