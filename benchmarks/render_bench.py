"""Speed of one default frame: 1024^2, stars to V = 9, full noise chain, no disk writes.

Prints the median time of ``render`` (scene already built: catalog, ephemeris and radiometry
tables warm) for the Dr.Jit LLVM sensor path and the numpy path, numpy's bare variate cost for
one Poisson + one Gaussian per pixel, the three taking turns in one run, and the ratios, each
as wall time and as CPU time (compare CPU times on a machine other processes share), with the
load average. One thread: the CI machine's single core is the reference (``DRJIT_NUM_THREADS=1``
is set below).

    python benchmarks/render_bench.py [--repeat 15]
    python benchmarks/render_bench.py --psf airy [--repeat 15] [--size 1024]

``--psf MODEL`` (airy, airy-poly, optical, tabulated, field; see ``psf_bench.py``) times the
default frame drawn with that PSF against the Gaussian frame, interleaved in the same run, a new
frame each round, and prints the ratio (the measurement of ``psf_bench.py``).
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("DRJIT_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402

PSF_CHOICES = ("airy", "airy-h10", "airy-poly", "optical", "tabulated", "field")


def median_ms(fns: dict, repeat):
    """Median wall time and median CPU time (this process, all threads) of each function, ms,
    the functions taking turns (one call of each per round), so that a change of the machine's
    load falls on all of them alike.

    The CPU time is the figure to compare on a shared machine: other processes stretch the wall
    time of a one-thread run, not the CPU time it needs.
    """
    for fn in fns.values():
        fn()  # warm-up (tables, kernels)
    wall = {k: [] for k in fns}
    cpu = {k: [] for k in fns}
    for _ in range(repeat):
        for k, fn in fns.items():
            t0, c0 = time.perf_counter(), time.process_time()
            fn()
            wall[k].append(time.perf_counter() - t0)
            cpu[k].append(time.process_time() - c0)
    return {k: (1e3 * float(np.median(wall[k])), 1e3 * float(np.median(cpu[k]))) for k in fns}


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=15)
    ap.add_argument("--psf", metavar="MODEL", choices=PSF_CHOICES,
                    help=f"time the frame with this PSF against the Gaussian one: {', '.join(PSF_CHOICES)}")
    ap.add_argument("--size", type=int, default=1024, help="with --psf: image width = height, px (default 1024)")
    args = ap.parse_args()
    if args.psf is not None:
        import psf_bench  # this folder's, the same measurement

        name = {"field": "tabulated-field"}.get(args.psf, args.psf)
        psf_bench.report(psf_bench.measure(["gaussian", name], args.repeat, args.size), args.repeat, args.size, False)
        return

    from skynav.renderer import jit_backend
    from skynav.renderer.render import RenderOptions, render
    from skynav.scenes import presets
    from skynav.scenes.scene import build_from_spec

    status = jit_backend.configure_llvm()
    try:
        import drjit as dr

        dr.set_thread_count(1)
    except Exception:
        pass
    t0 = time.perf_counter()
    scene = build_from_spec(presets.default_scene_spec())
    t_scene = time.perf_counter() - t0
    n_stars = int(scene.stars.in_fov.sum())
    rng = np.random.default_rng(1)

    n = scene.camera.width * scene.camera.height
    lam = np.full(n, 20.0)

    def variates():
        rng.poisson(lam)
        rng.standard_normal(n)

    fns = {}
    for backend in ("llvm", "numpy"):
        if backend == "llvm" and not status.available:
            print(f"llvm path: unavailable ({status.reason})")
            continue
        opts = RenderOptions(backend=backend)
        fns[backend] = lambda opts=opts: render(scene, rng=rng, options=opts)
    fns["variates"] = variates
    results = median_ms(fns, args.repeat)
    numpy_variates = results.pop("variates")
    load = os.getloadavg()
    print(f"default frame: {scene.camera.width}x{scene.camera.height}, {n_stars} stars in view (V <= {scene.catalog_limiting_v_mag:g}), "
          f"full noise, no disk writes; scene build {1e3 * t_scene:.0f} ms (not counted); medians of {args.repeat}, wall | CPU; "
          f"load average {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}")
    print(f"numpy variates (1 Poisson + 1 Gaussian per pixel): {numpy_variates[0]:8.1f} ms | {numpy_variates[1]:8.1f} ms CPU")
    for k, (w, c) in results.items():
        print(f"render, {k:5s} sensor path:                     {w:8.1f} ms | {c:8.1f} ms CPU   "
              f"ratio to numpy variates {w / numpy_variates[0]:5.2f} | {c / numpy_variates[1]:5.2f} CPU")
    if "llvm" in results and "numpy" in results:
        print(f"llvm path speed-up over numpy path: {results['numpy'][0] / results['llvm'][0]:.2f}x | "
              f"{results['numpy'][1] / results['llvm'][1]:.2f}x CPU")


if __name__ == "__main__":
    main()
