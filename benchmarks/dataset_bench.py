"""Dataset generation speed: frames/s with 1 and 2 workers, scaling, per-frame cost split.

    python benchmarks/dataset_bench.py [--frames 16] [--small] [--plot legs_vmag.png]

- Runs the default Monte Carlo recipe (paper camera 1024 x 1024, keep-filter visible_planet,
  PNG + EXR + JSON) with 1 worker (in process) and 2 spawned worker processes, each into a new
  folder, and prints frames/s and the scaling efficiency ``fps(2) / (2 fps(1))``; checks that
  both folders are byte-identical.
- Splits the cost of one frame: sampling (scene draw + keep-filter + ``build_scene``), render
  (``render``), encode (``write_frame`` into /dev/shm, a memory file system) and write (the
  same on the dataset's disk, minus encode: temp file, fsync, rename).
- ``--plot``: PNG of the planets' apparent V magnitudes along the navigation legs of the
  default sequence recipe (Pillow plot, no matplotlib).
"""

from __future__ import annotations

import argparse
import hashlib
import os
import statistics
import tempfile
import time
from pathlib import Path


def tree(root):
    root = Path(root)
    return {p.relative_to(root).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(root.rglob("*")) if p.is_file()}


def cost_split(recipe, n: int, disk_dir: Path):
    import numpy as np

    from skynav.datasets.samplers import frame_seed, make_plan
    from skynav.datasets.recipes import validate_recipe
    from skynav.renderer.render import render, write_frame
    from skynav.scenes.scene import build_scene

    rec = validate_recipe(recipe)
    plan = make_plan(rec)
    shm = Path(tempfile.mkdtemp(dir="/dev/shm" if os.path.isdir("/dev/shm") else None))
    out = {"sample": [], "render": [], "encode": [], "write": []}
    for k in range(n):
        ss = frame_seed(rec["seed"], k)
        rng = np.random.default_rng(ss)
        t0 = time.perf_counter()
        req = plan.frame_request(k, rng)
        scene = build_scene(req.epoch_tdb_s, position_km=req.position_km, velocity_km_s=req.velocity_km_s,
                            R_cam_icrs=req.R_cam_icrs, camera=plan.camera, star_mag_limit=rec["star_mag_limit"], sky=req.sky)
        t1 = time.perf_counter()
        frame = render(scene, seed=ss, rng=rng)
        t2 = time.perf_counter()
        write_frame(frame, shm, f"{k:06d}", formats=tuple(rec["formats"]))
        t3 = time.perf_counter()
        write_frame(frame, disk_dir, f"{k:06d}", formats=tuple(rec["formats"]))
        t4 = time.perf_counter()
        out["sample"].append(t1 - t0)
        out["render"].append(t2 - t1)
        out["encode"].append(t3 - t2)
        out["write"].append(max(0.0, (t4 - t3) - (t3 - t2)))
    for p in shm.iterdir():
        p.unlink()
    shm.rmdir()
    return {k: statistics.median(v) for k, v in out.items()}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=16)
    ap.add_argument("--small", action="store_true", help="256 x 256 camera, stars to V 7 (the tests' recipe)")
    ap.add_argument("--plot", type=str, default=None, help="write the leg magnitude plot to this PNG")
    a = ap.parse_args(argv)

    from skynav.datasets import generate, preset_recipe

    rec = preset_recipe("montecarlo")
    rec["frames"] = a.frames
    if a.small:
        rec["camera"] = {"preset": "paper", "width": 256, "height": 256, "fov_deg": 20.0}
        rec["star_mag_limit"] = 7.0
    print(f"recipe: montecarlo preset, {a.frames} frames, camera {'256 x 256' if a.small else '1024 x 1024'}, "
          f"stars to V {rec['star_mag_limit']}, cpu_count {os.cpu_count()}")
    with tempfile.TemporaryDirectory(dir=os.environ.get("BENCH_DIR")) as tmp:
        tmp = Path(tmp)
        # warm the catalog cache and the imports so that the 1-worker run is not charged for them
        warm = dict(rec, frames=1)
        generate(warm, tmp / "warm", workers=1, progress=False)
        results = {}
        for workers in (1, 2):
            s = generate(rec, tmp / f"w{workers}", workers=workers, progress=False)
            results[workers] = s
            print(f"workers {workers}: {s.frames_rendered} frames in {s.elapsed_s:.1f} s = {s.frames_per_s:.2f} frames/s "
                  f"({s.executor}; mean per frame " + ", ".join(f"{k} {v * 1e3:.0f} ms" for k, v in s.mean_timings_s.items()) + ")")
        eff = results[2].frames_per_s / (2 * results[1].frames_per_s)
        same = tree(tmp / "w1") == tree(tmp / "w2")
        print(f"scaling efficiency 2 workers: {eff:.2f} (includes spawning 2 interpreters and loading the catalog in each);"
              f" folders byte-identical: {same}")
        split = cost_split(rec, min(a.frames, 8), tmp / "split")
        total = sum(split.values())
        print("per-frame cost split (median of %d frames, 1 process): " % min(a.frames, 8)
              + ", ".join(f"{k} {v * 1e3:.0f} ms ({100 * v / total:.0f} %)" for k, v in split.items()))
    if a.plot:
        from skynav.datasets import preset_recipe as pr
        from skynav.datasets.plots import plot_leg_magnitudes
        from skynav.datasets.recipes import validate_recipe
        from skynav.datasets.samplers import make_plan

        plan = make_plan(validate_recipe(pr("sequence")))
        plot_leg_magnitudes(plan, a.plot)
        print(f"wrote {a.plot}: planets' V along the {plan.s['legs']} legs (pairs {plan.describe()['pairs']})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
