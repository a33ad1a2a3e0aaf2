"""How far a CONSISTENT filter's campaign NEES falls from the 95 % band when all runs share one
image sequence (the consistency criterion, read against its reference).

Usage::

    python benchmarks/nav_consistency.py DATASET [--seeds 10] [--runs 6] [--case 1]
    python benchmarks/nav_consistency.py DATASET --realisations SEQ1 SEQ2 ... [--runs 5] [--case 1]

Runs the campaign once on the dataset's images, then ``--seeds`` times with synthetic centroids
(:func:`skynav.pipeline.scoring_nav.run_campaign` ``synthetic_seed``: the measurement model at the
true state plus white noise of exactly the filter's measured R), and prints for each the
time-averaged NEES over the frames, the share of frames inside the band, and the final sample
and filter 3-sigma. The runs differ only in their initial errors, so their mean NEES is close to
one chi-square draw per frame, not to an average of independent runs: the band
``chi2.ppf([0.025, 0.975], 6 R) / R`` is the one for independent runs. About 30 s per campaign
of 6 runs over 720 frames (the image processing dominates).

``--realisations``: the Monte Carlo that the consistency criterion asks for, with
independent measurement noise. Each SEQ is the same cruise rendered with another dataset seed
(``skynav dataset generate sequence -o SEQk --seed k``: other image noise, cosmic rays and
pointing jitter); the filter's R is calibrated once, on DATASET, not on the realisations (out of
sample); each realisation gets ``--runs`` runs with their own initial errors (002 Eq. 45-46). It
prints, per realisation and pooled over all of them: the time-averaged NEES with the 95 % band of
``M`` independent runs (M = realisations: the runs of one realisation share its images, so M, not
M x runs, is the conservative count) and the share of frames inside it, and the final sample
3-sigma ``3 sqrt(mean |e|^2)`` against the filter's ``3 sqrt(mean tr P)`` in position and velocity.
"""

import argparse

import numpy as np
from scipy.stats import chi2

from skynav.pipeline.filter_dynamics import FilterDynamics
from skynav.pipeline.scoring_nav import calibrate_sigma_px, load_plan, run_campaign


def _stats(r):
    e, P = r.error, r.cov
    nees = np.einsum("rfi,rfi->rf", e, np.linalg.solve(P, e[..., None])[..., 0]).mean(0)
    R = e.shape[0]
    lo, hi = chi2.ppf([0.025, 0.975], 6 * R) / R
    s3 = 3 * np.sqrt(np.mean(np.sum(e[:, -1, :3] ** 2, 1)))
    f3 = 3 * np.sqrt(np.mean(np.trace(P[:, -1, :3, :3], axis1=1, axis2=2)))
    return nees.mean(), np.mean((nees >= lo) & (nees <= hi)), s3, f3, lo, hi


def _pooled(results, label):
    """Pooled consistency statistics over independent realisations (``results``: CampaignResults)."""
    e = np.concatenate([r.error for r in results], 0)         # (M*R, F, 6)
    P = np.concatenate([r.cov for r in results], 0)
    M = len(results)
    nees_rf = np.einsum("rfi,rfi->rf", e, np.linalg.solve(P, e[..., None])[..., 0])
    anees = nees_rf.mean(0)                                       # (F,) average over the runs
    lo, hi = chi2.ppf([0.025, 0.975], 6 * M) / M
    out = {"realisations": M, "runs": e.shape[0], "mean_nees": float(anees.mean()), "band": (float(lo), float(hi)),
           "frames_inside": float(np.mean((anees >= lo) & (anees <= hi)))}
    for name, sl, unit in (("position", slice(0, 3), 1.0), ("velocity", slice(3, 6), 1e3)):
        s3 = 3 * unit * np.sqrt(np.mean(np.sum(e[:, -1, sl] ** 2, 1)))
        f3 = 3 * unit * np.sqrt(np.mean(np.trace(P[:, -1, sl, sl], axis1=1, axis2=2)))
        out[name] = (float(s3), float(f3), float(s3 / f3 - 1))
    print(f"{label}: {M} realisations x {e.shape[0] // M} runs; time-averaged NEES {out['mean_nees']:.2f} "
          f"(95 % band of {M} independent runs {lo:.2f}..{hi:.2f}; {100 * out['frames_inside']:.0f} % of frames inside)")
    for name, unit in (("position", "km"), ("velocity", "m/s")):
        s3, f3, d = out[name]
        print(f"  final {name} 3-sigma: sample {s3:.4g} {unit}, filter {f3:.4g} {unit}, sample/filter - 1 = {100 * d:+.1f} %")
    return out


def realisations(dataset, dirs, *, runs, case, dynamics=None):
    """The consistency criterion on independent image realisations (module docstring)."""
    import time

    ref = load_plan(dataset)
    noise = calibrate_sigma_px(ref)
    print(f"R (calibrated on {dataset}): {noise.describe()}", flush=True)
    results = []
    for k, d in enumerate(dirs):
        t0 = time.perf_counter()
        plan = load_plan(d)
        if plan.frames != ref.frames or not np.allclose(plan.position_km, ref.position_km, atol=1e-6):
            raise SystemExit(f"{d}: not a realisation of {dataset}'s cruise (other frames or trajectory)")
        r = run_campaign(plan, runs=runs, case=case, noise=noise, seed=1000 + k, dynamics=dynamics)
        results.append(r)
        e_last = r.error[:, -1]
        print(f"{d}: final |dr| {np.sqrt(np.mean(np.sum(e_last[:, :3] ** 2, 1))):7.0f} km, "
              f"|dv| {1e3 * np.sqrt(np.mean(np.sum(e_last[:, 3:] ** 2, 1))):6.3f} m/s (RMS over runs); "
              f"{time.perf_counter() - t0:.0f} s", flush=True)
    print()
    return _pooled(results, f"case {case}")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("dataset")
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--runs", type=int, default=6)
    ap.add_argument("--case", type=int, default=1)
    ap.add_argument("--realisations", nargs="+", metavar="SEQ",
                    help="other renderings of the same cruise (independent image noise): the pooled Monte Carlo")
    ap.add_argument("--gm-sigma", type=float, default=None,
                    help="steady-state sigma of each Gauss-Markov process, km/s^2 (default: the filter's)")
    a = ap.parse_args()
    dyn = None
    if a.gm_sigma is not None:
        dyn = FilterDynamics(sigma_residual_km_s2=a.gm_sigma, sigma_srp_km_s2=a.gm_sigma)
        print(f"GM steady-state sigma {a.gm_sigma:g} km/s^2 per process")
    if a.realisations:
        realisations(a.dataset, a.realisations, runs=a.runs, case=a.case, dynamics=dyn)
        return
    plan = load_plan(a.dataset)
    noise = calibrate_sigma_px(plan)
    print(f"R: {noise.describe()}")
    rows, synthetic = [], []
    for seed in [None] + list(range(1, a.seeds + 1)):
        r = run_campaign(plan, runs=a.runs, case=a.case, noise=noise, seed=0 if seed is None else seed,
                         synthetic_seed=seed, dynamics=dyn)
        m, inside, s3, f3, lo, hi = _stats(r)
        rows.append(m)
        if seed is not None:
            synthetic.append(r)
        name = "images" if seed is None else f"synthetic {seed}"
        print(f"{name:>13}: mean NEES {m:6.2f} (band {lo:.2f}..{hi:.2f}), {100 * inside:4.0f} % of frames inside; "
              f"final 3-sigma sample {s3:6.0f} km, filter {f3:6.0f} km", flush=True)
    syn = np.array(rows[1:])
    if syn.size:
        print(f"synthetic: mean NEES median {np.median(syn):.2f}, range {syn.min():.2f}..{syn.max():.2f}; "
              f"images {rows[0]:.2f} is above {np.mean(syn < rows[0]) * 100:.0f} % of them")
        _pooled(synthetic, "synthetic, pooled (independent noise per seed)")


if __name__ == "__main__":
    main()
