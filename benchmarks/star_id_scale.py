"""Lost-in-space star identification against the camera's pixel scale: where it stops being reliable.

For each camera (``--cameras WIDTHxFOV_DEG ...``, square), renders ``--frames`` frames of the
``montecarlo`` preset (random sky pointings along random cruise positions; the same draws for every
camera) and runs :func:`skynav.pipeline.process_frame` on each with no prior attitude (lost in
space: what the first frame of every leg and every frame after a lost one needs). A frame counts as
identified when the status is ``ok`` and the attitude is within 3 pixels of the truth (a
misidentification is degrees off). Prints per camera its pixel scale (arcsec/px at the centre) and
the fraction identified, with its 90 % Wilson interval; :data:`skynav.pipeline.checks.MAX_STAR_ID_ARCSEC_PX`
is the limit drawn from it.

    python benchmarks/star_id_scale.py [--frames 24] [--cameras 256x20 224x20 192x20 ...]
"""

from __future__ import annotations

import argparse
import math
import os
import tempfile
import time
from pathlib import Path

import numpy as np


def wilson(k, n, z=1.645):
    """90 % Wilson score interval of a binomial fraction k/n."""
    p = k / n
    c = (p + z * z / (2 * n)) / (1 + z * z / n)
    h = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return max(0.0, c - h), min(1.0, c + h)


def identified(ds, k, catalog):
    """Lost-in-space ID of frame ``k``: (identified, status)."""
    from skynav.pipeline import process_frame

    obs = ds.observation(k)
    tr = ds.truth(k, validate=False)
    fr = process_frame(obs, catalog=catalog)
    if fr.status != "ok" or fr.attitude.R_cam_icrs is None:
        return False, fr.status
    dR = np.asarray(fr.attitude.R_cam_icrs) @ np.asarray(tr.R_cam_icrs).T
    angle = math.acos(max(-1.0, min(1.0, (np.trace(dR) - 1.0) / 2.0)))
    return angle < 3.0 * obs.camera.ifov_rad, fr.status


def main():
    from skynav import datasets
    from skynav.datasets.recipes import preset_recipe
    from skynav.pipeline import OnboardCatalog

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=24)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--cameras", nargs="+", default=["448x20", "320x20", "256x20", "224x20", "192x20", "160x20",
                                                       "128x10", "112x10", "96x10"])
    args = ap.parse_args()
    print(f"lost-in-space star ID, montecarlo preset, {args.frames} frames per camera, seed {args.seed}; load average "
          f"{os.getloadavg()[0]:.1f}", flush=True)
    with tempfile.TemporaryDirectory() as d:
        for spec in args.cameras:
            w, fov = spec.lower().split("x")
            r = preset_recipe("montecarlo")
            r.update(frames=args.frames, seed=args.seed, formats=["png", "json"],
                     camera={"preset": "paper", "width": int(w), "height": int(w), "fov_deg": float(fov)})
            out = Path(d) / spec
            t0 = time.perf_counter()
            datasets.generate(r, out, workers=1, progress=False)
            ds = datasets.open(out)
            cam = ds.observation(0).camera
            cat = OnboardCatalog.load(camera=cam)
            got = [identified(ds, k, cat) for k in range(len(ds))]
            k = sum(g for g, _ in got)
            lo, hi = wilson(k, len(got))
            fails = sorted({s for g, s in got if not g})
            print(f"  {spec}: {math.degrees(cam.ifov_rad) * 3600:.0f} arcsec/px, identified {k}/{len(got)} "
                  f"({100 * k / len(got):.0f} %, 90 % {100 * lo:.0f}-{100 * hi:.0f} %)"
                  + (f"; failed: {', '.join(fails)}" if fails else "") + f" ({time.perf_counter() - t0:.0f} s)",
                  flush=True)


if __name__ == "__main__":
    main()
