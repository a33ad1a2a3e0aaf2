"""Dataset generation speed: frames/s with 1 and 2 workers, scaling, per-frame cost split, RSS.

    python benchmarks/dataset_bench.py [--frames N] [--single-thread] [--dask] [--repeat R] [--small]
                                       [--split-frames N] [--plot legs_vmag.png]

- Runs the default Monte Carlo recipe (``skynav dataset generate montecarlo``: 3000 frames,
  paper camera 1024 x 1024, keep-filter visible_planet, PNG + EXR + JSON; ``--frames N`` for a
  shorter run) as a fresh process, the way a user does, in these set-ups, each into a new folder:

  * ``1 worker``: ``--workers 1`` as is (Dr.Jit's and OpenEXR's pools use every core for their
    parts of the frame);
  * ``2 workers``: ``--workers 2`` (each worker gets ``cores // 2`` threads);
  * with ``--single-thread``, also ``1 worker, 1 thread``: ``--workers 1`` with
    ``SKYNAV_THREADS=1`` (and OpenBLAS/OpenMP at 1), one core's worth of work;
  * with ``--dask``, also a ``distributed.LocalCluster`` of 1 and of 2 worker processes (one
    thread each; the cluster's start is in the wall clock).

  Each figure is frames / wall-clock seconds of the whole command (start-up, imports, spawning
  the workers, writing the manifest and index included), and the script also prints the
  steady-state rate (frames after the first 10 % over their time, from the progress callback)
  and the peak resident memory (RSS) of a worker: of the process itself for ``1 worker`` (it
  renders in-process), else the largest worker process. Scaling = fps(2) / fps(1); both
  references are printed. ``--repeat R`` runs the set-ups R times, alternating their order, and
  prints medians. The folders must be byte-identical (checked). The machine's 1-minute load
  average is printed with every figure: on a shared machine the figures move with it.
- Splits the cost of one frame of the Monte Carlo and of the sequence preset, in a fresh process
  with one thread (``SKYNAV_THREADS=1``): sampling (scene draw + keep-filter + ``build_scene``),
  render (``render``), encode (``write_frame`` into /dev/shm, a memory file system) and write
  (the same on the dataset's disk, minus encode: temp file, fsync, rename); medians over
  ``--split-frames`` frames after the first (which compiles the kernels), the ratio of the
  frame's cost to its bare render, and that process's peak RSS.
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
import json, os, resource, sys, time
t0 = time.perf_counter()
from skynav.datasets import generate, preset_recipe
cfg = json.loads(sys.argv[1])
rec = preset_recipe(cfg["preset"])
limit = None
if cfg["preset"] == "montecarlo":
    rec["frames"] = cfg["frames"]
else:
    limit = cfg["frames"]
if cfg["small"]:
    rec["camera"] = {"preset": "paper", "width": 256, "height": 256, "fov_deg": 20.0}
    rec["catalog_limiting_v_mag"] = 7.0
marks = []
def progress(done, total):
    marks.append((done, time.perf_counter()))
kw = {"workers": cfg["workers"]}
if cfg["dask"]:
    from distributed import Client, LocalCluster
    cluster = LocalCluster(n_workers=cfg["workers"], threads_per_worker=1, processes=True, dashboard_address=None)
    client = Client(cluster)
    kw = {"client": client}
t_gen = time.perf_counter()
s = generate(rec, cfg["out"], progress=progress, max_frames=limit, **kw)
t_done = time.perf_counter()
if cfg["dask"]:
    client.close(); cluster.close()
n = s.frames_rendered
skip = max(1, n // 10)
t_skip = next(t for d, t in marks if d >= skip)
t_end = marks[-1][1]
kib = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss, resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
print(json.dumps({"frames": n, "elapsed_s": s.elapsed_s, "imports_s": t_gen - t0,
                  "steady_fps": (n - skip) / (t_end - t_skip) if t_end > t_skip else float("nan"),
                  "executor": s.executor, "mean": s.mean_timings_s,
                  "rss_self_mb": kib[0] / 1024, "rss_children_mb": kib[1] / 1024}))
"""

_SPLIT = r"""
import json, sys
sys.path.insert(0, sys.argv[2])
from dataset_bench import cost_split, preset_for
cfg = json.loads(sys.argv[1])
print(json.dumps(cost_split(preset_for(cfg["preset"], cfg["small"]), cfg["frames"], cfg["out"])))
"""

def _one_thread() -> dict:
    """The runner's thread-count variables, all at 1."""
    from skynav.datasets.pool import THREAD_VARS

    return {name: "1" for name in THREAD_VARS}


def _load() -> str:
    return "load %.1f" % os.getloadavg()[0]


def preset_for(preset: str, small: bool) -> dict:
    from skynav.datasets import preset_recipe

    rec = preset_recipe(preset)
    if small:
        rec["camera"] = {"preset": "paper", "width": 256, "height": 256, "fov_deg": 20.0}
        rec["catalog_limiting_v_mag"] = 7.0
    return rec


def _child(code: str, cfg: dict, env_extra: dict) -> tuple:
    env = {k: v for k, v in os.environ.items() if k not in _one_thread()}
    env.update(env_extra)
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-c", code, json.dumps(cfg), str(Path(__file__).parent)],
                          capture_output=True, text=True, env=env)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        raise SystemExit(f"benchmark child {cfg} failed:\n{proc.stderr[-2000:]}")
    return json.loads(proc.stdout.strip().splitlines()[-1]), wall


def run_cold(frames: int, out: Path, workers: int, small: bool, env_extra: dict, *, preset: str = "montecarlo",
             dask: bool = False) -> dict:
    """One fresh ``python`` running ``generate`` (what the CLI calls); wall clock of it all."""
    r, wall = _child(_CHILD, {"preset": preset, "frames": frames, "out": str(out), "workers": workers,
                              "small": small, "dask": dask}, env_extra)
    r["wall_s"] = wall
    r["fps"] = r["frames"] / wall
    r["load"] = os.getloadavg()[0]
    return r


def tree(root):
    root = Path(root)
    return {p.relative_to(root).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(root.rglob("*")) if p.is_file()}


def cost_split(recipe, n: int, disk_dir):
    """Median per-frame seconds of sample, render, encode, write over frames 0..n-1 (see the
    module docstring), and the peak RSS of this process (MB)."""
    import numpy as np

    from skynav.datasets.samplers import frame_seed, make_plan
    from skynav.datasets.recipes import validate_recipe
    from skynav.datasets.frame_files import write_frame
    from skynav.renderer.render import render
    from skynav.scenes.scene import build_scene

    rec = validate_recipe(recipe)
    plan = make_plan(rec)
    n = min(n, plan.n_frames)
    disk_dir = Path(disk_dir)
    shm = Path(tempfile.mkdtemp(dir="/dev/shm" if os.path.isdir("/dev/shm") else None))
    out = {"sample": [], "render": [], "encode": [], "write": []}
    for k in range(n):
        ss = frame_seed(rec["seed"], k)
        rng = np.random.default_rng(ss)
        t0 = time.perf_counter()
        req = plan.frame_request(k, rng)
        scene = build_scene(req.epoch_tdb_s, position_km=req.position_km, velocity_km_s=req.velocity_km_s,
                            R_cam_icrs=req.R_cam_icrs, camera=plan.camera, catalog_limiting_v_mag=rec["catalog_limiting_v_mag"],
                            angular_velocity_rad_s=req.angular_velocity_rad_s, visibility=plan.visibility, sky=req.sky)
        t1 = time.perf_counter()
        frame = render(scene, seed=ss, rng=rng)
        t2 = time.perf_counter()
        write_frame(frame, shm, f"{k:06d}", formats=tuple(rec["formats"]))
        t3 = time.perf_counter()
        write_frame(frame, disk_dir, f"{k:06d}", formats=tuple(rec["formats"]))
        t4 = time.perf_counter()
        if k == 0:
            continue  # the first frame pays for JIT kernels and caches
        out["sample"].append(t1 - t0)
        out["render"].append(t2 - t1)
        out["encode"].append(t3 - t2)
        out["write"].append(max(0.0, (t4 - t3) - (t3 - t2)))
    for p in shm.iterdir():
        p.unlink()
    shm.rmdir()
    import resource

    res = {k: statistics.median(v) for k, v in out.items()}
    res["frames"] = n - 1
    res["rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    return res


def _print_split(label: str, split: dict) -> None:
    parts = {k: split[k] for k in ("sample", "render", "encode", "write")}
    total = sum(parts.values())
    print(f"{label}: per-frame cost split (median of {split['frames']} frames, 1 process, 1 thread): "
          + ", ".join(f"{k} {v * 1e3:.1f} ms ({100 * v / total:.0f} %)" for k, v in parts.items())
          + f"; frame = {total / parts['render']:.2f} x its bare render; peak RSS {split['rss_mb']:.0f} MB; {_load()}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=None, help="frames (default: the recipe's, 3000)")
    ap.add_argument("--single-thread", action="store_true", help="also run 1 worker with SKYNAV_THREADS=1")
    ap.add_argument("--small", action="store_true", help="256 x 256 camera, stars to V 7 (the tests' recipe)")
    ap.add_argument("--repeat", type=int, default=1, help="run the set-ups this many times, alternating; print medians")
    ap.add_argument("--dask", action="store_true", help="also a Dask LocalCluster of 1 and of 2 workers (1 thread each)")
    ap.add_argument("--split-frames", type=int, default=12, help="frames of each cost split (default 12; the first is not counted)")
    ap.add_argument("--plot", type=str, default=None, help="write the leg magnitude plot to this PNG")
    a = ap.parse_args(argv)

    from skynav.datasets import generate, preset_recipe

    rec = preset_recipe("montecarlo")
    a.frames = a.frames or rec["frames"]
    rec = preset_for("montecarlo", a.small)
    rec["frames"] = a.frames
    print(f"recipe: montecarlo preset, {a.frames} frames, camera {'256 x 256' if a.small else '1024 x 1024'}, "
          f"stars to V {rec['catalog_limiting_v_mag']}, cpu_count {os.cpu_count()}, {_load()}")
    with tempfile.TemporaryDirectory(dir=os.environ.get("BENCH_DIR")) as tmp:
        tmp = Path(tmp)
        # fill the on-disk caches (catalog, JIT probe, Dr.Jit kernels) so that no run pays for them
        generate(dict(rec, frames=2), tmp / "warm", workers=1, progress=False)
        setups = [("1 worker", 1, {}, False), ("2 workers", 2, {}, False)]
        if a.single_thread:
            setups.insert(0, ("1 worker, 1 thread", 1, _one_thread(), False))
        if a.dask:
            setups += [("dask 1 worker", 1, {}, True), ("dask 2 workers", 2, {}, True)]
        runs = {label: [] for label, *_ in setups}
        for rep in range(a.repeat):
            order = setups if rep % 2 == 0 else setups[::-1]
            for label, workers, env, dask in order:
                i = [s[0] for s in setups].index(label)
                r = run_cold(a.frames, tmp / f"run{i}_{rep}", workers, a.small, env, dask=dask)
                runs[label].append(r)
                rss = r["rss_self_mb"] if r["executor"] == "in-process" else r["rss_children_mb"]
                print(f"{label:18s}: {r['frames']} frames in {r['wall_s']:.1f} s = {r['fps']:.2f} frames/s "
                      f"(start-up and imports {r['imports_s']:.1f} s; steady state {r['steady_fps']:.2f} frames/s; {r['executor']}; "
                      "mean per frame " + ", ".join(f"{k} {v * 1e3:.0f} ms" for k, v in r["mean"].items())
                      + f"; peak RSS of a worker {rss:.0f} MB; load {r['load']:.1f})")
        med = {label: {k: statistics.median(r[k] for r in rs) for k in ("fps", "steady_fps")} for label, rs in runs.items()}
        if a.repeat > 1:
            for label, m in med.items():
                print(f"{label:18s}: median of {a.repeat}: {m['fps']:.2f} frames/s, steady state {m['steady_fps']:.2f}")
        pairs = [("2 workers", lb) for lb, w, _, d in setups if w == 1 and not d]
        if a.dask:
            pairs.append(("dask 2 workers", "dask 1 worker"))
        for two, one in pairs:
            print(f"scaling {two} vs {one}: {med[two]['fps'] / med[one]['fps']:.2f} x wall clock, "
                  f"{med[two]['steady_fps'] / med[one]['steady_fps']:.2f} x steady state; {_load()}")
        trees = [tree(tmp / f"run{i}_{rep}") for i in range(len(setups)) for rep in range(a.repeat)]
        print(f"folders byte-identical: {all(t == trees[0] for t in trees)}")
        for preset in ("montecarlo", "sequence"):
            split, _ = _child(_SPLIT, {"preset": preset, "small": a.small, "frames": a.split_frames + 1,
                                       "out": str(tmp / f"split_{preset}")}, _one_thread())
            _print_split(f"{preset} preset", split)
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
