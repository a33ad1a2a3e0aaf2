"""Speed on one GPU: the default frame and the Monte Carlo preset with the sensor on Dr.Jit's CUDA
backend, against the CPU's sensor paths, measured in one run.

    python benchmarks/gpu_bench.py [--repeat 15] [--workers 1 16] [--frames-per-worker 40]
                                   [--backends cuda llvm numpy] [--batch [--batch-sizes 1 2 4 ... 256]]

1. **Default frame** (1024^2, stars to V 9, full noise, no disk writes): ``render`` with each
   sensor backend (``cuda``; ``llvm`` where libLLVM >= 19 works; ``numpy``), the backends taking
   turns, medians of the wall time; and the sensor alone (``Sensor.expose`` of that frame's
   electrons: the image's copies to the GPU and back included). One process; Dr.Jit's CPU pool
   and numpy's of one thread, as in ``render_bench.py``.
2. **Monte Carlo preset**: ``generate(preset, workers=W, render_options=RenderOptions(backend=B))``
   (``dataset_bench.py``'s child process: sample, render, encode, write, checksums), the
   steady-state frames/s for each ``W`` of ``--workers`` and each backend ``B``. The ``W`` workers
   share the one GPU, each with a CUDA context of its own. Resolved bodies are ray-traced by the
   variant the renderer picks: ``cuda_ad_spectral`` wherever CUDA works (the first line says).

3. **Batched frames** (``--batch``): ``batch_bench.py``'s measurement (its CPU twin) on the first
   Dr.Jit backend of ``--backends``: frames/s of ``render_batch`` for each batch size at 256, 512
   and 1024 px, in memory and written as PNG + truth JSON, with the per-frame stage split,
   against the per-frame path in the same run; ``nvidia-smi``'s GPU utilisation is sampled while
   it runs.

Every figure is printed with the GPU's name, the cores and the load average. Without a working
CUDA backend (and ``cuda`` among ``--backends``) the script says why in one line and exits with 2;
``--backends llvm numpy`` runs the same measurements on a machine without a GPU.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("DRJIT_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).parent))
from dataset_bench import run_cold  # noqa: E402  (this folder's: the same child process)
from render_bench import median_ms  # noqa: E402

BACKENDS = ("cuda", "llvm", "numpy")


def gpu_name() -> str:
    exe = shutil.which("nvidia-smi")
    if exe is None:
        return "no nvidia-smi"
    out = subprocess.run([exe, "--query-gpu=name,memory.total,driver_version", "--format=csv,noheader"],
                         capture_output=True, text=True, check=False).stdout.strip()
    return out.splitlines()[0] if out else "nvidia-smi printed nothing"


def usable(backends) -> list:
    """The backends of ``backends`` that work here; exits with 2 for a CUDA that does not."""
    from skynav.renderer import jit_backend

    ok = []
    for b in backends:
        status = jit_backend.probe_cuda() if b == "cuda" else jit_backend.configure_llvm() if b == "llvm" else None
        if status is not None and not status.available:
            if b == "cuda":
                print(f"gpu_bench: Dr.Jit's CUDA backend does not work here ({status.reason}); "
                      "run with --backends llvm numpy for the CPU's figures", file=sys.stderr)
                raise SystemExit(2)
            print(f"{b} sensor path: unavailable ({status.reason})")
            continue
        ok.append(b)
    return ok


def default_frame(backends, repeat: int) -> None:
    from skynav.renderer import jit_backend
    from skynav.renderer.detector import Sensor
    from skynav.renderer.render import RenderOptions, render
    from skynav.renderer.sparse_images import float32_image
    from skynav.scenes import presets
    from skynav.scenes.scene import build_from_spec

    scene = build_from_spec(presets.default_scene_spec())
    cam = scene.camera
    rng = np.random.default_rng(1)
    electrons = float32_image(render(scene, seed=1, options=RenderOptions(noise=False)).electrons, None)
    sensor = Sensor(cam.sensor, (cam.height, cam.width))
    frames, sensors = {}, {}
    for b in backends:
        opts = RenderOptions(backend=b)
        frames[b] = lambda opts=opts: render(scene, rng=rng, options=opts)
        sensors[b] = lambda b=b: sensor.expose(electrons, cam.exposure_s, rng, backend=b)
    frame_ms = median_ms(frames, repeat)
    sensor_ms = median_ms(sensors, repeat)
    variant = jit_backend.select_mitsuba_variant()[0]
    print(f"default frame {cam.width}x{cam.height}, {int(scene.stars.in_fov.sum())} stars, full noise, no disk writes; "
          f"medians of {repeat}, backends taking turns; Mitsuba variant here: {variant}")
    base = frame_ms[backends[-1]][0]
    for b in backends:
        (fw, _), (sw, _) = frame_ms[b], sensor_ms[b]
        print(f"  sensor {b:5s}: frame {fw:7.1f} ms = {1e3 / fw:6.1f} frames/s ({base / fw:5.2f}x the {backends[-1]} frame); "
              f"the sensor alone {sw:6.2f} ms")


def monte_carlo(backends, workers, per_worker: int, small: bool) -> None:
    print(f"Monte Carlo preset{' (small)' if small else ''}: generate(), steady-state frames/s "
          f"({per_worker} frames a worker plus 60; sample, render, encode, write):")
    rates = {}
    with tempfile.TemporaryDirectory() as d:
        for w in workers:
            for i, b in enumerate(backends if w % 2 else backends[::-1]):
                frames = 60 + per_worker * w
                r = run_cold(frames, Path(d) / f"w{w}_{b}", w, small, {}, backend=b)
                rates[(w, b)] = r["steady_fps"]
                print(f"  {w:2d} worker{'s' if w > 1 else ' '}, sensor {b:5s}: {r['steady_fps']:7.1f} frames/s steady "
                      f"({r['frames']} frames, {r['wall_s']:.1f} s with start-up; worker RSS "
                      f"{max(r['rss_self_mb'], r['rss_children_mb']):.0f} MB; load {r['load']:.1f})")
                shutil.rmtree(Path(d) / f"w{w}_{b}", ignore_errors=True)
    for w in workers:
        line = ", ".join(f"{b} / {backends[-1]} {rates[(w, b)] / rates[(w, backends[-1])]:.2f}x" for b in backends[:-1])
        if line:
            print(f"  {w} worker{'s' if w > 1 else ''}: {line}")


def gpu_utilisation() -> str:
    """``nvidia-smi``'s GPU utilisation now, %, or why there is none."""
    exe = shutil.which("nvidia-smi")
    if exe is None:
        return "no nvidia-smi"
    out = subprocess.run([exe, "--query-gpu=utilization.gpu", "--format=csv,noheader"], capture_output=True, text=True,
                         check=False).stdout.strip()
    return out.splitlines()[0] if out else "nvidia-smi printed nothing"


def batched_frames(backend, sizes, pxs) -> None:
    """``batch_bench.py``'s measurement on ``backend``, GPU utilisation sampled every second."""
    import threading

    from batch_bench import measure  # this folder's: the CPU twin's measurement

    if backend is None:
        print("batched frames: no Dr.Jit backend among --backends")
        return
    samples, done = [], threading.Event()

    def sample():
        while not done.wait(1.0):
            samples.append(gpu_utilisation())

    watcher = threading.Thread(target=sample, daemon=True)
    watcher.start()
    try:
        for px in pxs:
            measure(px, sizes, 3, True, 32, backend)
    finally:
        done.set()
        watcher.join()
    used = [float(s.split()[0]) for s in samples if s.split() and s.split()[0].replace(".", "").isdigit()]
    print(f"batched frames on {backend}: nvidia-smi GPU utilisation while measuring: "
          + (f"median {np.median(used):.0f} %, max {max(used):.0f} % ({len(used)} samples)" if used
             else (samples[-1] if samples else "not sampled")))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=15, help="default frame: rounds (default 15)")
    ap.add_argument("--workers", type=int, nargs="+", default=[1, os.cpu_count() or 1],
                    help="Monte Carlo: worker counts (default 1 and the cores)")
    ap.add_argument("--frames-per-worker", type=int, default=40, help="Monte Carlo: frames a worker, plus 60 (default 40)")
    ap.add_argument("--backends", nargs="+", choices=BACKENDS, default=list(BACKENDS),
                    help="sensor backends, compared with the last (default: cuda llvm numpy)")
    ap.add_argument("--small", action="store_true", help="Monte Carlo on a 256 x 256 camera (the tests' recipe)")
    ap.add_argument("--no-monte-carlo", action="store_true", help="only the default frame")
    ap.add_argument("--batch", action="store_true", help="also the batched frames (batch_bench.py's measurement)")
    ap.add_argument("--batch-sizes", type=int, nargs="+", default=[1, 2, 4, 8, 16, 32, 64, 128, 256],
                    help="with --batch: batch sizes (default 1 .. 256)")
    ap.add_argument("--batch-px", type=int, nargs="+", default=[256, 512, 1024],
                    help="with --batch: image sizes (default 256 512 1024)")
    a = ap.parse_args(argv)
    backends = usable(a.backends)
    print(f"{gpu_name()}; {os.cpu_count()} cores; load average {' '.join(f'{x:.1f}' for x in os.getloadavg())}; "
          f"{time.strftime('%Y-%m-%d %H:%M')}")
    default_frame(backends, a.repeat)
    if not a.no_monte_carlo:
        monte_carlo(backends, a.workers, a.frames_per_worker, a.small)
    if a.batch:
        batched_frames(next((b for b in backends if b != "numpy"), None), a.batch_sizes, a.batch_px)
    return 0


if __name__ == "__main__":
    sys.exit(main())
