"""Mitsuba backend speed: an 80 px Moon at 16 spp per variant, and kernels compiled per frame.

Usage::

    python benchmarks/mitsuba_bench.py [--variants scalar_spectral,llvm_ad_spectral] [--frames 5]

Each variant runs in its own subprocess (``mi.set_variant`` is process-global and a bad libLLVM
must not take the benchmark down). For each: the first frame (scene load + JIT compilation), the
median of the next frames, and, for JIT variants, the number of kernels Dr.Jit compiled in each
frame of a 5-frame sequence where the Moon moves and its phase changes (read from
``dr.kernel_history()`` with ``JitFlag.KernelHistory``: "new" = distinct kernel hashes the
process had not launched before (compiled now or loaded from Dr.Jit's on-disk kernel cache),
"launched" = kernel launches in the frame): "new" must be 0 after the first frame, because the
backend reuses one Mitsuba scene and only updates its parameters (the crop's line-of-sight table
is a Dr.Jit array, the sensor rotation and origin opaque variables: never literals in a kernel).

The rays come from the camera as a Projection (``skynav_projection`` sensor: a per-pixel-corner
line-of-sight table). Three alternating runs of 10 frames against the built-in ``perspective``
sensor it replaced (llvm_ad_spectral, 2 cores shared with other jobs, so the spread is load):
median later frame 24-36 ms (perspective: 27-45 ms); first frame 1.0-1.3 s (0.9-1.1 s); new
kernels [9, 0, 0, ...] ([10, 0, 0, ...]); 6 kernel launches per frame (9).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import textwrap

_WORKER = textwrap.dedent(
    r"""
    import json, math, sys, time
    import numpy as np
    sys.path.insert(0, sys.argv[3])
    from tests.renderer.conftest import make_body_scene
    from skynav.renderer import mitsuba_backend as mb
    variant, n_frames = sys.argv[1], int(sys.argv[2])
    mb.current_variant(variant)
    import drjit as dr
    jit = not variant.startswith("scalar")
    if jit:
        dr.set_flag(dr.JitFlag.KernelHistory, True)
        dr.kernel_history()  # clear
    times, kernels, hits, seen = [], [], [], set()
    for k in range(n_frames):
        scene, body = make_body_scene(xy=(400.0 + 7.3 * k, 500.0 - 3.1 * k), diameter_px=80.0,
                                      phase_deg=30.0 + 5.0 * k, distance_km=3.844e5 + 1e3 * k, name="moon",
                                      sun_distance_km=1.5e8 + 1e5 * k)
        t = time.perf_counter()
        img = mb.render_resolved_body(scene, body, spp=16, rng=k, variant=variant)
        times.append(time.perf_counter() - t)
        if jit:
            hist = dr.kernel_history()
            jk = [h for h in hist if h.get("type") == dr.KernelType.JIT]
            # new = a kernel (by hash) this process had not launched before: compiled by
            # LLVM/NVRTC now or loaded from Dr.Jit's on-disk kernel cache
            fresh = {h["hash"] for h in jk} - seen
            kernels.append(len(fresh))
            hits.append(len(jk))
            seen |= fresh
    print("RESULT " + json.dumps({"variant": img.variant, "crop": list(img.electrons.shape), "brdf": img.brdf.kind,
                                  "times_s": times, "kernels_compiled": kernels, "kernel_cache_hits": hits}))
    """
)


def run(variant: str, frames: int, env: dict) -> dict | None:
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    proc = subprocess.run([sys.executable, "-c", _WORKER, variant, str(frames), root], capture_output=True, text=True,
                          env=env, timeout=1800)
    for line in proc.stdout.splitlines():
        if line.startswith("RESULT "):
            return json.loads(line[7:])
    print(f"{variant}: failed (exit {proc.returncode}): {(proc.stderr or proc.stdout).strip().splitlines()[-1:]}")
    return None


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--variants", default=None, help="comma-separated (default: scalar, llvm if it probes OK, cuda if present)")
    ap.add_argument("--frames", type=int, default=5)
    args = ap.parse_args(argv)
    from skynav.renderer import jit_backend

    env = dict(os.environ)
    if args.variants:
        variants = args.variants.split(",")
    else:
        variants = ["scalar_spectral"]
        llvm = jit_backend.configure_llvm()
        if llvm.available:
            variants.append("llvm_ad_spectral")
            env["DRJIT_LIBLLVM_PATH"] = llvm.libllvm
        if jit_backend.probe_cuda().available:
            variants.append("cuda_ad_spectral")
    print(f"80 px Moon (Lommel-Seeliger), 16 spp, {args.frames} frames (moving, changing phase)")
    print(f"{'variant':20s} {'crop':>9s} {'first s':>8s} {'median next s':>14s} {'new kernels per frame':>24s} {'launched':>22s}")
    for v in variants:
        r = run(v, args.frames, env)
        if r is None:
            continue
        t = r["times_s"]
        nxt = sorted(t[1:])[len(t[1:]) // 2] if len(t) > 1 else float("nan")
        k = r["kernels_compiled"] if r["kernels_compiled"] else "n/a (scalar)"
        hk = r["kernel_cache_hits"] if r["kernel_cache_hits"] else ""
        print(f"{r['variant']:20s} {'x'.join(map(str, r['crop'])):>9s} {t[0]:8.3f} {nxt:14.4f} {str(k):>24s} {str(hk):>22s}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
