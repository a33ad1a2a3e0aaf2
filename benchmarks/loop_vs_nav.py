"""Closed loop against ``bench nav``: the distributions of their errors over independent renderings.

One ``bench loop`` run and one ``bench nav`` campaign each see ONE image sequence: their runs'
last-leg RMS error is close to one draw of the common error that sequence's centroid errors leave
(docs/navigation.md, "Filter consistency"), so one loop run against one nav campaign compares two
draws, not two filters. This script renders the same cruise with several master seeds (same
trajectory; other image noise, cosmic rays and pointing errors), runs the closed loop once per seed
(its own rendering through the service) and ``dataset generate`` + the nav campaign once per seed,
and prints per seed and as mean +- standard deviation: the RMS position error over the last leg,
the final position error and the filter's final 1-sigma (sqrt of trace of P's position block).

Both filters use the same measurement model: ``--sigma-px S`` for both, or by default the noise
calibration of ``bench nav`` (:func:`skynav.pipeline.scoring_nav.calibrate_sigma_px`), measured on
each seed's dataset for the nav campaign and through the service for the loop
(:func:`skynav.service.loop.calibrate_loop_noise`).

    python benchmarks/loop_vs_nav.py [--seeds 1 2 3 4] [--sigma-px S] [--set sequence.track_s=900 ...]
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np


def _recipe(sets, seed):
    from skynav import datasets
    from skynav.datasets.recipes import read_recipe_mapping
    from skynav.cli_common import apply_overrides, parse_set

    r = read_recipe_mapping("sequence")
    if sets:
        r = apply_overrides(r, [parse_set(s) for s in sets])
    r = datasets.validate_recipe(r)
    r["seed"] = int(seed)
    return r


def _stats(error, cov, last_leg):
    """Per run: (last-leg RMS position error km, final position error km, final filter 1-sigma km)."""
    e = np.asarray(error)[:, :, :3]
    rms = np.sqrt(np.mean(np.sum(e[:, last_leg] ** 2, -1), -1))
    fin = np.linalg.norm(e[:, -1], axis=-1)
    sig = np.sqrt(np.trace(np.asarray(cov)[:, -1, :3, :3], axis1=-2, axis2=-1))
    return rms, fin, sig


def loop_side(seeds, sets, sigma_px, runs_seed, renderings=1, stride=1, pointing="estimate"):
    from skynav.pipeline.ekf import initial_covariance
    from skynav.service import Client, LocalServer
    from skynav.service.loop import Simulator, calibrate_loop_noise, run_loop

    rows = []
    with LocalServer(workers=1) as url:
        client = Client(url)
        for s in seeds:
            t0 = time.perf_counter()
            sim = Simulator(_recipe(sets, s))
            P0 = initial_covariance()
            rng = np.random.default_rng(np.random.SeedSequence([runs_seed + s, 45]))
            r0, v0 = sim.state(sim.schedule()[0][0])
            x0 = np.concatenate([r0, v0, np.zeros(6)]) + rng.standard_normal(12) * np.sqrt(np.diag(P0))
            noise = sigma_px
            if noise is None:
                noise = calibrate_loop_noise(sim, client, seed=s, renderings=renderings, stride=stride)
            run = run_loop(sim, client, x0=x0, P0=P0, noise=noise, seed=runs_seed + s, pointing=pointing)
            last = np.array([lg for _, lg, _, _ in sim.schedule()]) == sim.schedule()[-1][1]
            rows.append((s, *[float(x[0]) for x in _stats(run.error[None], run.cov[None], last)],
                         time.perf_counter() - t0))
            print(f"  loop seed {s}: last-leg RMS {rows[-1][1]:.0f} km, final {rows[-1][2]:.0f} km, "
                  f"filter 1-sigma {rows[-1][3]:.0f} km ({rows[-1][4]:.0f} s)", flush=True)
    return rows


def nav_side(seeds, sets, sigma_px, runs_seed, workdir):
    from skynav.pipeline.scoring_nav import CentroidNoise, calibrate_sigma_px, load_plan, run_campaign

    rows = []
    for s in seeds:
        t0 = time.perf_counter()
        out = Path(workdir) / f"seq{s}"
        cmd = [sys.executable, "-m", "skynav", "dataset", "generate", "sequence", "-o", str(out), "--seed", str(s),
               "--workers", "1", "-q", "--set", "formats=[png, json]"]
        for x in sets:
            cmd += ["--set", x]
        subprocess.run(cmd, check=True)
        plan = load_plan(out)
        noise = CentroidNoise(sigma0_px=sigma_px) if sigma_px is not None else calibrate_sigma_px(plan, seed=s)
        res = run_campaign(plan, runs=1, seed=runs_seed + s, noise=noise)
        last = plan.leg == plan.leg[-1]
        rows.append((s, *[float(x[0]) for x in _stats(res.error, res.cov, last)], time.perf_counter() - t0))
        print(f"  nav  seed {s}: last-leg RMS {rows[-1][1]:.0f} km, final {rows[-1][2]:.0f} km, "
              f"filter 1-sigma {rows[-1][3]:.0f} km ({rows[-1][4]:.0f} s)", flush=True)
    return rows


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3, 4], help="master seeds (renderings)")
    ap.add_argument("--sigma-px", type=float, default=None, help="centroid sigma of both filters (default: calibrated)")
    ap.add_argument("--runs-seed", type=int, default=0, help="seed of the initial states and pointing errors")
    ap.add_argument("--calibration-renderings", type=int, default=1, help="loop: renderings R is pooled from")
    ap.add_argument("--calibration-stride", type=int, default=1, help="loop: every N-th frame of each")
    ap.add_argument("--pointing", default="estimate", choices=("estimate", "truth"),
                    help="loop: point from the estimate (closed loop) or from the truth (as a dataset)")
    ap.add_argument("--sides", nargs="+", default=["loop", "nav"], choices=("loop", "nav"))
    ap.add_argument("--set", dest="sets", action="append", default=[], metavar="KEY=VALUE", help="recipe overrides")
    args = ap.parse_args()
    import os

    print(f"loop against nav, sequence {' '.join(args.sets)}, seeds {args.seeds}, R: "
          f"{'%g px' % args.sigma_px if args.sigma_px else 'calibrated'}; load average {os.getloadavg()[0]:.1f}",
          flush=True)
    res = {}
    with tempfile.TemporaryDirectory() as d:
        if "loop" in args.sides:
            res["loop"] = loop_side(args.seeds, args.sets, args.sigma_px, args.runs_seed, args.calibration_renderings,
                                    args.calibration_stride, args.pointing)
        if "nav" in args.sides:
            res["nav"] = nav_side(args.seeds, args.sets, args.sigma_px, args.runs_seed, d)
    for name, rows in res.items():
        a = np.array([r[1:4] for r in rows])
        m, sd = a.mean(0), a.std(0, ddof=1) if len(a) > 1 else np.zeros(3)
        print(f"{name}: last-leg RMS {m[0]:.0f} +- {sd[0]:.0f} km, final error {m[1]:.0f} +- {sd[1]:.0f} km, "
              f"filter 1-sigma {m[2]:.0f} +- {sd[2]:.0f} km ({len(a)} renderings)")
    if len(res) == 2:
        a, b = (np.array([r[1:4] for r in res[k]]) for k in ("loop", "nav"))
        rms_a, rms_b = np.sqrt(np.mean(a[:, 0] ** 2)), np.sqrt(np.mean(b[:, 0] ** 2))
        print(f"loop / nav: last-leg RMS over the renderings {rms_a:.0f} / {rms_b:.0f} km = {rms_a / rms_b:.2f}; "
              f"filter 1-sigma {a[:, 2].mean() / b[:, 2].mean():.2f}")


if __name__ == "__main__":
    main()
