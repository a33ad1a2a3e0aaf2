"""Mitsuba backend speed: an 80 px Moon (88 x 88 crop) at 16 spp per variant and sensor, against
the backend before the projection sensor, and kernels compiled per frame.

Usage::

    python benchmarks/mitsuba_bench.py [--variants scalar_spectral,llvm_ad_spectral] [--frames 5]
                                       [--rounds 3] [--baseline eda9324^] [--threads 1]

For each variant three codes render the same frames, each in its own subprocess
(``mi.set_variant`` is process-global and a bad libLLVM must not take the benchmark down), the
three alternating ``--rounds`` times so that the machine's load falls on each alike:

- ``perspective``: this tree for the paper camera, a plain pinhole, which takes Mitsuba's
  built-in ``perspective`` sensor (``render_resolved_body(sensor="auto")``);
- ``projection``: this tree with the ``skynav_projection`` line-of-sight table forced, the sensor
  every other projection (distortion, fx != fy, a bench screen) takes;
- ``baseline``: the backend as it was at ``--baseline`` (default ``eda9324^``, the commit before
  the projection sensor replaced the perspective one: ``git log -S skynav_projection``), read with
  ``git archive`` into a temporary folder and imported from there.

Printed per code: the first frame (scene load + JIT compilation) and the medians of the later
frames' wall and CPU time (this process's threads; ``--threads`` sets Dr.Jit's pool, which
renders the scalar variant's blocks too: 1 by default, so that CPU time is the figure to compare
on a shared machine), and the ratios to the baseline. For JIT variants the kernels Dr.Jit
compiled in each frame of the first round (read from ``dr.kernel_history()`` with
``JitFlag.KernelHistory``: "new" = distinct kernel hashes the process had not launched before
(compiled now or loaded from Dr.Jit's on-disk kernel cache), "launched" = kernel launches in the
frame): "new" must be 0 after the first frame, because the backend reuses one Mitsuba scene and
only updates its parameters (the sensor's pose, the crop's line-of-sight table, the body's and
the Sun's transforms: never literals in a kernel).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tarfile
import tempfile
import textwrap
import tomllib
from pathlib import Path

_WORKER = textwrap.dedent(
    r"""
    import json, math, sys, time
    root, site = sys.argv[3], sys.argv[4]
    sys.path.insert(0, root)
    if site:
        sys.path.insert(0, site)  # the baseline's skynav package, ahead of the installed one
    import numpy as np
    from tests.renderer.conftest import make_body_scene
    from skynav.renderer import mitsuba_backend as mb
    variant, n_frames, sensor = sys.argv[1], int(sys.argv[2]), sys.argv[5]
    assert mb.__file__.startswith(site or root), (mb.__file__, site, root)
    mb.current_variant(variant)
    import drjit as dr
    if int(sys.argv[6]) > 0:
        dr.set_thread_count(int(sys.argv[6]))
    kw = {} if sensor == "default" else {"sensor": sensor}
    jit = not variant.startswith("scalar")
    if jit:
        dr.set_flag(dr.JitFlag.KernelHistory, True)
        dr.kernel_history()  # clear
    wall, cpu, kernels, hits, seen = [], [], [], [], set()
    for k in range(n_frames):
        scene, body = make_body_scene(xy=(400.0 + 7.3 * k, 500.0 - 3.1 * k), diameter_px=80.0,
                                      phase_deg=30.0 + 5.0 * k, distance_km=3.844e5 + 1e3 * k, name="moon",
                                      sun_distance_km=1.5e8 + 1e5 * k)
        t, c = time.perf_counter(), time.process_time()
        img = mb.render_resolved_body(scene, body, spp=16, rng=k, variant=variant, **kw)
        wall.append(time.perf_counter() - t)
        cpu.append(time.process_time() - c)
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
                                  "sensor": getattr(img, "sensor", "perspective"), "wall_s": wall, "cpu_s": cpu,
                                  "kernels_compiled": kernels, "kernel_cache_hits": hits}))
    """
)

ROOT = Path(__file__).resolve().parent.parent


def baseline_site(commit: str, tmp: Path) -> tuple[str, str] | str:
    """Extract ``commit`` of this repository into ``tmp`` and lay its packages out as ``skynav``.

    Returns (tree root, folder to put first on sys.path), or one line saying why not.
    """
    tree = tmp / "tree"
    tree.mkdir()
    archive = tmp / "tree.tar"
    try:
        with open(archive, "wb") as f:
            subprocess.run(["git", "-C", str(ROOT), "archive", commit], stdout=f, stderr=subprocess.PIPE, check=True, timeout=120)
    except (OSError, subprocess.SubprocessError) as exc:
        return f"cannot read {commit} with git archive ({exc})"
    with tarfile.open(archive) as tar:
        tar.extractall(tree, filter="data")
    mapping = tomllib.loads((tree / "pyproject.toml").read_text())["tool"]["setuptools"]["package-dir"]
    site = tmp / "site"
    (site / "skynav").mkdir(parents=True)
    for name, folder in sorted(mapping.items()):
        parts = name.split(".")
        if parts == ["skynav"]:
            for p in (tree / folder).iterdir():
                if p.suffix == ".py":
                    (site / "skynav" / p.name).symlink_to(p)
        else:
            (site / "skynav" / parts[1]).symlink_to(tree / folder, target_is_directory=True)
    return str(tree), str(site)


def run(variant: str, frames: int, env: dict, root: str, site: str, sensor: str, threads: int) -> dict | str:
    proc = subprocess.run([sys.executable, "-c", _WORKER, variant, str(frames), root, site, sensor, str(threads)],
                          capture_output=True, text=True, env=env, timeout=1800)
    for line in proc.stdout.splitlines():
        if line.startswith("RESULT "):
            return json.loads(line[7:])
    return f"failed (exit {proc.returncode}): {(proc.stderr or proc.stdout).strip().splitlines()[-1:]}"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--variants", default=None, help="comma-separated (default: scalar, llvm if it probes OK, cuda if present)")
    ap.add_argument("--frames", type=int, default=5, help="frames per code and round (the first is not in the medians)")
    ap.add_argument("--rounds", type=int, default=3, help="alternating rounds of the three codes")
    ap.add_argument("--baseline", default="eda9324^", help="commit of the backend before the projection sensor")
    ap.add_argument("--threads", type=int, default=1, help="Dr.Jit / Mitsuba threads per process (0: one per core)")
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
    load = os.getloadavg()
    print(f"80 px Moon (Lommel-Seeliger), 16 spp, {args.frames} frames (moving, changing phase) x {args.rounds} rounds, "
          f"{args.threads or 'all'} thread(s); load average {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}")
    with tempfile.TemporaryDirectory(prefix="mitsuba-bench-") as tmp:
        base = baseline_site(args.baseline, Path(tmp))
        codes = [("perspective", str(ROOT), "", "auto"), ("projection", str(ROOT), "", "projection")]
        if isinstance(base, str):
            print(f"baseline {args.baseline}: {base}")
        else:
            codes.append((f"baseline {args.baseline}", base[0], base[1], "default"))
        print(f"{'variant':18s} {'code':20s} {'sensor':12s} {'crop':>6s} {'first s':>8s} {'median next s':>14s} {'CPU s':>7s}"
              f" {'/ baseline':>11s}  new kernels per frame (launched)")
        for v in variants:
            res: dict = {}
            for _ in range(args.rounds):
                for name, root, site, sensor in codes:
                    r = run(v, args.frames, env, root, site, sensor, args.threads)
                    if isinstance(r, str):
                        res[name] = r
                        continue
                    if isinstance(res.get(name), str):
                        continue
                    acc = res.setdefault(name, {"first": [], "wall": [], "cpu": [], "r": r})
                    acc["first"].append(r["wall_s"][0])
                    acc["wall"] += r["wall_s"][1:]
                    acc["cpu"] += r["cpu_s"][1:]
            base_key = next((k for k in res if k.startswith("baseline")), None)
            for name, _, _, _ in codes:
                acc = res.get(name)
                if acc is None:
                    continue
                if isinstance(acc, str):
                    print(f"{v:18s} {name:20s} {acc}")
                    continue
                r = acc["r"]
                wall, cpu = statistics.median(acc["wall"]), statistics.median(acc["cpu"])
                ratio = ""
                if base_key and not isinstance(res[base_key], str):
                    b = res[base_key]
                    ratio = f"{wall / statistics.median(b['wall']):5.2f}|{cpu / statistics.median(b['cpu']):4.2f}"
                k = f"{r['kernels_compiled']} ({r['kernel_cache_hits']})" if r["kernels_compiled"] else "n/a (scalar)"
                print(f"{r['variant']:18s} {name:20s} {r['sensor']:12s} {'x'.join(map(str, r['crop'])):>6s} "
                      f"{statistics.median(acc['first']):8.3f} {wall:14.4f} {cpu:7.4f} {ratio:>11s}  {k}")
    print("/ baseline: median later frame, wall|CPU, to the baseline's in the same run")
    return 0


if __name__ == "__main__":
    sys.exit(main())
