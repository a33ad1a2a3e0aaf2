"""The navigation campaign: Monte Carlo EKF runs along a ``sequence`` dataset (``skynav bench nav``).

Scoring module. The filter (anyone's; skynav's EKF by default) sees the images through an image
processor (skynav's pipeline by default: attitude and planet centroid), the calibrated camera, the
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
from skynav.scenes.ephemeris_jpl import BODY_RADII_KM, default_ephemeris

from .filter_dynamics import FilterDynamics
from .flight import DEFAULT_FILTER, DEFAULT_PIPELINE, UPDATE_ITERATIONS, FlightComputer, initial_states, make_filter
from .measurement import CASES, planet_pixel
from .planet_centroid import CentroidNoise
from .protocols import FilterSetup
from .scoring_nav_plan import NavInputError, NavPlan, observation

__all__ = ["UPDATE_ITERATIONS", "CampaignResult", "ChunkResult", "run_campaign", "run_realisations",
           "check_realisations"]


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
    faults: tuple = ()           # (R,) per run, (F,) per frame: the filter's fault in that step ("" none)
    filter_name: str = DEFAULT_FILTER   # the filter, MODULE:FACTORY
    measured: np.ndarray | None = None  # (R, F) bool: the run's filter was given the frame's centroid


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
    faults: tuple = ()
    measured: np.ndarray | None = None


def _run_chunk(plan: NavPlan, x0, P0, case: int, noise: CentroidNoise, dynamics: FilterDynamics, phase_offset: bool,
               progress_q=None, synthetic_seed=None, filter_spec: str = DEFAULT_FILTER, pipeline: str = DEFAULT_PIPELINE,
               frame_timeout_s: float | None = None):
    ds = sdat.open(plan.root)
    eph = default_ephemeris()
    t = plan.t_tdb_s
    setup = FilterSetup(ephemeris=eph, t_start_tdb_s=float(t[0]), t_end_tdb_s=float(t[-1]), case=case, dynamics=dynamics)
    n_runs, F = len(x0), plan.frames
    err = np.full((n_runs, F, 6), np.nan)
    cov = np.full((n_runs, F, 6, 6), np.nan)
    res = np.full((n_runs, F, 2), np.nan)
    acc = np.zeros((n_runs, F), dtype=bool)
    given = np.zeros(F, dtype=bool)
    meas = np.full((F, 2), np.nan)
    faults = [[""] * F for _ in range(n_runs)]
    status = []
    track_frames = {}   # frames per (leg, phase): the commanded observation plan
    for lg, ph in zip(plan.leg, plan.phase):
        track_frames[(int(lg), ph)] = track_frames.get((int(lg), ph), 0) + 1
    fc = FlightComputer(make_filter(filter_spec, setup), noise=noise, ephemeris=eph,
                        track_frames=track_frames, phase_offset=phase_offset, pipeline=pipeline,
                        frame_timeout_s=frame_timeout_s)
    fc.start(t[0], x0, P0)
    pairs = []
    read_s = 0.0
    for i in range(F):
        fc.propagate(t[i])
        if i == 0 or plan.leg[i] != plan.leg[i - 1]:
            lg = int(plan.leg[i])
            plan_pair = plan.plan_pairs[lg] if lg < len(plan.plan_pairs) else ("", "")
            pairs.append((lg, tuple(plan_pair), fc.choose_pair(t[i])))
        c0 = time.perf_counter()
        obs = observation(ds, plan, i)
        read_s += time.perf_counter() - c0
        step = fc.step(obs, plan.target[i], track=(int(plan.leg[i]), plan.phase[i]),
                       replace_xy=None if synthetic_seed is None else _synthetic(plan, i, eph, phase_offset, synthetic_seed))
        status.append(step.status)
        if step.measurement is not None:
            res[:, i], acc[:, i], given[i] = step.residual_px, step.accepted, True
        if step.xy_px is not None:
            meas[i] = step.xy_px - plan.target_xy_px[i]
        x, P, _ = fc.estimate()
        truth = np.concatenate([plan.position_km[i], plan.velocity_km_s[i]])
        err[:, i] = x[:, :6] - truth
        cov[:, i] = P[:, :6, :6]
        for r in np.flatnonzero(step.failed):
            faults[r][i] = step.fault
        if progress_q is not None:
            progress_q(1)
    return ChunkResult(error=err, cov=cov, residual_px=res, accepted=acc, measured_error_px=meas,
                       ip_status=tuple(status), ip_time_s=fc.ip_time_s + read_s, filter_time_s=fc.filter_time_s,
                       pairs=tuple(pairs), faults=tuple(tuple(f) for f in faults),
                       measured=np.broadcast_to(given, (n_runs, F)).copy())


def _synthetic(plan, i, eph, phase_offset, synthetic_seed):
    """Reference mode: the exact model (case 1, this photocentre law) at the TRUE state plus white
    noise of exactly the filter's R; the same draw in every worker."""
    def replace_xy(obs, result, use, sigma_px):
        t = plan.t_tdb_s[i]
        rp, vp = eph.position_velocity(plan.target[i], t)
        radius = BODY_RADII_KM[plan.target[i]]
        m_true = planet_pixel(plan.position_km[i], plan.velocity_km_s[i], rp, vp, result.R_cam_icrs,
                              obs.camera, corrections=CASES[1], sun_position_km=eph.position("sun", t),
                              planet_radius_km=radius if phase_offset else 0.0, photocentre=use)
        g = np.random.default_rng(np.random.SeedSequence([int(synthetic_seed), 0x5E, i]))
        return m_true.xy_px + sigma_px * g.standard_normal(2)
    return replace_xy


def _chunk_worker(args):
    return _run_chunk(*args)


def run_campaign(plan: NavPlan, *, runs: int = 50, case: int = 1, seed: int = 0, workers: int = 1,
                 noise: CentroidNoise, dynamics: FilterDynamics | None = None, phase_offset: bool = True,
                 progress=None, synthetic_seed: int | None = None, filter_spec: str = DEFAULT_FILTER,
                 pipeline: str = DEFAULT_PIPELINE, frame_timeout_s: float | None = None) -> CampaignResult:
    """Monte Carlo EKF runs along the plan (Andreis et al. (2024), Eq. 45-46 initial errors; Andreis et al. (2023b), Table 2 sigmas).

    ``progress``: a callable ``progress(n_frames_done)`` (in-process only) or None.
    ``synthetic_seed``: reference mode; every centroid the filter would use is replaced by the
    measurement model at the true state plus white noise of the filter's own R (seeded): what a
    consistent filter shows on ONE realisation shared by the runs (``benchmarks/nav_consistency.py``).
    ``filter_spec``: the navigation filter, ``MODULE:FACTORY`` (:mod:`skynav.pipeline.flight`).
    ``pipeline``: the image processor, ``MODULE:FACTORY`` (one per worker); ``frame_timeout_s``: its
    time limit per frame (None: none), a frame past it a failed measurement.
    """
    if case not in CASES:
        raise NavInputError(f"--case {case}: give 1, 2, 3, 4 or 5")
    if runs < 1:
        raise NavInputError(f"--runs {runs}: give at least 1 run")
    dynamics = dynamics or FilterDynamics()
    x0, P0 = initial_states(plan.position_km[0], plan.velocity_km_s[0], runs, seed)
    workers = max(1, min(int(workers), runs))
    chunks = np.array_split(np.arange(runs), workers)
    if workers == 1:
        outs = [_run_chunk(plan, x0, P0, case, noise, dynamics, phase_offset, progress, synthetic_seed, filter_spec,
                           pipeline, frame_timeout_s)]
    else:
        outs = process_pool_map(_chunk_worker, [(plan, x0[c], P0, case, noise, dynamics, phase_offset, None,
                                                 synthetic_seed, filter_spec, pipeline, frame_timeout_s)
                                                for c in chunks], workers)
    cat = lambda k: np.concatenate([getattr(o, k) for o in outs], 0)  # noqa: E731
    return CampaignResult(case=case, noise=noise, t_tdb_s=plan.t_tdb_s, error=cat("error"),
                          cov=cat("cov"), residual_px=cat("residual_px"), accepted=cat("accepted"),
                          ip_status=outs[0].ip_status, measured_error_px=outs[0].measured_error_px,
                          ip_time_s=max(o.ip_time_s for o in outs), filter_time_s=max(o.filter_time_s for o in outs),
                          pairs=outs[0].pairs, faults=sum((o.faults for o in outs), ()), filter_name=filter_spec,
                          measured=cat("measured"))


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
                     reference: NavPlan | None = None, filter_spec: str = DEFAULT_FILTER,
                     pipeline: str = DEFAULT_PIPELINE, frame_timeout_s: float | None = None) -> CampaignResult:
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
                     noise=noise, dynamics=dynamics, phase_offset=phase_offset, filter_spec=filter_spec,
                     pipeline=pipeline, frame_timeout_s=frame_timeout_s))
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
                          sequences=len(outs), faults=sum((o.faults for o in outs), ()), filter_name=filter_spec,
                          measured=cat("measured"))
