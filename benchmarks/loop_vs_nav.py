"""Closed loop against ``bench nav``, paired: both filters on the same images, over several renderings.

One ``bench loop`` run and one ``bench nav`` campaign each see ONE image sequence, and their
errors are mostly that sequence's draw of the error its centroid errors leave (docs/navigation.md,
"Filter consistency"): one rendering's last-leg RMS over another's is 0.44-4.7 in 90 % of pairs, so
two filters on two renderings compare two draws, not two filters. Here they see the SAME images:
per master seed (``--seeds``), the closed loop runs through the render service (its measurement
noise R calibrated out of sample, :func:`skynav.service.loop.calibrate_loop_noise`), its frames are
kept, and ``bench nav``'s campaign (:func:`skynav.pipeline.scoring_nav.run_campaign`, one run,
the same initial-error draw) navigates those frames (``--images``) with three measurement models:

- ``nav, loop's R``: the loop's own R (the same object): everything equal but the code path;
- ``nav, R out of sample``: R calibrated by ``bench nav``'s function on ANOTHER seed's frames
  (the previous seed, cyclically): an out-of-sample calibration like the loop's;
- ``nav, R in sample``: R calibrated on the navigated frames themselves: ``bench nav``'s default.

The per-rendering draw then cancels in the paired ratios (loop / nav per seed) and in the ratio of
the RMS over seeds, which are printed with 90 % bootstrap intervals over the seeds (resampled
jointly). ``--pointing-check`` also runs the loop pointed from the truth (the images a dataset
would have: same seeds, same controller errors) to show what closing the loop costs.

``--own-rendering`` also runs the unpaired design, ``bench loop`` against ``bench nav`` each as a
user runs them: nav on its own ``dataset generate`` rendering of each seed (R in sample). The loop
draws the controller's pointing errors of that dataset frame by frame
(:meth:`skynav.service.loop.Simulator.scene`), so the two see the same cruise; they differ in
where the closed loop points (its estimate, not the truth) and in the image noise (the service's
``render.seed`` against the dataset's stream). It compares, class by class, the measurement noise
calibrated on the two renderings and, frame by frame, the centroid errors on the dataset's frames
against those on the loop's. ``--other-draw`` also runs the loop on another draw of the
controller's errors and image noise (rendering 1): with ``--own-rendering``, the former unpaired
design, two different cruises (the planet's pixel phase sets most of the centroid error).

Printed per seed and over seeds: the RMS position error over the last leg, the final position
error (3 x its RMS over the seeds: the final sample 3-sigma of ``bench nav``'s report) and the
filter's final 3-sigma (3 sqrt of the trace of P's position block).

    python benchmarks/loop_vs_nav.py [--seeds 1 2 3 4] [--set sequence.track_s=900 ...] [--pointing-check]
        [--own-rendering [--other-draw]]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np


def _recipe(sets, seed):
    from skynav import datasets
    from skynav.datasets.recipes import read_recipe_mapping
    from skynav.scenes.overrides import apply_overrides, keep_field_of_view, parse_override

    r = read_recipe_mapping("sequence")
    if sets:
        overrides = [parse_override(s) for s in sets]
        before, r = r, apply_overrides(r, overrides)
        keep_field_of_view(before, r, overrides)  # as skynav bench loop --set
    r = datasets.validate_recipe(r)
    r["seed"] = int(seed)
    return r


def _stats(error, cov, last_leg):
    """One run: (last-leg RMS position error km, final position error km, final filter 1-sigma km)."""
    e = np.asarray(error)[..., :3].reshape(-1, 3)
    rms = float(np.sqrt(np.mean(np.sum(e[last_leg] ** 2, -1))))
    fin = float(np.linalg.norm(e[-1]))
    sig = float(np.sqrt(np.trace(np.asarray(cov).reshape(-1, 6, 6)[-1, :3, :3])))
    return rms, fin, sig


class _Keeping:
    """A client that keeps every PNG it receives as ``folder/NNNNNN.png`` (frame order)."""

    def __init__(self, client, folder):
        self.client, self.folder, self.k = client, Path(folder), 0
        self.folder.mkdir(parents=True, exist_ok=True)

    def render(self, mapping, outputs):
        frame = self.client.render(mapping, outputs=outputs)
        (self.folder / f"{self.k:06d}.png").write_bytes(frame.png)
        self.k += 1
        return frame


def _generate(out, seed, sets):
    cmd = [sys.executable, "-m", "skynav", "dataset", "generate", "sequence", "-o", str(out), "--seed", str(seed),
           "--workers", "1", "-q", "--set", "formats=[png, json]"]
    for x in sets:
        cmd += ["--set", x]
    subprocess.run(cmd, check=True)


def loop_side(seeds, sets, runs_seed, workdir, pointing_check, other_draw=False):
    """Per seed: the loop's R, its closed-loop run (frames kept) and, if asked, the run pointed from
    the truth and the run on another draw of the controller's errors (rendering 1)."""
    from skynav.pipeline.ekf import initial_covariance
    from skynav.service import Client, LocalServer
    from skynav.service.loop import Simulator, calibrate_loop_noise, run_loop

    out = {}
    with LocalServer(workers=1) as url:
        client = Client(url)
        for s in seeds:
            t0 = time.perf_counter()
            sim = Simulator(_recipe(sets, s))
            P0 = initial_covariance()
            rng = np.random.default_rng(np.random.SeedSequence([runs_seed + s, 45]))   # as run_campaign's runs
            r0, v0 = sim.state(sim.schedule()[0][0])
            x0 = np.concatenate([r0, v0, np.zeros(6)]) + rng.standard_normal(12) * np.sqrt(np.diag(P0))
            noise = calibrate_loop_noise(sim, client, seed=s)
            t1 = time.perf_counter()
            kept = _Keeping(client, Path(workdir) / f"loop{s}")
            run = run_loop(sim, kept, x0=x0, P0=P0, noise=noise)
            last = np.array([lg for _, lg, _, _ in sim.schedule()]) == sim.schedule()[-1][1]
            rec = {"noise": noise, "images": kept.folder, "loop": _stats(run.error, run.cov, last),
                   "in_field": float(run.in_field.mean())}
            t2 = time.perf_counter()
            if pointing_check:
                tr = run_loop(sim, client, x0=x0, P0=P0, noise=noise, pointing="truth")
                rec["loop, pointed from the truth"] = _stats(tr.error, tr.cov, last)
            if other_draw:
                other = _Keeping(client, Path(workdir) / f"other{s}")
                od = run_loop(sim, other, x0=x0, P0=P0, noise=noise, rendering=1)
                rec["loop, another draw"] = _stats(od.error, od.cov, last)
                rec["images, another draw"] = other.folder
            out[s] = rec
            print(f"  loop seed {s}: last-leg RMS {rec['loop'][0]:.0f} km, final {rec['loop'][1]:.0f} km, filter "
                  f"1-sigma {rec['loop'][2]:.0f} km; target in the field {100 * rec['in_field']:.0f} % (calibration "
                  f"{t1 - t0:.0f} s, loop {t2 - t1:.0f} s)", flush=True)
    return out


def nav_side_paired(seeds, sets, runs_seed, workdir, loop):
    """bench nav's campaign on each seed's closed-loop frames, with the loop's R, R out of sample, R in sample."""
    from skynav.pipeline.scoring_nav import calibrate_sigma_px, load_plan, run_campaign

    base = Path(workdir) / "truth"   # the cruise's truth (positions, legs, targets); its own images unused
    _generate(base, 0, sets)
    plans = {s: load_plan(base, images=loop[s]["images"]) for s in seeds}
    t0 = time.perf_counter()
    own = {s: calibrate_sigma_px(plans[s], seed=s) for s in seeds}   # bench nav's default: on the navigated frames
    for s in seeds:
        loop[s]["R, loop frames"] = own[s]
    print(f"  nav: R calibrated in sample on each seed's frames ({time.perf_counter() - t0:.0f} s)", flush=True)
    for i, s in enumerate(seeds):
        other = seeds[i - 1] if len(seeds) > 1 else None
        last = plans[s].leg == plans[s].leg[-1]
        for name, noise in (("nav, loop's R", loop[s]["noise"]),
                            ("nav, R out of sample", None if other is None else own[other]),
                            ("nav, R in sample", own[s])):
            if noise is None:
                continue
            t0 = time.perf_counter()
            res = run_campaign(plans[s], runs=1, seed=runs_seed + s, noise=noise)
            loop[s][name] = _stats(res.error[0], res.cov[0], last)
            print(f"  {name} seed {s}: last-leg RMS {loop[s][name][0]:.0f} km, final {loop[s][name][1]:.0f} km, "
                  f"filter 1-sigma {loop[s][name][2]:.0f} km ({time.perf_counter() - t0:.0f} s)", flush=True)


def nav_side_own_rendering(seeds, sets, runs_seed, workdir, loop):
    """The unpaired design: bench nav on its own rendering of each seed (dataset generate), R in
    sample; and frame by frame, the centroid errors on the dataset's frames against those on the
    loop's (and the other draw's) frames."""
    from skynav.pipeline.scoring_nav import calibrate_sigma_px, load_plan, run_campaign
    from skynav.pipeline.scoring_nav_noise import centroid_errors

    for s in seeds:
        t0 = time.perf_counter()
        out = Path(workdir) / f"seq{s}"
        _generate(out, s, sets)
        plan = load_plan(out)
        loop[s]["R, dataset frames"] = noise = calibrate_sigma_px(plan, seed=s)
        res = run_campaign(plan, runs=1, seed=runs_seed + s, noise=noise)
        loop[s]["nav, own rendering, R in sample"] = v = _stats(res.error[0], res.cov[0], plan.leg == plan.leg[-1])
        print(f"  nav (own rendering) seed {s}: last-leg RMS {v[0]:.0f} km, final {v[1]:.0f} km, filter 1-sigma "
              f"{v[2]:.0f} km ({time.perf_counter() - t0:.0f} s)", flush=True)
        loop[s]["centroid errors, dataset frames"] = centroid_errors(plan, seed=s)
        for name, key in (("loop frames", "images"), ("another draw", "images, another draw")):
            if key in loop[s]:
                loop[s][f"centroid errors, {name}"] = centroid_errors(load_plan(out, images=loop[s][key]), seed=s)


def compare_centroids(records, seeds, a, b):
    """Per class of measurement, over the frames both use: the correlation of the centroid errors
    on frames ``a`` and ``b`` (both axes) and the RMS of their difference, px."""
    e = {}
    for s in seeds:
        if a in records[s] and b in records[s]:
            (ea, ka), (eb, kb) = records[s][a], records[s][b]
            for i, k in enumerate(ka):
                if k and k.split("/")[0] == kb[i].split("/")[0]:
                    e.setdefault(k.split("/")[0], []).append(np.concatenate([ea[i], eb[i]]))
    lines = [f"{a} / {b}, frame by frame (same frames, same predicted states):"] if e else []
    for k, v in sorted(e.items()):
        v = np.array(v)
        x, y = v[:, :2].ravel(), v[:, 2:].ravel()
        lines.append(f"  {k}: correlation {np.corrcoef(x, y)[0, 1]:.2f}, RMS of the difference "
                     f"{np.sqrt(np.mean((x - y) ** 2)):.3f} px, RMS {np.sqrt(np.mean(x**2)):.3f} / "
                     f"{np.sqrt(np.mean(y**2)):.3f} px ({len(v)} frames)")
    return lines


def compare_noise(records, seeds, a, b):
    """Per class of measurement: the mean over seeds of sigma and track bias calibrated on frames ``a`` and ``b``."""
    lines = [f"measurement noise calibrated on {a} / on {b}, per class (mean over seeds; px):"]
    cls = {}
    for s in seeds:
        for which in (a, b):
            if which in records[s]:
                for key, sig, n, sb in records[s][which].classes:
                    cls.setdefault(key, {a: [], b: []})[which].append((sig, sb, n))
    for key, v in sorted(cls.items()):
        if v[a] and v[b]:
            x, y = np.mean(v[a], 0), np.mean(v[b], 0)
            lines.append(f"  {key}: sigma {x[0]:.3f} / {y[0]:.3f}, track bias {x[1]:.3f} / {y[1]:.3f} "
                         f"({x[2]:.0f} / {y[2]:.0f} frames, {len(v[a])} / {len(v[b])} seeds)")
    return lines


#: the three figures compared, their index in a record and how they are pooled over seeds
FIGURES = (("last-leg RMS", 0, "rms"), ("final error, 3 x RMS", 1, "3rms"), ("filter final 3-sigma", 2, "3mean"))


def _pool(x, how):
    x = np.asarray(x, dtype=float)
    return {"rms": np.sqrt(np.mean(x**2, -1)), "3rms": 3 * np.sqrt(np.mean(x**2, -1)), "3mean": 3 * np.mean(x, -1)}[how]


def compare(records, seeds, a, b, n_boot=4000, rng=None):
    """Lines comparing columns ``a`` and ``b`` over the seeds that have both: the pooled ratio and its
    90 % bootstrap interval (seeds resampled jointly), the per-seed ratios' median and their correlation."""
    rng = rng or np.random.default_rng(0)
    s = [k for k in seeds if a in records[k] and b in records[k]]
    if not s:
        return []
    A = np.array([records[k][a] for k in s])
    B = np.array([records[k][b] for k in s])
    idx = rng.integers(0, len(s), (n_boot, len(s)))
    lines = []
    for name, j, how in FIGURES:
        ra, rb = _pool(A[:, j], how), _pool(B[:, j], how)
        boot = _pool(A[idx, j], how) / _pool(B[idx, j], how)
        lo, hi = np.percentile(boot, [5, 95])
        per = A[:, j] / B[:, j]
        corr = np.corrcoef(A[:, j], B[:, j])[0, 1] if len(s) > 2 else float("nan")
        lines.append(f"  {name}: {ra:.0f} / {rb:.0f} km = {ra / rb:.2f} (90 % bootstrap {lo:.2f}-{hi:.2f}); per seed "
                     f"median {np.median(per):.2f}, range {per.min():.2f}-{per.max():.2f}, correlation {corr:.2f}")
    return [f"{a} / {b} over {len(s)} seeds:"] + lines


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3, 4], help="master seeds (renderings)")
    ap.add_argument("--runs-seed", type=int, default=0, help="seed of the initial states and pointing errors")
    ap.add_argument("--own-rendering", action="store_true",
                    help="also run nav on its own dataset rendering of each seed (the unpaired design)")
    ap.add_argument("--pointing-check", action="store_true", help="also run the loop pointed from the truth")
    ap.add_argument("--other-draw", action="store_true",
                    help="also run the loop on another draw of the controller's pointing errors and image noise "
                         "(rendering 1; with --own-rendering: the unpaired design before the loop drew the dataset's)")
    ap.add_argument("--set", dest="sets", action="append", default=[], metavar="KEY=VALUE", help="recipe overrides")
    args = ap.parse_args()
    print(f"loop against nav, sequence {' '.join(args.sets)}, seeds {args.seeds}; "
          f"load average {os.getloadavg()[0]:.1f}", flush=True)
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as d:
        rec = loop_side(args.seeds, args.sets, args.runs_seed, d, args.pointing_check, args.other_draw)
        nav_side_paired(args.seeds, args.sets, args.runs_seed, d, rec)
        if args.own_rendering:
            nav_side_own_rendering(args.seeds, args.sets, args.runs_seed, d, rec)
    cols = [c for c in ("loop", "loop, pointed from the truth", "loop, another draw", "nav, loop's R",
                        "nav, R out of sample",
                        "nav, R in sample", "nav, own rendering, R in sample") if any(c in rec[s] for s in args.seeds)]
    print(f"over the seeds ({time.perf_counter() - t0:.0f} s; load average {os.getloadavg()[0]:.1f}):")
    for c in cols:
        a = np.array([rec[s][c] for s in args.seeds if c in rec[s]])
        print(f"  {c}: last-leg RMS {_pool(a[:, 0], 'rms'):.0f} km, final error 3 x RMS {_pool(a[:, 1], '3rms'):.0f} "
              f"km, filter final 3-sigma {_pool(a[:, 2], '3mean'):.0f} km ({len(a)} seeds)")
    for c in cols[1:]:
        for line in compare(rec, args.seeds, "loop", c):
            print(line)
    if "nav, R in sample" in cols:
        for c in ("nav, loop's R", "nav, R out of sample"):
            for line in compare(rec, args.seeds, c, "nav, R in sample"):
                print(line)
    if args.own_rendering:
        for a in ("nav, R in sample", "loop, another draw"):
            for line in compare(rec, args.seeds, a, "nav, own rendering, R in sample"):
                print(line)
        for line in compare_noise(rec, args.seeds, "R, loop frames", "R, dataset frames"):
            print(line)
        for name in ("loop frames", "another draw"):
            for line in compare_centroids(rec, args.seeds, "centroid errors, dataset frames",
                                          f"centroid errors, {name}"):
                print(line)


if __name__ == "__main__":
    main()
