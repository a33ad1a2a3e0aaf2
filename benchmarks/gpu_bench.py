"""Speed on one GPU: the default frame and the Monte Carlo preset with the sensor on Dr.Jit's CUDA
backend, against the CPU's sensor paths, measured in one run.

    python benchmarks/gpu_bench.py [--repeat 15] [--workers 1 16] [--frames-per-worker 40]
                                   [--backends cuda llvm numpy]

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
    from skynav.scenes import presets
    from skynav.scenes.scene import build_from_spec

    scene = build_from_spec(presets.default_scene_spec())
    cam = scene.camera
    rng = np.random.default_rng(1)
    electrons = render(scene, seed=1, options=RenderOptions(noise=False)).electrons.astype(np.float32)
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
    a = ap.parse_args(argv)
    backends = usable(a.backends)
    print(f"{gpu_name()}; {os.cpu_count()} cores; load average {' '.join(f'{x:.1f}' for x in os.getloadavg())}; "
          f"{time.strftime('%Y-%m-%d %H:%M')}")
    default_frame(backends, a.repeat)
    if not a.no_monte_carlo:
        monte_carlo(backends, a.workers, a.frames_per_worker, a.small)
    return 0


if __name__ == "__main__":
    sys.exit(main())
