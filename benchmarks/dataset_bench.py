"""Dataset generation speed: a frame's cost against its bare render, and scaling over workers.

    python benchmarks/dataset_bench.py [--frames N] [--split-frames N] [--warmup W] [--repeat R]
                                       [--dask] [--no-scaling | --no-split] [--small] [--plot legs_vmag.png]
                                       [--dir DIR]

Every figure is a median over ``--repeat`` fresh processes (default 3), run in alternating
order, and every ratio is taken inside one run (numerator and denominator from the same process
or the same round), so a shared machine's load moves both. The 1-minute load average is printed
beside each figure. Defaults take about 5 minutes on an idle 2-core machine.

1. **A frame against its bare render** (Monte Carlo and sequence presets, one thread:
   ``SKYNAV_THREADS=1``, OpenBLAS/OpenMP at 1). Each repeat is a fresh ``python`` that

   a. makes ``W + N + 1`` frames of the preset with ``generate(..., workers=1)`` (what
      ``skynav dataset generate --workers 1`` runs: sample, render, encode, write, checksums,
      journal, manifest checkpoints, index) and takes N frames' costs from the progress
      callback, as CPU time of the process (``time.process_time``: every thread's work on one
      core's worth of budget; the waits for the disk are not in it) and as wall-clock time (an
      interval between two marks holds one frame's making and the previous frame's writing; the
      run's last interval, the last write alone, is left out);
   b. then, in the same process, makes the same N frames again stage by stage: **sample**
      (the sampler's frame request and ``build_scene``), **render** (``render``: the bare
      render), **encode** (the PNG, EXR and JSON bytes in memory), **write** (the three files
      written atomically on one thread as the runner's writer thread writes them, their SHA-256 and the frame's journal record), each timed as CPU and
      wall-clock.

   The first ``W`` frames (``--warmup``, default 8: Dr.Jit compiles its kernels, caches fill) are
   left out. It prints the median of each stage, and **frame / bare render = median cost of a
   dataset frame (a) / median bare render (b)**, CPU time (the headline figure) and wall
   clock; then the median of the repeats, and the process's peak RSS.

2. **Scaling** (``--no-scaling`` skips it; ``--no-split`` runs it alone): ``--frames``
   (default 400) Monte Carlo frames, each set-up a fresh process running ``generate`` into a new folder:

   * ``1 worker, 1 thread``: ``--workers 1`` with ``SKYNAV_THREADS=1``;
   * ``2 workers``: ``--workers 2`` (the process itself and one spawned helper that joins once
     it has started, sharing the frames; ``cores // 2`` threads each: one each on 2 cores);
   * ``1 worker, 1 core``: as ``1 worker, 1 thread``, the process confined to one core
     (``sched_setaffinity``). One worker alone runs its writer thread on the second core beside
     its renders (about 1.1 cores' worth of CPU a frame), which two workers cannot do; against
     this baseline, ``2 workers`` measures the parallel efficiency of two workers, each on one
     core;
   * ``2 processes``: the machine's ceiling for two workers. Two fresh processes at once, each
     running ``1 worker, 1 thread`` into a folder of its own, sharing nothing but the machine
     (its cores, caches, memory bandwidth and disk); their steady-state frames/s are summed.
     ``2 workers / 2 processes`` is then the pool's own cost, and ``2 processes / 1 worker, 1
     thread`` what the machine gives two workers at best. Before the rounds, a pure-Python loop
     (no memory traffic) runs on each core alone and on both at once: how fast each core is, and
     what two processes get when they share nothing at all;
   * with ``--dask``: a ``distributed.LocalCluster`` of 1 and of 2 worker processes, one thread
     each.

   **Steady state** (what the scaling criteria compare): the frames completed between the
   first progress report at or past ``n/5`` frames and the last one at or before
   ``n - 8 x workers`` (a Dask run's results arrive in runs of up to 8 frames, ``execute.POOL_CHUNK``), over
   the time between those two reports. Left out before it: imports, the workers' spawn and
   imports, their first frames (kernel compilation), the cluster's start; after it, the tail
   where some workers have no frame left. Also printed: frames / wall clock of the whole command (start-up
   included: the total frames/s), and the peak RSS of a worker (the process itself, or its
   largest helper if that is larger). Scaling = steady-state rate of 2 workers / that of 1
   worker, in each round, median over the rounds, against ``1 worker, 1 thread`` (the headline
   figure), against ``1 worker, 1 core`` and against ``2 processes``. The folders must be byte-identical
   (checked: the files that differ are named, a PNG's DN compared, and the script exits with 1).

``--dir``: where the datasets go (a temporary folder in it; default the system's temporary
folder). The write stage is mostly the file system's work (a file created, written, fsync'ed
and renamed per format, the folder fsync'ed, the journal record), so its cost is the file
system's: the first line names it (type, whether an ext4 has a journal, the mount options).
On one 2-core VM whose root is an ext4 without a journal, mounted with ``discard``, creating
the frame's files cost 2-5 ms a frame in the flow, 1.4-1.6 ms on an ext4 with a journal.

``--small``: a 256 x 256 camera and stars to V 7 (the tests' recipe), for a quick look.
``--plot``: PNG of the planets' apparent V magnitudes along the navigation legs of the default
sequence recipe (matplotlib, Agg).
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
cfg = json.loads(sys.argv[1])
if cfg.get("one_core"):  # this process and every thread it starts on one core
    os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
sys.path.insert(0, sys.argv[2])
from dataset_bench import preset_for
from skynav.datasets import generate
rec = preset_for(cfg["preset"], cfg["small"])
limit = None
if cfg["preset"] == "montecarlo":
    rec["frames"] = cfg["frames"]
else:
    limit = cfg["frames"]
marks = []
def progress(done, total):
    marks.append((done, time.perf_counter()))
kw = {"workers": cfg["workers"]}
if cfg.get("backend"):  # the sensor backend (gpu_bench.py); else the renderer's "auto"
    from skynav.renderer.render import RenderOptions
    kw["render_options"] = RenderOptions(backend=cfg["backend"])
if cfg["dask"]:
    from distributed import Client, LocalCluster
    cluster = LocalCluster(n_workers=cfg["workers"], threads_per_worker=1, processes=True, dashboard_address=None)
    client = Client(cluster)
    kw = {"client": client}
t_gen = time.perf_counter()
s = generate(rec, cfg["out"], progress=progress, max_frames=limit, **kw)
if cfg["dask"]:
    client.close(); cluster.close()
n = s.frames_rendered
from skynav.datasets.execute import POOL_CHUNK
a, b = max(1, n // 5), n - POOL_CHUNK * cfg["workers"]
d_a, t_a = next((d, t) for d, t in marks if d >= a)  # results arrive in runs of frames: the marks' own counts
d_b, t_b = [(d, t) for d, t in marks if d <= b][-1]
kib = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss, resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
print(json.dumps({"frames": n, "elapsed_s": s.elapsed_s, "imports_s": t_gen - t0,
                  "steady_fps": (d_b - d_a) / (t_b - t_a) if d_b > d_a and t_b > t_a else float("nan"),
                  "steady_frames": d_b - d_a, "executor": s.executor,
                  "rss_self_mb": kib[0] / 1024, "rss_children_mb": kib[1] / 1024}))
"""

_SPIN = r"""
import json, os, sys, time
cfg = json.loads(sys.argv[1])
os.sched_setaffinity(0, {cfg["core"]})
c0, x = time.process_time(), 0
for i in range(cfg["n"]):
    x += i * i
print(json.dumps({"cpu_s": time.process_time() - c0}))
"""

_SPLIT = r"""
import json, sys
sys.path.insert(0, sys.argv[2])
from dataset_bench import cost_split, preset_for
cfg = json.loads(sys.argv[1])
print(json.dumps(cost_split(preset_for(cfg["preset"], cfg["small"]), cfg["frames"], cfg["warmup"], cfg["out"])))
"""

STAGES = ("sample", "render", "encode", "write")

#: The scaling set-up that is the machine's ceiling for two workers: two independent one-worker
#: processes at once (:func:`run_cold_pair`).
PAIR = "2 processes"


def _one_thread() -> dict:
    """The runner's thread-count variables, all at 1."""
    from skynav.infra.pool import THREAD_VARS

    return {name: "1" for name in THREAD_VARS}


def _load() -> float:
    return os.getloadavg()[0]


def file_system(path) -> str:
    """The file system that holds ``path``, in words: its mount point, type, whether an ext4 has
    a journal (Linux's ``/proc/fs/jbd2``), and its mount options; what is known (Linux only)."""
    path = os.path.realpath(path)
    try:
        with open("/proc/self/mountinfo") as f:
            mounts = [line.split() for line in f]
    except OSError:
        return "file system unknown (no /proc/self/mountinfo)"
    best = None
    for m in mounts:
        point = m[4]
        if (path == point or path.startswith(point.rstrip("/") + "/")) and (best is None or len(point) >= len(best[4])):
            best = m
    if best is None:
        return "file system unknown"
    sep = best.index("-")
    kind, source = best[sep + 1], best[sep + 2]
    options = ",".join(dict.fromkeys(best[5].split(",") + (best[sep + 3].split(",") if len(best) > sep + 3 else [])))
    words = kind
    if kind == "ext4":
        dev = os.path.basename(source)
        journals = os.listdir("/proc/fs/jbd2") if os.path.isdir("/proc/fs/jbd2") else []
        words += ", with a journal" if any(j.rsplit("-", 1)[0] == dev for j in journals) else ", no journal"
    return f"{best[4]} ({words}; mount options {options})"


def preset_for(preset: str, small: bool) -> dict:
    from skynav.datasets import preset_recipe

    rec = preset_recipe(preset)
    if small:
        rec["camera"] = {"preset": "paper", "width": 256, "height": 256, "fov_deg": 20.0}
        rec["catalog_limiting_v_mag"] = 7.0
    return rec


def _start(code: str, cfg: dict, env_extra: dict) -> subprocess.Popen:
    env = {k: v for k, v in os.environ.items() if k not in _one_thread()}
    env.update(env_extra)
    return subprocess.Popen([sys.executable, "-c", code, json.dumps(cfg), str(Path(__file__).parent)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)


def _finish(proc: subprocess.Popen, cfg: dict) -> dict:
    out, err = proc.communicate()
    if proc.returncode != 0:
        raise SystemExit(f"benchmark child {cfg} failed:\n{err[-2000:]}")
    return json.loads(out.strip().splitlines()[-1])


def _child(code: str, cfg: dict, env_extra: dict) -> tuple:
    t0 = time.perf_counter()
    r = _finish(_start(code, cfg, env_extra), cfg)
    return r, time.perf_counter() - t0


def _cold_cfg(frames: int, out: Path, workers: int, small: bool, *, preset: str = "montecarlo", dask: bool = False,
              one_core: bool = False, backend: str | None = None) -> dict:
    """The configuration :data:`_CHILD` reads: one ``generate`` run."""
    return {"preset": preset, "frames": frames, "out": str(out), "workers": workers, "small": small, "dask": dask,
            "one_core": one_core, "backend": backend}


def run_cold(frames: int, out: Path, workers: int, small: bool, env_extra: dict, *, preset: str = "montecarlo",
             dask: bool = False, one_core: bool = False, backend: str | None = None) -> dict:
    """One fresh ``python`` running ``generate`` (what the CLI calls); wall clock of it all.
    ``one_core``: the process (its writer thread too) confined to one core. ``backend``: the
    sensor backend (default: the renderer's ``"auto"``)."""
    r, wall = _child(_CHILD, _cold_cfg(frames, out, workers, small, preset=preset, dask=dask, one_core=one_core,
                                       backend=backend), env_extra)
    r["wall_s"] = wall
    r["fps"] = r["frames"] / wall
    r["load"] = _load()
    return r


def core_speeds(n: int = 10_000_000) -> dict:
    """The CPU time of one pure-Python arithmetic loop (no memory traffic: nothing shared but the
    cores) on each of the first two cores, alone and then both at once: how fast each core is,
    and what the machine gives two processes that share nothing. ``{(core, "alone"|"both"): s}``."""
    cfgs = [{"core": c, "n": n} for c in sorted(os.sched_getaffinity(0))[:2]]
    out = {(cfg["core"], "alone"): _finish(_start(_SPIN, cfg, {}), cfg)["cpu_s"] for cfg in cfgs}
    procs = [_start(_SPIN, cfg, {}) for cfg in cfgs]
    for proc, cfg in zip(procs, cfgs):
        out[(cfg["core"], "both")] = _finish(proc, cfg)["cpu_s"]
    return out


def run_cold_pair(frames: int, outs: list, small: bool, env_extra: dict) -> dict:
    """Two fresh ``python`` processes at once, each running ``generate(..., workers=1)`` of
    ``frames`` frames into its own folder, one thread each: the machine's ceiling for two
    workers (two independent processes share nothing but the machine: its two cores' speeds,
    caches, memory bandwidth and disk). Frames/s are the sum of the two."""
    cfgs = [_cold_cfg(frames, o, 1, small) for o in outs]
    t0 = time.perf_counter()
    procs = [_start(_CHILD, cfg, env_extra) for cfg in cfgs]
    rs = [_finish(p, cfg) for p, cfg in zip(procs, cfgs)]
    wall = time.perf_counter() - t0
    return {"frames": sum(r["frames"] for r in rs), "steady_fps": sum(r["steady_fps"] for r in rs),
            "steady_frames": sum(r["steady_frames"] for r in rs), "imports_s": max(r["imports_s"] for r in rs),
            "executor": PAIR, "rss_self_mb": max(r["rss_self_mb"] for r in rs), "rss_children_mb": 0.0,
            "wall_s": wall, "fps": sum(r["frames"] for r in rs) / wall, "load": _load()}


def _png_chunk_difference(x: bytes, y: bytes) -> str:
    """Which chunks of two PNG files differ (type, the two payload sizes, the first byte that differs)."""
    def chunks(data):
        out, p = [], 8
        while p + 8 <= len(data):
            n = int.from_bytes(data[p:p + 4], "big")
            out.append((data[p + 4:p + 8].decode("latin-1"), data[p + 8:p + 8 + n]))
            p += 12 + n
        return out

    cx, cy = chunks(x), chunks(y)
    words = [f"sizes {len(x)} and {len(y)}"]
    for (tx, px), (ty, py) in zip(cx, cy):
        if tx != ty or px != py:
            first = next((i for i, (u, v) in enumerate(zip(px, py)) if u != v), min(len(px), len(py)))
            words.append(f"{tx}/{ty} {len(px)} and {len(py)} bytes, first difference at byte {first}")
    if len(cx) != len(cy):
        words.append(f"{len(cx)} and {len(cy)} chunks")
    return "; ".join(words)


def _png_difference(a, b) -> str:
    """How two PNGs of one frame differ, in words: their decoded DN, pixel by pixel."""
    import numpy as np

    from skynav.datasets.frame_files import read_png

    try:
        x, y = read_png(a).astype(int), read_png(b).astype(int)
    except Exception as exc:  # noqa: BLE001 - a report line, not a check
        return f"not decoded ({exc})"
    if x.shape != y.shape:
        return f"shapes {x.shape} and {y.shape}"
    d = np.argwhere(x != y)
    if not len(d):
        return f"the same DN, other bytes: {_png_chunk_difference(Path(a).read_bytes(), Path(b).read_bytes())}"
    return (f"{len(d)} pixels differ, |dDN| up to {int(np.abs(x - y).max())}, rows {d[:, 0].min()}-{d[:, 0].max()}, "
            f"columns {d[:, 1].min()}-{d[:, 1].max()}")


def tree(root):
    root = Path(root)
    return {p.relative_to(root).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(root.rglob("*")) if p.is_file()}


class _Clock:
    """CPU (``process_time``) and wall-clock (``perf_counter``) time together."""

    def __init__(self):
        self.cpu, self.wall = time.process_time(), time.perf_counter()

    def lap(self) -> tuple:
        cpu, wall = time.process_time(), time.perf_counter()
        out = (cpu - self.cpu, wall - self.wall)
        self.cpu, self.wall = cpu, wall
        return out


def cost_split(recipe, n: int, warmup: int, disk_dir) -> dict:
    """A dataset frame's cost and its stages, CPU and wall-clock seconds (see the module
    docstring, part 1): medians over frames ``warmup .. warmup + n - 1``; the peak RSS (MB)."""
    import resource

    import numpy as np

    from skynav.datasets import generate, layout
    from skynav.infra.atomic_files import atomic_write_many, sha256_file
    from skynav.datasets.frame_files import frame_file_bytes
    from skynav.datasets.journal import write_record
    from skynav.datasets.recipe_checks import validate_recipe
    from skynav.datasets.samplers import frame_seed, make_plan
    from skynav.renderer.render import render
    from skynav.scenes.scene import build_scene

    disk_dir = Path(disk_dir)
    total = warmup + n
    rec = dict(recipe)
    limit = None
    # (a) makes one frame more than it measures: the interval between two progress marks holds
    # the making of one frame and the writing of the one before (the writer thread's, meanwhile);
    # after the last frame is made only its write is left, so the last interval would be a write
    # alone, not a frame
    if rec["kind"] == "montecarlo":
        rec["frames"] = total + 1
    else:
        limit = total + 1
    # (a) the dataset frame, as the runner makes it
    marks = []
    generate(rec, disk_dir / "dataset", workers=1, max_frames=limit,
             progress=lambda done, _total: marks.append((done, time.process_time(), time.perf_counter())))
    marks = [m for m in marks if warmup <= m[0] <= total]  # frame k is done at the mark k + 1
    frame_cpu = [b[1] - a[1] for a, b in zip(marks, marks[1:])]
    frame_wall = [b[2] - a[2] for a, b in zip(marks, marks[1:])]
    # (b) the same frames again, stage by stage
    rec = validate_recipe(rec)
    plan = make_plan(rec)
    formats = tuple(rec["formats"])
    out = disk_dir / "stages"
    (out / layout.FRAMES_DIR).mkdir(parents=True)
    cost = {f"{s}_{c}": [] for s in STAGES for c in ("cpu", "wall")}
    for k in range(total):
        ss = frame_seed(rec["seed"], k)
        rng = np.random.default_rng(ss)
        clock = _Clock()
        req = plan.frame_request(k, rng)
        scene = build_scene(req.epoch_tdb_s, position_km=req.position_km, velocity_km_s=req.velocity_km_s,
                            R_cam_icrs=req.R_cam_icrs, camera=plan.camera, catalog_limiting_v_mag=rec["catalog_limiting_v_mag"],
                            angular_velocity_rad_s=req.angular_velocity_rad_s, visibility=plan.visibility, sky=req.sky)
        laps = [clock.lap()]
        frame = render(scene, seed=ss, rng=rng)
        laps.append(clock.lap())
        blobs = {fmt: frame_file_bytes(frame, fmt) for fmt in formats}
        laps.append(clock.lap())
        rel = layout.frame_relpaths(k, formats)
        atomic_write_many((out / rel[fmt], data) for fmt, data in blobs.items())
        write_record(out, k, {rel[fmt]: sha256_file(out / rel[fmt]) for fmt in formats})
        laps.append(clock.lap())
        if k >= warmup:
            for stage, (cpu, wall) in zip(STAGES, laps):
                cost[f"{stage}_cpu"].append(cpu)
                cost[f"{stage}_wall"].append(wall)
    res = {key: statistics.median(v) for key, v in cost.items()}
    res["frame_cpu"] = statistics.median(frame_cpu)
    res["frame_wall"] = statistics.median(frame_wall)
    res["frames"] = n
    res["rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    return res


def _print_split(label: str, split: dict, load: float) -> None:
    cpu = {s: split[f"{s}_cpu"] for s in STAGES}
    total = sum(cpu.values())
    print(f"{label}: median of {split['frames']} frames, 1 thread, CPU ms: "
          + ", ".join(f"{s} {v * 1e3:.1f} ({100 * v / total:.0f} %)" for s, v in cpu.items())
          + f"; stages / render {total / cpu['render']:.2f}; dataset frame {split['frame_cpu'] * 1e3:.1f} ms"
          f" = {split['frame_cpu'] / cpu['render']:.2f} x bare render (CPU), {split['frame_wall'] / split['render_wall']:.2f} x"
          f" (wall clock); peak RSS {split['rss_mb']:.0f} MB; load {load:.1f}")


def _args(argv):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=400, help="Monte Carlo frames of each scaling run (default 400)")
    ap.add_argument("--split-frames", type=int, default=40, help="frames of each cost split after the warm-up (default 40)")
    ap.add_argument("--warmup", type=int, default=8, help="frames left out at the start of each cost split (default 8)")
    ap.add_argument("--repeat", type=int, default=3, help="fresh processes per figure, alternating; medians (default 3)")
    ap.add_argument("--dask", action="store_true", help="also a Dask LocalCluster of 1 and of 2 workers (1 thread each)")
    ap.add_argument("--no-scaling", action="store_true", help="only the cost of a frame against its render")
    ap.add_argument("--no-split", action="store_true", help="only the scaling over workers")
    ap.add_argument("--small", action="store_true", help="256 x 256 camera, stars to V 7 (the tests' recipe)")
    ap.add_argument("--plot", type=str, default=None, help="write the leg magnitude plot to this PNG")
    ap.add_argument("--dir", type=str, default=None, help="make the datasets in a temporary folder in DIR "
                                                         "(default: the system's temporary folder)")
    return ap.parse_args(argv)


def run_splits(a, tmp: Path) -> None:
    """Part 1: a frame against its bare render, each preset in ``a.repeat`` fresh processes."""
    ratios = {"montecarlo": [], "sequence": []}
    for rep in range(a.repeat):
        for preset in (("montecarlo", "sequence") if rep % 2 == 0 else ("sequence", "montecarlo")):
            split, _ = _child(_SPLIT, {"preset": preset, "small": a.small, "frames": a.split_frames,
                                       "warmup": a.warmup, "out": str(tmp / f"split_{preset}_{rep}")}, _one_thread())
            load = _load()
            _print_split(f"{preset:10s} #{rep + 1}", split, load)
            ratios[preset].append((split["frame_cpu"] / split["render_cpu"], split["frame_wall"] / split["render_wall"],
                                   load, split["rss_mb"]))
    for preset, rs in ratios.items():
        print(f"{preset} preset: dataset frame / its bare render, 1 thread, median of {len(rs)}: "
              f"{statistics.median(r[0] for r in rs):.2f} x (CPU time; each {', '.join(f'{r[0]:.2f}' for r in rs)}), "
              f"{statistics.median(r[1] for r in rs):.2f} x (wall clock); peak RSS {max(r[3] for r in rs):.0f} MB; "
              f"load {min(r[2] for r in rs):.1f}-{max(r[2] for r in rs):.1f}")


def _setups(dask: bool) -> tuple:
    """The scaling set-ups: (label, workers, environment, dask, one core); whether cores can be pinned."""
    setups = [("1 worker, 1 thread", 1, _one_thread(), False, False), ("2 workers", 2, {}, False, False)]
    can_pin = hasattr(os, "sched_setaffinity") and len(os.sched_getaffinity(0)) > 1  # two cores to pin to
    if can_pin:
        setups.append(("1 worker, 1 core", 1, _one_thread(), False, True))
    setups.append((PAIR, 2, _one_thread(), False, False))
    if dask:
        setups += [("dask 1 worker", 1, {}, True, False), ("dask 2 workers", 2, {}, True, False)]
    return setups, can_pin


def _print_core_speeds() -> None:
    sp = core_speeds()
    cores = sorted({c for c, _ in sp})
    fast = min(sp[(c, "alone")] for c in cores)
    print("cores, pure-Python loop (no memory traffic), CPU s: "
          + "; ".join(f"core {c} {sp[(c, 'alone')]:.2f} alone, {sp[(c, 'both')]:.2f} with the other busy" for c in cores)
          + f"; two such processes = {sum(fast / sp[(c, 'both')] for c in cores):.2f} x one on the faster core")


def _print_ratios(runs: dict, dask: bool) -> None:
    pairs = ([("2 workers", "1 worker, 1 thread")] + ([("2 workers", "1 worker, 1 core")] if "1 worker, 1 core" in runs else [])
             + [(PAIR, "1 worker, 1 thread"), ("2 workers", PAIR)]
             + ([("dask 2 workers", "dask 1 worker"), ("dask 2 workers", PAIR)] if dask else []))
    for two, one in pairs:
        steady = [r2["steady_fps"] / r1["steady_fps"] for r1, r2 in zip(runs[one], runs[two])]
        wall = [r2["fps"] / r1["fps"] for r1, r2 in zip(runs[one], runs[two])]
        loads = [r["load"] for r in runs[one] + runs[two]]
        print(f"scaling {two} / {one}: {statistics.median(steady):.2f} x steady state (median of {len(steady)}; "
              f"each {', '.join(f'{x:.2f}' for x in steady)}), {statistics.median(wall):.2f} x with start-up "
              f"(each {', '.join(f'{x:.2f}' for x in wall)}); "
              f"{statistics.median(r['steady_fps'] for r in runs[two]):.2f} against "
              f"{statistics.median(r['steady_fps'] for r in runs[one]):.2f} frames/s steady, "
              f"{statistics.median(r['fps'] for r in runs[two]):.2f} against "
              f"{statistics.median(r['fps'] for r in runs[one]):.2f} with start-up; load {min(loads):.1f}-{max(loads):.1f}")


def _folders_identical(tmp: Path, setups: list, repeat: int) -> bool:
    """Whether every scaling run wrote the same bytes; the files that differ are named."""
    names = [f"run{i}_{rep}{b}" for i in range(len(setups)) for rep in range(repeat)
             for b in (("", "b") if setups[i][0] == PAIR else ("",))]
    trees = {name: tree(tmp / name) for name in names}
    first = trees[names[0]]
    identical = all(t == first for t in trees.values())
    print(f"folders byte-identical: {identical}")
    for name, t in trees.items():
        differ = sorted(k for k in set(t) | set(first) if t.get(k) != first.get(k))
        if differ:
            label = setups[int(name[3:].split("_")[0])][0]
            print(f"  {label} #{int(name.split('_')[1].rstrip('b')) + 1} differs from {setups[0][0]} #1 in {len(differ)} "
                  f"file(s): {', '.join(differ[:6])}{' ...' if len(differ) > 6 else ''}")
            for rel in [r for r in differ if r.endswith(".png")][:3]:
                print(f"    {rel}: {_png_difference(tmp / names[0] / rel, tmp / name / rel)}")
    return identical


def run_scaling(a, tmp: Path) -> bool:
    """Part 2: frames/s over workers, each set-up in ``a.repeat`` alternating rounds; whether the
    folders are byte-identical."""
    setups, can_pin = _setups(a.dask)
    runs = {label: [] for label, *_ in setups}
    if can_pin:
        _print_core_speeds()
    for rep in range(a.repeat):
        for label, workers, env, dask, one_core in (setups if rep % 2 == 0 else setups[::-1]):
            i = [s[0] for s in setups].index(label)
            if label == PAIR:
                r = run_cold_pair(a.frames, [tmp / f"run{i}_{rep}", tmp / f"run{i}_{rep}b"], a.small, env)
            else:
                r = run_cold(a.frames, tmp / f"run{i}_{rep}", workers, a.small, env, dask=dask, one_core=one_core)
            runs[label].append(r)
            rss = r["rss_self_mb"] if r["executor"] in ("in-process", PAIR) else max(r["rss_self_mb"], r["rss_children_mb"])
            print(f"{label:18s} #{rep + 1}: steady state {r['steady_fps']:.2f} frames/s ({r['steady_frames']} frames); "
                  f"{r['frames']} frames in {r['wall_s']:.1f} s = {r['fps']:.2f} frames/s with start-up "
                  f"(imports {r['imports_s']:.1f} s); {r['executor']}; peak RSS of a worker {rss:.0f} MB; load {r['load']:.1f}")
    _print_ratios(runs, a.dask)
    return _folders_identical(tmp, setups, a.repeat)


def _plot_legs(path: str) -> None:
    from skynav.datasets import preset_recipe as pr
    from skynav.datasets.plots import plot_leg_magnitudes
    from skynav.datasets.recipe_checks import validate_recipe
    from skynav.datasets.samplers import make_plan

    plan = make_plan(validate_recipe(pr("sequence")))
    plot_leg_magnitudes(plan, path)
    print(f"wrote {path}: planets' V along the {plan.s['legs']} legs (pairs {plan.describe()['pairs']})")


def main(argv=None) -> int:
    a = _args(argv)
    from skynav.datasets import generate

    rec = preset_for("montecarlo", a.small)
    identical = True
    print(f"camera {'256 x 256' if a.small else '1024 x 1024'}, stars to V {rec['catalog_limiting_v_mag']}, "
          f"cpu_count {os.cpu_count()}, {a.repeat} repeat(s); load {_load():.1f}")
    with tempfile.TemporaryDirectory(dir=a.dir) as tmp:
        tmp = Path(tmp)
        print(f"datasets written under {tmp}, on {file_system(tmp)}")
        # fill the on-disk caches (catalog, JIT probe, Dr.Jit kernels) so that no run pays for them
        generate(dict(rec, frames=2), tmp / "warm", workers=1, progress=False)
        if not a.no_split:
            run_splits(a, tmp)
        if not a.no_scaling:
            identical = run_scaling(a, tmp)
    if a.plot:
        _plot_legs(a.plot)
    return 0 if identical else 1  # folders that differ are a defect, not a figure


if __name__ == "__main__":
    raise SystemExit(main())
