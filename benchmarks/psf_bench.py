"""Speed of each PSF model: the default frame (1024^2, stars to V = 9, full noise) per model.

For each model prints the one-off table build (once per camera, cached; not in the frame time),
the stamp half size (a table kernel's, and in brackets the median star's: a faint star's stamp
is sized by its charge, ``TableKernel.half_sizes_px``), and the median wall and CPU time of ``render`` with the ratio to the
Gaussian frame measured in the same run. One thread (``DRJIT_NUM_THREADS=1``), as
``render_bench.py``. The tabulated models read PSF images this script writes to a temporary
folder (a coma PSF at 4 samples/px; a 3 x 3 field grid of them with the coma growing outwards).

    python benchmarks/psf_bench.py [--repeat 9] [--models gaussian,airy,...] [--size 1024] [--same-scene]

The models are timed in interleaved rounds (one frame of each per round), so a busy moment of a
shared machine slows all of them alike; the table build includes one first frame. Each round
turns the camera about its boresight by another 1e-3 rad (the same stars at other sub-pixel
phases), as the frames of a dataset differ: a table kernel keeps its last stamps for the
frame's irradiance pass, and ``--same-scene`` (every round the same frame) lets them be reused
from one frame to the next, which no dataset does.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import tempfile
import time

os.environ.setdefault("DRJIT_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402

MODELS = ("gaussian", "airy", "airy-h10", "airy-poly", "optical", "tabulated", "tabulated-field")


def _coma_image(folder, name, coma_waves, oversampling=4, half_px=8):
    """A coma PSF image (defocus 0.3 + coma, f/20 at 5 um, 550 nm) from the optical model's
    intensity, written as .npy; returns the path."""
    from skynav.renderer.optics import _pupil

    n_p = 128
    n = 2 * half_px * oversampling + 1
    u = (np.arange(n) - n // 2) / oversampling
    xc, p = _pupil(n_p, 0.2, ((4, 0.3), (8, coma_waves)))
    a = np.exp(2j * np.pi * np.outer(u, xc) / 2.2)
    e = a @ p @ a.T
    path = os.path.join(folder, name)
    np.save(path, np.abs(e) ** 2)
    return path


def model_dict(name, folder):
    if name == "gaussian":
        return {"model": "gaussian", "sigma_px": 0.5}
    if name == "airy":
        return {"model": "airy", "obscuration": 0.2, "wavelength_nm": 550.0}
    if name == "airy-h10":  # stamps cut at 10 px (1.8e-3 of the flux beyond, folded back)
        return {"model": "airy", "obscuration": 0.2, "wavelength_nm": 550.0, "max_half_px": 10}
    if name == "airy-poly":
        return {"model": "airy", "obscuration": 0.2}
    if name == "optical":
        return {"model": "optical", "obscuration": 0.2, "wavelength_nm": 550.0, "zernike_waves": {4: 0.3, 8: 0.2}}
    if name == "tabulated":
        return {"model": "tabulated", "file": _coma_image(folder, "coma.npy", 0.2), "oversampling": 4}
    if name == "tabulated-field":
        pts = [{"x_px": x, "y_px": y, "file": _coma_image(folder, f"coma_{i}_{j}.npy", 0.05 + 0.1 * (abs(i - 1) + abs(j - 1)))}
               for i, x in enumerate((0.0, 511.5, 1023.0)) for j, y in enumerate((0.0, 511.5, 1023.0))]
        return {"model": "tabulated", "field": pts, "oversampling": 4}
    raise SystemExit(f"psf_bench: unknown model {name!r}; allowed: {', '.join(MODELS)}")


def measure(models, repeat=9, size=1024, same_scene=False):
    """Time the default frame with each PSF model of ``models`` (names of :data:`MODELS`), in
    interleaved rounds. Returns rows ``(name, table build s, half px, median wall ms, median CPU
    ms, stars in view)``, in the order given; ``half`` of a table kernel is the pair (its
    table's, the median star's stamp: a faint star's is sized by its charge)."""
    from skynav.renderer import jit_backend
    from skynav.renderer.optics import kernel_for
    from skynav.renderer.radiometry import Radiometry
    from skynav.renderer.render import RenderOptions, render
    from skynav.scenes import presets
    from skynav.scenes.scene import build_from_spec

    jit_backend.configure_llvm()
    try:
        import drjit as dr

        dr.set_thread_count(1)
    except Exception:
        pass
    spec = presets.default_scene_spec()
    base = build_from_spec(spec)
    opts = RenderOptions()
    rng = np.random.default_rng(1)
    rows = []
    runs = []
    with tempfile.TemporaryDirectory() as folder:
        for name in models:
            cam = base.camera.replace(psf=model_dict(name, folder), width=size, height=size)
            twists = [0.0] if same_scene else [1e-3 * (r + 1) for r in range(repeat)]
            scenes = [build_from_spec(dataclasses.replace(spec, camera=cam, attitude=dataclasses.replace(
                spec.attitude, twist_rad=spec.attitude.twist_rad + t))) for t in twists]
            scene = build_from_spec(dataclasses.replace(spec, camera=cam))
            t0 = time.perf_counter()
            k = kernel_for(cam, None, opts.flux_fraction_lost)
            render(scene, rng=rng, options=opts)  # every table of the frame (all nodes of a polychromatic Airy)
            build = time.perf_counter() - t0
            h = k.half_size_px(opts.flux_fraction_lost)
            if hasattr(k, "half_sizes_px"):  # a faint star's stamp is sized by its charge: the median star's
                st = scene.stars
                e = np.asarray(Radiometry.for_camera(cam).star_electrons_per_s(st.v_mag, st.teff_k)) * cam.exposure_s
                h = (h, int(np.median(k.half_sizes_px(e[st.in_fov], opts.flux_fraction_lost))))
            runs.append((name, scenes, build, h))
        # interleaved rounds: a busy moment of a shared machine slows every model alike
        wall = {r[0]: [] for r in runs}
        cpu = {r[0]: [] for r in runs}
        for i in range(repeat):
            for name, scenes, _, _ in runs:
                scene = scenes[i % len(scenes)]
                t0, c0 = time.perf_counter(), time.process_time()
                render(scene, rng=rng, options=opts)
                wall[name].append(time.perf_counter() - t0)
                cpu[name].append(time.process_time() - c0)
        for name, scenes, build, h in runs:
            rows.append((name, build, h, 1e3 * float(np.median(wall[name])), 1e3 * float(np.median(cpu[name])),
                         int(scenes[0].stars.in_fov.sum())))
    return rows


def report(rows, repeat, size, same_scene):
    """Print the rows of :func:`measure` with their ratios to the Gaussian's (or the first row's)."""
    g = next((r for r in rows if r[0] == "gaussian"), rows[0])
    print(f"default scene, {size}x{size} paper camera (f/2.2, 13.8 um: lambda F = 0.09 px at 550 nm), "
          f"full noise, one thread; medians of {repeat}, wall | CPU; ratio to {g[0]} in this run; "
          f"{'the same frame every round' if same_scene else 'a new frame (twist) every round'}; "
          f"load average {os.getloadavg()[0]:.2f}")
    for name, build, h, w, c, n in rows:
        half = f"{h:2d} px      " if isinstance(h, int) else f"{h[0]:2d} px ({h[1]:2d})"
        print(f"{name:16s} stars {n:4d}  half {half}  tables {1e3 * build:7.0f} ms  frame {w:7.1f} ms | {c:7.1f} ms CPU"
              f"   ratio {w / g[3]:5.2f} | {c / g[4]:5.2f} CPU")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=9)
    ap.add_argument("--models", default=",".join(MODELS))
    ap.add_argument("--size", type=int, default=1024, help="image width = height, px (default 1024)")
    ap.add_argument("--same-scene", action="store_true", help="render the same frame every round (stamps reused)")
    args = ap.parse_args()
    models = args.models.split(",")
    for name in models:
        if name not in MODELS:
            ap.error(f"--models: unknown model {name!r}; allowed: {', '.join(MODELS)}")
    report(measure(models, args.repeat, args.size, args.same_scene), args.repeat, args.size, args.same_scene)


if __name__ == "__main__":
    main()
