"""The plug-in layer of ``bench ip``: the same results as the pipeline called directly, and its cost.

Usage::

    nice -n 10 python benchmarks/plugin_overhead.py DATASET [--frames 200] [--modes paper improved]

For every frame and every predicted-position sigma of ``bench ip`` (the same predicted-state
draws), skynav's pipeline is called twice, in alternating order: directly
(:func:`skynav.pipeline.process_frame`) and through the plug-in door (``--pipeline skynav-<mode>``:
:func:`skynav.pipeline.plugins.call_processor` on :class:`~skynav.pipeline.plugins.SkynavProcessor`,
with the frame time limit's alarm, the result's checks and its conversion to an ``ImageResult``).

Prints, per mode: the runs whose results differ (attitude matrix, status, centroids, matched
stars, beacons; and the scores ``bench ip`` computes from them), which must be 0; the total time of
each path and their ratio (both in the same process, interleaved, so a job on the other core slows
both alike); and the layer's own cost, timed apart on a processor that returns a finished result
(what the door adds to a call, without the pipeline's noise), as a share of the median direct run.
"""

from __future__ import annotations

import argparse
import os
import time

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import numpy as np  # noqa: E402


def _same(fr, res) -> bool:
    """The plug-in's ImageResult carries the FrameResult's figures, bit for bit."""
    R1, R2 = fr.attitude.R_cam_icrs, res.R_cam_icrs
    same_R = (R1 is None and R2 is None) or (R1 is not None and R2 is not None and np.array_equal(R1, R2))
    beacons = [(b.name, None if b.xy_px is None else tuple(b.xy_px), b.status) for b in fr.beacons]
    theirs = [(b.name, None if b.xy_px is None else tuple(b.xy_px), b.status) for b in res.beacons]
    return bool(same_R and fr.status == res.status and np.array_equal(fr.centroids_xy_px, res.centroids_xy_px)
                and np.array_equal(fr.matched_star_ids, res.matched_star_ids) and beacons == theirs
                and fr.star_id_method == res.method)


def _score_key(row):
    def f(x):  # nan == nan (no attitude, no beacon error) for the comparison
        return None if x != x else x

    return (row.status, row.attitude, f(row.error_arcsec), row.n_stars, row.n_spots, row.method,
            tuple((b.name, b.outcome, f(b.error_px)) for b in row.beacons))


def layer_cost_us(obs, ps, result, repeat=2000) -> float:
    """Median microseconds :func:`call_processor` adds to a call (a processor returning ``result``)."""
    from skynav.pipeline.plugins import call_processor

    class Done:
        def process(self, observation, prediction):
            return result

    proc = Done()
    t = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        call_processor(proc, obs, ps, timeout_s=60.0)
        t.append(time.perf_counter() - t0)
    t_bare = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        proc.process(obs, ps)
        t_bare.append(time.perf_counter() - t0)
    return (float(np.median(t)) - float(np.median(t_bare))) * 1e6


def run_mode(src, cat, mode, sigmas, n, seed):
    from skynav.pipeline import process_frame
    from skynav.pipeline.plugins import SkynavProcessor, call_processor, image_result
    from skynav.pipeline.scoring import predicted_state, score_frame

    proc = SkynavProcessor(src.observation(0).camera, mode=mode, catalog=cat)
    t_direct = t_plugin = 0.0
    direct_ms, differ, runs = [], 0, 0
    conv = []
    for k in range(n):
        obs, truth = src.observation(k), src.truth(k)
        for i, s in enumerate(sigmas):
            ps = predicted_state(truth, s, np.random.default_rng(np.random.SeedSequence([seed, k, i])))
            for first in ((0, 1) if (k + i) % 2 == 0 else (1, 0)):
                t0 = time.perf_counter()
                if first == 0:
                    fr = process_frame(obs, catalog=cat, predicted_state=ps, mode=mode)
                    dt = time.perf_counter() - t0
                    t_direct += dt
                    direct_ms.append(dt * 1e3)
                else:
                    res, fault, _ = call_processor(proc, obs, ps, timeout_s=60.0)
                    t_plugin += time.perf_counter() - t0
            t0 = time.perf_counter()
            image_result(fr)
            conv.append(time.perf_counter() - t0)
            runs += 1
            a = score_frame(image_result(fr), truth, frame=k, sigma_km=s)
            b = score_frame(res, truth, frame=k, sigma_km=s) if fault is None else None
            if fault is not None or not _same(fr, res) or _score_key(a) != _score_key(b):
                differ += 1
    return {"runs": runs, "differ": differ, "direct_s": t_direct, "plugin_s": t_plugin,
            "median_direct_ms": float(np.median(direct_ms)), "last": (obs, ps, res),
            "convert_us": float(np.median(conv)) * 1e6}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("dataset")
    ap.add_argument("--frames", type=int, default=200)
    ap.add_argument("--modes", nargs="+", default=["paper", "improved"], choices=("paper", "improved"))
    ap.add_argument("--sigmas", type=float, nargs="+", default=[1e4, 1e5, 1e6, 1e7])
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)

    from skynav.pipeline import OnboardCatalog
    from skynav.pipeline.scoring import open_frames

    src = open_frames(args.dataset)
    n = min(args.frames, len(src))
    cat = OnboardCatalog.load(camera=src.observation(0).camera)
    print(f"{args.dataset}: {n} frames x {len(args.sigmas)} sigmas, seed {args.seed}")
    print("| mode | runs | results that differ | direct s | plug-in s | plug-in / direct | layer us per call "
          "| layer % of a median run |")
    print("|---|---|---|---|---|---|---|---|")
    for mode in args.modes:
        r = run_mode(src, cat, mode, args.sigmas, n, args.seed)
        obs, ps, res = r["last"]
        layer = layer_cost_us(obs, ps, res) + r["convert_us"]
        print(f"| {mode} | {r['runs']} | {r['differ']} | {r['direct_s']:.1f} | {r['plugin_s']:.1f} | "
              f"{r['plugin_s'] / r['direct_s']:.4f} | {layer:.1f} | {100 * layer / (r['median_direct_ms'] * 1e3):.3f} |",
              flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
