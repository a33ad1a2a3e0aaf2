"""How far a CONSISTENT filter's campaign NEES falls from the 95 % band when all runs share one
image sequence (issue 14's consistency criterion, read against its reference).

Usage::

    python benchmarks/nav_consistency.py DATASET [--seeds 10] [--runs 6] [--case 1]

Runs the campaign once on the dataset's images, then ``--seeds`` times with synthetic centroids
(:func:`skynav.pipeline.scoring_nav.run_campaign` ``synthetic_seed``: the measurement model at the
true state plus white noise of exactly the filter's measured R), and prints for each the
time-averaged NEES over the frames, the share of frames inside the band, and the final sample
and filter 3-sigma. The runs differ only in their initial errors, so their mean NEES is close to
one chi-square draw per frame, not to an average of independent runs: the band
``chi2.ppf([0.025, 0.975], 6 R) / R`` is the one for independent runs. About 30 s per campaign
of 6 runs over 720 frames (the image processing dominates).
"""

import argparse

import numpy as np
from scipy.stats import chi2

from skynav.pipeline.scoring_nav import calibrate_sigma_px, load_plan, run_campaign


def _stats(r):
    e, P = r.error, r.cov
    nees = np.einsum("rfi,rfi->rf", e, np.linalg.solve(P, e[..., None])[..., 0]).mean(0)
    R = e.shape[0]
    lo, hi = chi2.ppf([0.025, 0.975], 6 * R) / R
    s3 = 3 * np.sqrt(np.mean(np.sum(e[:, -1, :3] ** 2, 1)))
    f3 = 3 * np.sqrt(np.mean(np.trace(P[:, -1, :3, :3], axis1=1, axis2=2)))
    return nees.mean(), np.mean((nees >= lo) & (nees <= hi)), s3, f3, lo, hi


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("dataset")
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--runs", type=int, default=6)
    ap.add_argument("--case", type=int, default=1)
    a = ap.parse_args()
    plan = load_plan(a.dataset)
    noise = calibrate_sigma_px(plan)
    print(f"R: {noise.describe()}")
    rows = []
    for seed in [None] + list(range(1, a.seeds + 1)):
        r = run_campaign(plan, runs=a.runs, case=a.case, noise=noise, seed=0 if seed is None else seed,
                         synthetic_seed=seed)
        m, inside, s3, f3, lo, hi = _stats(r)
        rows.append(m)
        name = "images" if seed is None else f"synthetic {seed}"
        print(f"{name:>13}: mean NEES {m:6.2f} (band {lo:.2f}..{hi:.2f}), {100 * inside:4.0f} % of frames inside; "
              f"final 3-sigma sample {s3:6.0f} km, filter {f3:6.0f} km", flush=True)
    syn = np.array(rows[1:])
    if syn.size:
        print(f"synthetic: mean NEES median {np.median(syn):.2f}, range {syn.min():.2f}..{syn.max():.2f}; "
              f"images {rows[0]:.2f} is above {np.mean(syn < rows[0]) * 100:.0f} % of them")


if __name__ == "__main__":
    main()
