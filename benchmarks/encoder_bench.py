"""What the PNG and EXR writers' fast paths save of a dataset frame, against their references.

    python benchmarks/encoder_bench.py [--frames N] [--warmup W] [--small]

In one process on one thread (``SKYNAV_THREADS=1``), the Monte Carlo preset's frames are
rendered and each is encoded by both paths, CPU time (``time.process_time``) of each:

* PNG: :func:`skynav.datasets.png_rle.png_rle_bytes` (unfiltered rows, zlib-ng ``Z_RLE``)
  against :func:`~skynav.datasets.png_rle.reference_png_bytes` (Pillow's writer);
* EXR: the sparse RLE encoder (:mod:`skynav.datasets.exr_rle`) against OpenEXR's own RLE
  encoder (``_exr_bytes(..., sparse=False)``).

The frame is its render plus its three files encoded by the references (PNG, EXR, JSON); a fast
path's **share** is (reference - fast) / that frame, median over ``--frames`` frames after
``--warmup`` (Dr.Jit compiles its kernels, caches fill). A fast path earns its place at a share
of 5 % or more. Every pair is also decoded and compared (the same pixels, or the script exits
with 1).
"""

from __future__ import annotations

import argparse
import io
import os
import statistics
import time

os.environ.setdefault("SKYNAV_THREADS", "1")


def _cpu(fn, *args, **kw):
    t = time.process_time()
    out = fn(*args, **kw)
    return out, time.process_time() - t


def _frames(n: int, warmup: int, small: bool):
    """Rendered frames of the Monte Carlo preset, after ``warmup`` left out, and each render's CPU s."""
    import numpy as np

    from skynav.datasets import preset_recipe
    from skynav.datasets.plan import frame_seed
    from skynav.datasets.recipe_checks import validate_recipe
    from skynav.datasets.samplers import make_plan
    from skynav.renderer.render import render
    from skynav.scenes.scene import build_scene

    rec = preset_recipe("montecarlo")
    if small:
        rec["camera"] = {"preset": "paper", "width": 256, "height": 256, "fov_deg": 20.0}
        rec["catalog_limiting_v_mag"] = 7.0
    rec = validate_recipe(dict(rec, frames=n + warmup))
    plan = make_plan(rec)
    for k in range(n + warmup):
        ss = frame_seed(rec["seed"], k)
        rng = np.random.default_rng(ss)
        req = plan.frame_request(k, rng)
        scene = build_scene(req.epoch_tdb_s, position_km=req.position_km, velocity_km_s=req.velocity_km_s,
                            R_cam_icrs=req.R_cam_icrs, camera=plan.camera,
                            catalog_limiting_v_mag=rec["catalog_limiting_v_mag"],
                            angular_velocity_rad_s=req.angular_velocity_rad_s, visibility=plan.visibility, sky=req.sky)
        frame, cpu = _cpu(render, scene, seed=ss, rng=rng)
        if k >= warmup:
            yield frame, cpu


def _decoded_png(data):
    import numpy as np
    from PIL import Image

    with Image.open(io.BytesIO(data)) as im:
        return np.array(im)


def measure(n: int, warmup: int, small: bool) -> dict:
    """``{figure: [per frame]}``: CPU s of the render, the JSON, and each encoder; whether every
    pair decoded to the same pixels."""
    import numpy as np

    from skynav.datasets.frame_files import PNG_SCALING, PNG_SCALING_KEY, _exr_bytes, read_exr, scale_dn_to_png
    from skynav.datasets.png_rle import png_rle_bytes, reference_png_bytes
    from skynav.datasets.truth_schema import truth_json_bytes

    cost = {k: [] for k in ("render", "json", "png_fast", "png_ref", "exr_fast", "exr_ref")}
    same = True
    for frame, render_cpu in _frames(n, warmup, small):
        cost["render"].append(render_cpu)
        cost["json"].append(_cpu(truth_json_bytes, frame.truth)[1])
        bits = frame.truth["camera"]["bit_depth"]
        stored = scale_dn_to_png(frame.dn, bits)
        sbit = bits if bits not in (8, 16) else None
        text = ((PNG_SCALING_KEY, PNG_SCALING),) if sbit else ()
        fast, cost_fast = _cpu(png_rle_bytes, stored, 6, sbit=sbit, text=text)
        ref, cost_ref = _cpu(reference_png_bytes, stored, 6, sbit=sbit, text=text)
        cost["png_fast"].append(cost_fast)
        cost["png_ref"].append(cost_ref)
        same &= np.array_equal(_decoded_png(fast), _decoded_png(ref))
        channels = {"electrons": frame.electrons, "irradiance_w_m2": frame.irradiance_w_m2}
        fast, cost_fast = _cpu(_exr_bytes, channels, None)
        ref, cost_ref = _cpu(_exr_bytes, channels, None, sparse=False)
        cost["exr_fast"].append(cost_fast)
        cost["exr_ref"].append(cost_ref)
        a, b = read_exr(io.BytesIO(fast)), read_exr(io.BytesIO(ref))
        same &= all(np.array_equal(a[c].view(np.uint32), b[c].view(np.uint32)) for c in channels)
    return {"cost": cost, "same": same}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=20, help="frames measured (default 20)")
    ap.add_argument("--warmup", type=int, default=3, help="frames left out first (default 3)")
    ap.add_argument("--small", action="store_true", help="256 x 256 camera, stars to V 7 (the tests' recipe)")
    a = ap.parse_args(argv)
    r = measure(a.frames, a.warmup, a.small)
    c = r["cost"]
    frame = [sum(v[i] for v in (c["render"], c["json"], c["png_ref"], c["exr_ref"])) for i in range(a.frames)]
    med = {k: statistics.median(v) for k, v in c.items()}
    print(f"{a.frames} Monte Carlo frames ({'256 x 256' if a.small else '1024 x 1024'}), 1 thread, CPU ms, medians: "
          f"render {med['render'] * 1e3:.1f}, JSON {med['json'] * 1e3:.1f}; frame with the references "
          f"{statistics.median(frame) * 1e3:.1f}; load {os.getloadavg()[0]:.1f}")
    for fmt, name in (("png", "PNG (zlib-ng Z_RLE, unfiltered) against Pillow"),
                      ("exr", "EXR (sparse RLE) against OpenEXR's RLE")):
        share = [(r_ - f) / fr for f, r_, fr in zip(c[f"{fmt}_fast"], c[f"{fmt}_ref"], frame)]
        print(f"{name}: {med[f'{fmt}_fast'] * 1e3:.2f} against {med[f'{fmt}_ref'] * 1e3:.2f} ms; "
              f"saves {100 * statistics.median(share):.1f} % of the frame")
    print(f"decoded pixels identical: {r['same']}")
    return 0 if r["same"] else 1


if __name__ == "__main__":
    raise SystemExit(main())
