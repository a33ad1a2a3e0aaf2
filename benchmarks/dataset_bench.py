"""Dataset generation speed: frames/s with 1 and 2 workers, scaling, per-frame cost split.

    python benchmarks/dataset_bench.py [--frames N] [--single-thread] [--small] [--plot legs_vmag.png]

- Runs the default Monte Carlo recipe (``skynav dataset generate montecarlo``: 3000 frames,
  paper camera 1024 x 1024, keep-filter visible_planet, PNG + EXR + JSON; ``--frames N`` for a
  shorter run) as a fresh process, the way a user does, in these set-ups, each into a new folder:

  * ``1 worker``: ``--workers 1`` as is (Dr.Jit's and OpenEXR's pools use every core for their
    parts of the frame);
  * ``2 workers``: ``--workers 2`` (each worker gets ``cores // 2`` threads);
  * with ``--single-thread``, also ``1 worker, 1 thread``: ``--workers 1`` with
    ``SKYNAV_THREADS=1`` (and OpenBLAS/OpenMP at 1), one core's worth of work.

  Each figure is frames / wall-clock seconds of the whole command (start-up, imports, spawning
  the workers, writing the manifest and index included), and the script also prints the
  steady-state rate (frames after the first 10 % over their time, from the progress callback).
  Scaling = fps(2 workers) / fps(1 worker); both references are printed. The folders must be
  byte-identical (checked).
- Splits the cost of one frame: sampling (scene draw + keep-filter + ``build_scene``), render
  (``render``), encode (``write_frame`` into /dev/shm, a memory file system) and write (the
  same on the dataset's disk, minus encode: temp file, fsync, rename).
- ``--plot``: PNG of the planets' apparent V magnitudes along the navigation legs of the
  default sequence recipe (matplotlib, Agg).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

_CHILD = r"""
import json, sys, time
t0 = time.perf_counter()
from skynav.datasets import generate, preset_recipe
rec = preset_recipe("montecarlo")
rec["frames"] = int(sys.argv[1])
if sys.argv[4] == "small":
    rec["camera"] = {"preset": "paper", "width": 256, "height": 256, "fov_deg": 20.0}
    rec["catalog_limiting_v_mag"] = 7.0
marks = []
def progress(done, total):
    marks.append((done, time.perf_counter()))
s = generate(rec, sys.argv[2], workers=int(sys.argv[3]), progress=progress)
n = s.frames_rendered
skip = max(1, n // 10)
t_skip = next(t for d, t in marks if d >= skip)
t_end = marks[-1][1]
print(json.dumps({"frames": n, "elapsed_s": s.elapsed_s, "imports_s": time.perf_counter() - t0 - s.elapsed_s,
                  "steady_fps": (n - skip) / (t_end - t_skip) if t_end > t_skip else float("nan"),
                  "executor": s.executor, "mean": s.mean_timings_s}))
"""

def _one_thread() -> dict:
    """The runner's thread-count variables, all at 1."""
    from skynav.datasets.pool import THREAD_VARS

    return {name: "1" for name in THREAD_VARS}


def run_cold(frames: int, out: Path, workers: int, small: bool, env_extra: dict) -> dict:
    """One fresh ``python`` running ``generate`` (what the CLI calls); wall clock of it all."""
    env = {k: v for k, v in os.environ.items() if k not in _one_thread()}
    env.update(env_extra)
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-c", _CHILD, str(frames), str(out), str(workers), "small" if small else "full"],
                          capture_output=True, text=True, env=env)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        raise SystemExit(f"generate with {workers} worker(s) failed:\n{proc.stderr[-2000:]}")
    r = json.loads(proc.stdout.strip().splitlines()[-1])
    r["wall_s"] = wall
    r["fps"] = frames / wall
    return r


def tree(root):
    root = Path(root)
    return {p.relative_to(root).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(root.rglob("*")) if p.is_file()}


def cost_split(recipe, n: int, disk_dir: Path):
    import numpy as np

    from skynav.datasets.samplers import frame_seed, make_plan
    from skynav.datasets.recipes import validate_recipe
    from skynav.datasets.frame_files import write_frame
    from skynav.renderer.render import render
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
                            R_cam_icrs=req.R_cam_icrs, camera=plan.camera, catalog_limiting_v_mag=rec["catalog_limiting_v_mag"],
                            visibility=plan.visibility, sky=req.sky)
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
    ap.add_argument("--frames", type=int, default=None, help="frames (default: the recipe's, 3000)")
    ap.add_argument("--single-thread", action="store_true", help="also run 1 worker with SKYNAV_THREADS=1")
    ap.add_argument("--small", action="store_true", help="256 x 256 camera, stars to V 7 (the tests' recipe)")
    ap.add_argument("--plot", type=str, default=None, help="write the leg magnitude plot to this PNG")
    a = ap.parse_args(argv)

    from skynav.datasets import generate, preset_recipe

    rec = preset_recipe("montecarlo")
    a.frames = a.frames or rec["frames"]
    rec["frames"] = a.frames
    if a.small:
        rec["camera"] = {"preset": "paper", "width": 256, "height": 256, "fov_deg": 20.0}
        rec["catalog_limiting_v_mag"] = 7.0
    print(f"recipe: montecarlo preset, {a.frames} frames, camera {'256 x 256' if a.small else '1024 x 1024'}, "
          f"stars to V {rec['catalog_limiting_v_mag']}, cpu_count {os.cpu_count()}")
    with tempfile.TemporaryDirectory(dir=os.environ.get("BENCH_DIR")) as tmp:
        tmp = Path(tmp)
        # fill the on-disk caches (catalog, JIT probe, Dr.Jit kernels) so that no run pays for them
        generate(dict(rec, frames=2), tmp / "warm", workers=1, progress=False)
        setups = [("1 worker", 1, {}), ("2 workers", 2, {})]
        if a.single_thread:
            setups.insert(0, ("1 worker, 1 thread", 1, _one_thread()))
        res = {}
        for i, (label, workers, env) in enumerate(setups):
            r = res[label] = run_cold(a.frames, tmp / f"run{i}", workers, a.small, env)
            print(f"{label:18s}: {r['frames']} frames in {r['wall_s']:.1f} s = {r['fps']:.2f} frames/s "
                  f"(start-up and imports {r['imports_s']:.1f} s; steady state {r['steady_fps']:.2f} frames/s; {r['executor']}; "
                  "mean per frame " + ", ".join(f"{k} {v * 1e3:.0f} ms" for k, v in r["mean"].items()) + ")")
        two = res["2 workers"]
        for ref in [lb for lb, w, _ in setups if w == 1]:
            one = res[ref]
            print(f"scaling 2 workers vs {ref}: {two['fps'] / one['fps']:.2f} x wall clock, "
                  f"{two['steady_fps'] / one['steady_fps']:.2f} x steady state")
        trees = [tree(tmp / f"run{i}") for i in range(len(setups))]
        print(f"folders byte-identical: {all(t == trees[0] for t in trees)}")
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
