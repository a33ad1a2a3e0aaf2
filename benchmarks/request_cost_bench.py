"""The render service's cost model (:mod:`skynav.service.budget`) against what requests cost.

A warm worker (:func:`skynav.service.worker.warm_up`, one thread) renders requests that each
stress one part of the model (the frame, a wide Gaussian, a streak, a diffraction PSF's tables,
a field grid of measured PSFs, Mitsuba's samples) at sizes small enough to measure on a shared
machine, and for each prints the model's estimate beside what was measured: the growth of the
process's peak RSS over the render (``VmHWM`` after, less ``VmRSS`` before, the peak reset through
``/proc/self/clear_refs`` first; Linux) and its wall and CPU seconds. The model's constants are
chosen so that each estimate is at or above what is measured (``ratio`` >= 1); the line ``WORST``
gives the smallest ratios. The process runs under an address-space limit (``--as-limit-gb``, 8 by
default) so that a case the model underestimates cannot take the machine down; such a case is
printed as ``MemoryError``.

    python benchmarks/request_cost_bench.py            # every case
    python benchmarks/request_cost_bench.py -k airy    # the cases whose name matches 'airy'
"""

from __future__ import annotations

import argparse
import re
import os
import resource
import tempfile
import time

os.environ.setdefault("SKYNAV_THREADS", "1")

import numpy as np  # noqa: E402


def _status() -> dict:
    with open("/proc/self/status") as f:
        d = dict(line.split(":", 1) for line in f)
    return {k: int(d[k].split()[0]) * 1024 for k in ("VmRSS", "VmHWM", "VmSize")}


def _scene(name="default", size=64, camera=None, render=None, attitude=None):
    from skynav.scenes.presets import preset_mapping

    m = preset_mapping(name)
    m["camera"].update({"width": size, "height": size, **(camera or {})})
    m.setdefault("render", {}).update(render or {})
    m["attitude"].update(attitude or {})
    return m


def cases(data_dir: str) -> dict:
    """``{name: request mapping}``: each stresses one part of the model."""
    out = {f"frame {n}": _scene(size=n) for n in (256, 1024, 2048, 4096)}
    for s in (20, 50, 100):
        out[f"gaussian sigma {s}"] = _scene(camera={"psf": {"model": "gaussian", "sigma_px": s}})
    for s in (50, 100):
        out[f"defocus {s}"] = _scene(camera={"defocus_sigma_px": s})
    for t in (2, 5):
        out[f"streak {t} s 1 deg/s 1024"] = _scene(size=1024, camera={"exposure_s": t},
                                                   attitude={"angular_velocity_deg_s": [1.0, 0.0, 0.0]})
    for h, size in ((16, 64), (32, 64), (32, 256), (64, 64)):
        out[f"airy half {h} at {size}"] = _scene(size=size, camera={"psf": {"model": "airy", "max_half_px": h}})
    y, x = np.mgrid[-64:65, -64:65]
    np.save(os.path.join(data_dir, "psf.npy"), np.exp(-(x**2 + y**2) / 50.0))
    for g in (2, 4):
        field = [{"x_px": float(i * 20), "y_px": float(j * 20), "file": "psf.npy"} for j in range(g) for i in range(g)]
        out[f"tabulated grid {g}x{g}"] = _scene(camera={"psf": {"model": "tabulated", "oversampling": 2, "field": field}})
    for spp, size in ((64, 256), (1024, 256)):
        out[f"mitsuba earth {spp} spp at {size}"] = _scene("earth_departure", size=size, render={"mitsuba_spp": spp})
    for spp in (64, 256, 1024):   # the observer 10 times nearer: a 308 px Earth, a 340 x 340 crop
        m = _scene("earth_departure", size=256, render={"mitsuba_spp": spp})
        m["observer"]["position_km"] = [0.1 * x for x in m["observer"]["position_km"]]
        out[f"mitsuba near earth {spp} spp at 256"] = m
    return out


def measure(name: str, mapping: dict, data_dir: str) -> dict:
    """The estimate and the measured peak growth and seconds of one request."""
    from skynav.renderer.render import RenderOptions
    from skynav.scenes.config import scene_spec_from_mapping
    from skynav.scenes.scene import build_from_spec
    from skynav.service.budget import estimate
    from skynav.service.files import request_files
    from skynav.service.worker import render_outputs

    with request_files((data_dir,), 1 << 24):
        spec = scene_spec_from_mapping(mapping)
        scene = build_from_spec(spec)
        parts = estimate(scene, RenderOptions(noise=True, backend="auto", mitsuba_spp=spec.mitsuba_spp), mapping)
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
        before = _status()
        t0, c0 = time.perf_counter(), time.process_time()
        try:
            render_outputs(mapping, ("png", "truth"))
            error = ""
        except MemoryError:
            error = "MemoryError"
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        after = _status()
    est_b, est_s = sum(p.bytes for p in parts), sum(p.seconds for p in parts)
    grew = after["VmHWM"] - before["VmRSS"]
    return {"name": name, "est_mb": est_b / 1e6, "peak_mb": grew / 1e6, "est_s": est_s, "wall_s": wall, "cpu_s": cpu,
            "ratio_b": est_b / max(grew, 1.0), "ratio_s": est_s / max(cpu, 1e-3), "error": error,
            "top": max(parts, key=lambda p: p.bytes).key,
            "bodies": " ".join(f"{b.name} {b.angular_diameter_px:.0f} px" for b in scene.bodies if b.resolved)}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("-k", default="", help="only the cases whose name matches this regular expression")
    ap.add_argument("--as-limit-gb", type=float, default=8.0, help="address-space limit of this process, GB")
    args = ap.parse_args(argv)
    from skynav.service.worker import warm_up

    warm_s = warm_up()
    limit = int(args.as_limit_gb * 1e9)
    resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
    print(f"warm in {warm_s:.1f} s; worker RSS {_status()['VmRSS'] / 1e6:.0f} MB, address space "
          f"{_status()['VmSize'] / 1e6:.0f} MB; load {os.getloadavg()[0]:.1f}")
    print(f"{'case':34s} {'est MB':>8s} {'peak MB':>8s} {'ratio':>6s} {'est s':>7s} {'cpu s':>7s} {'wall s':>7s} "
          f"{'ratio':>6s}  largest part")
    rows = []
    with tempfile.TemporaryDirectory() as data_dir:
        for name, mapping in cases(data_dir).items():
            if not re.search(args.k, name):
                continue
            r = measure(name, mapping, data_dir)
            rows.append(r)
            print(f"{r['name']:34s} {r['est_mb']:8.1f} {r['peak_mb']:8.1f} {r['ratio_b']:6.2f} {r['est_s']:7.3f} "
                  f"{r['cpu_s']:7.3f} {r['wall_s']:7.3f} {r['ratio_s']:6.2f}  {r['top']} {r['error']} {r['bodies']}", flush=True)
    if rows:
        print(f"WORST memory ratio {min(r['ratio_b'] for r in rows):.2f}, time ratio {min(r['ratio_s'] for r in rows):.2f}; "
              f"load {os.getloadavg()[0]:.1f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
