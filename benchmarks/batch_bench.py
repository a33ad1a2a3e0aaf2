"""Frames/s of the batched frame program (renderer/batch.py) against the per-frame path.

    python benchmarks/batch_bench.py [--backend llvm] [--sizes 1 2 4 ... 256] [--px 256 512 1024]
                                     [--repeat 3] [--written] [--baseline-frames 32] [--acceptance]
                                     [--scene default] [--bodies]
                                     [--psf scene|airy|optical|polychromatic]

For each image size (the scene ``--scene``, a preset, the default scene unless said; its field
kept: the pixel pitch follows the width) and each batch size N: ``render_batch`` of N frames (seeds 0 .. N-1), the DN brought to
the host, medians of ``--repeat`` rounds, as frames/s, with the per-frame stage split
(``optics``: expected images, cosmic rays, truths, on this thread; ``launch``: the sensor's
inputs to the device and its kernels launched; ``sensor wait``: the wait for the last launches),
against ``render`` of ``--baseline-frames`` frames one after the other (the per-frame path, in
a warm heap as a dataset's worker runs it: ``infra/heap.py``; the batch warms its own), the
two taking turns, wall time and CPU time (this process, all threads: the figure to compare on a
machine other processes share). ``--written`` adds each frame written as PNG + truth JSON
(encoded, then written atomically into a temporary folder), for both paths.

``--acceptance`` then times a batch of 32 frames of the scene (1024 px) in memory against 32
frames of the per-frame path, the stars drawn per frame by numpy and by Dr.Jit on the device
(``star_splat``), the three taking turns in each round, and prints the ratios.

``--bodies`` then times the ray-traced bodies of one frame of the scene (at its own size,
Mitsuba 4 spp) blurred and composited: by numpy, as ``expected_image`` draws them, against
Dr.Jit (``renderer/bodies_jit.py``, what ``star_splat='device'`` runs), for the camera's PSF and
an Airy PSF (550 nm), medians.

``--psf`` gives the camera another PSF model (default the scene's own): ``airy`` (550 nm,
obscuration 0.2), ``optical`` (the same with coma), ``polychromatic`` (the Airy blended by
each source's spectrum); the batches and ``--acceptance`` then render with it.

This is the CPU twin of ``gpu_bench.py``'s batch section (``--backend cuda`` runs the same
measurement on a GPU). Dr.Jit's pool has as many threads as the machine has cores unless
``DRJIT_NUM_THREADS`` says otherwise (the line says which). A batch whose images would take more
than a third of the free memory is skipped, and the line says so.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("DRJIT_NUM_THREADS", str(os.cpu_count() or 1))

import numpy as np  # noqa: E402

SIZES = (1, 2, 4, 8, 16, 32, 64, 128, 256)


#: The PSF models ``--psf`` names (None: the scene's own).
PSFS = {"scene": None,
        "airy": {"model": "airy", "obscuration": 0.2, "wavelength_nm": 550.0},
        "optical": {"model": "optical", "obscuration": 0.2, "wavelength_nm": 550.0,
                    "zernike_waves": {4: 0.3, 7: 0.2, 8: -0.1}},
        "polychromatic": {"model": "airy", "obscuration": 0.2}}


def scene_of_size(px: int, name: str = "default", psf: str = "scene"):
    from skynav.scenes import build_from_spec, default_scene_spec
    from skynav.scenes.presets import preset_mapping, scene_spec_from_mapping

    spec = default_scene_spec() if name == "default" else scene_spec_from_mapping(preset_mapping(name))
    cam = spec.camera
    camera = cam.replace(width=px, height=px, pixel_pitch_um=cam.pixel_pitch_um * cam.width / px)
    if PSFS[psf] is not None:
        camera = camera.replace(psf=PSFS[psf])
    return build_from_spec(dataclasses.replace(spec, camera=camera))


def _free_bytes() -> int:
    try:
        with open("/proc/meminfo") as f:
            info = dict(line.split(":", 1) for line in f)
        return int(info["MemAvailable"].split()[0]) * 1024
    except (OSError, KeyError, ValueError):
        return 8 << 30


def _write(frames, folder: Path) -> None:
    from skynav.datasets.frame_files import encode_frame, write_files

    for k, frame in frames:
        blobs = encode_frame(frame, ("png", "json"))
        write_files((folder / f"{k:06d}.{fmt}", data) for fmt, data in blobs.items())


def per_frame(scene, options, n: int, folder):
    """The per-frame path: ``render`` of n frames (and their files when ``folder``), as a
    dataset's worker loops over them: in a :class:`~skynav.infra.heap.WarmHeap` warmed after
    the first frame (``render_batch`` warms its own), so that neither path pays the garbage
    collector's walks of the frames' truths that the other is spared."""
    from skynav.infra.heap import WarmHeap
    from skynav.renderer.render import render

    frames = []
    with WarmHeap() as heap:
        for k in range(n):
            frames.append((k, render(scene, seed=k, options=options)))
            heap.warm()
    if folder is not None:
        _write(frames, folder)


def batched(scene, options, n: int, folder, split: dict, star_splat: str = "auto"):
    """``render_batch`` of n frames, the DN brought over (and their files when ``folder``)."""
    from skynav.renderer.batch import render_batch
    from skynav.renderer.render import Frame

    b = render_batch([scene] * n, list(range(n)), options=options, electrons=False, star_splat=star_splat)
    dn = b.dn
    for key, v in b.timings_s.items():
        split.setdefault(key, []).append(v / n)
    if folder is not None:
        _write([(k, Frame(dn=dn[k], electrons=None, irradiance_w_m2=None, truth=b.truths[k]))
                for k in range(n)], folder)


def timed(fn, repeat: int):
    """Median wall and CPU time of ``fn()`` over ``repeat`` calls (after one warm-up), s."""
    fn()
    wall, cpu = [], []
    for _ in range(repeat):
        t0, c0 = time.perf_counter(), time.process_time()
        fn()
        wall.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    return float(np.median(wall)), float(np.median(cpu))


def measure(px: int, sizes, repeat: int, written: bool, baseline: int, backend: str, name: str = "default",
            psf: str = "scene") -> dict:
    from skynav.renderer.render import RenderOptions

    scene = scene_of_size(px, name, psf)
    options = RenderOptions(backend=backend)
    out = {}
    with tempfile.TemporaryDirectory() as tmp:
        modes = [("in memory", None)] + ([("written", Path(tmp))] if written else [])
        for mode, folder in modes:
            bw, bc = timed(lambda: per_frame(scene, options, baseline, folder), repeat)
            out[(mode, "per-frame")] = (baseline / bw, baseline / bc)
            print(f"{px} px, {mode}: per-frame path {baseline / bw:8.1f} frames/s wall, {baseline / bc:8.1f} per CPU-s "
                  f"({baseline} frames, medians of {repeat})", flush=True)
            for n in sizes:
                if n * px * px * 4 * 3 > _free_bytes() / 3:
                    print(f"{px} px, {mode}: batch {n:3d}: skipped (its images would take over a third of the free "
                          "memory)", flush=True)
                    continue
                split = {}
                w, c = timed(lambda n=n: batched(scene, options, n, folder, split), repeat)
                out[(mode, n)] = (n / w, n / c)
                stages = ", ".join(f"{k.replace('_', ' ')} {1e3 * float(np.median(v)):.1f} ms" for k, v in split.items())
                print(f"{px} px, {mode}: batch {n:3d}: {n / w:8.1f} frames/s wall ({n / w / (baseline / bw):5.2f}x the "
                      f"per-frame path), {n / c:8.1f} per CPU-s ({n / c / (baseline / bc):5.2f}x); per frame: {stages}",
                      flush=True)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--backend", choices=("llvm", "cuda"), default="llvm", help="Dr.Jit backend (default llvm)")
    ap.add_argument("--sizes", type=int, nargs="+", default=list(SIZES), help="batch sizes (default 1 .. 256)")
    ap.add_argument("--px", type=int, nargs="+", default=[256, 512, 1024], help="image sizes (default 256 512 1024)")
    ap.add_argument("--repeat", type=int, default=3, help="rounds; medians (default 3)")
    ap.add_argument("--baseline-frames", type=int, default=32, help="frames of the per-frame path (default 32)")
    ap.add_argument("--written", action="store_true", help="also write each frame as PNG + truth JSON")
    ap.add_argument("--acceptance", action="store_true",
                    help="then a batch of 32 frames of the scene against the per-frame path, taking turns")
    ap.add_argument("--scene", default="default", help="the scene: a preset (default: default)")
    ap.add_argument("--psf", choices=tuple(PSFS), default="scene", help="the camera's PSF model (default: the scene's own)")
    ap.add_argument("--bodies", action="store_true",
                    help="then the ray-traced bodies' blur and composite of one frame, numpy against Dr.Jit")
    a = ap.parse_args(argv)
    from skynav.renderer import jit_backend

    status = jit_backend.probe_cuda() if a.backend == "cuda" else jit_backend.configure_llvm()
    if not status.available:
        print(f"batch_bench: Dr.Jit's {a.backend} backend does not work here ({status.reason})", file=sys.stderr)
        return 2
    print(f"batched frames, backend {a.backend}, PSF {a.psf}; {os.cpu_count()} cores, DRJIT_NUM_THREADS="
          f"{os.environ['DRJIT_NUM_THREADS']}; load average {' '.join(f'{x:.1f}' for x in os.getloadavg())}; "
          f"{time.strftime('%Y-%m-%d %H:%M')}", flush=True)
    for px in a.px:
        measure(px, a.sizes, a.repeat, a.written, a.baseline_frames, a.backend, a.scene, a.psf)
    if a.acceptance:
        acceptance(a.repeat, a.backend, a.scene, a.psf)
    if a.bodies:
        bodies(a.scene, a.repeat, a.backend)
    return 0


def bodies(name: str, repeat: int, backend: str) -> None:
    """The ray-traced bodies of one frame of the scene ``name`` (its own camera; Mitsuba 4 spp)
    blurred and composited by numpy and by Dr.Jit, for the camera's PSF and an Airy PSF, medians."""
    import drjit as dr

    from skynav.renderer.bodies_jit import body_crops, composite_bodies
    from skynav.renderer.expected import _draw_resolved_bodies, expected_image
    from skynav.renderer.render import RenderOptions
    from skynav.renderer.sensor_jit import _jit_module
    from skynav.scenes import build_from_spec
    from skynav.scenes.presets import preset_mapping, scene_spec_from_mapping

    options = RenderOptions(backend=backend, mitsuba_spp=4)
    for label, psf in (("the camera's PSF", None), ("an Airy PSF", {"model": "airy", "wavelength_nm": 550.0})):
        m = preset_mapping(name)
        if psf is not None:
            m["camera"]["psf"] = psf
        scene = build_from_spec(scene_spec_from_mapping(m))
        shape, traced = (scene.camera.height, scene.camera.width), []
        ex = expected_image(scene, rng=np.random.default_rng(0), options=options, with_irradiance=False,
                            traced_out=traced)
        if not traced:
            print(f"{name}: no ray-traced body in the frame")
            return
        light = (dict(ex.body_electrons), dict(ex.body_electrons))
        sig = _jit_module(backend).Float(np.zeros(shape[0] * shape[1], np.float32))

        def host():
            _draw_resolved_bodies(traced, options, light, (np.zeros(shape), None), [], {}, {})

        def device():
            out, moments = composite_bodies(sig, [body_crops(traced, options.flux_fraction_lost)], shape)
            dr.eval(out, moments)
            moments.numpy()  # the truth's moments brought over: the launch is done

        h, d = timed(host, repeat)[0], timed(device, repeat)[0]
        crops = ", ".join(f"{t.name} {t.image.electrons.shape[1]}x{t.image.electrons.shape[0]} px, "
                          f"{np.count_nonzero(t.image.electrons)} lit" for t in traced)
        print(f"{name} ({shape[1]} px), {label}: ray-traced bodies ({crops}) blurred and composited: numpy "
              f"{1e3 * h:.2f} ms, Dr.Jit {backend} {1e3 * d:.2f} ms a frame ({h / d:.2f}x; medians of {repeat})",
              flush=True)


def acceptance(repeat: int, backend: str, name: str = "default", psf: str = "scene") -> None:
    """A batch of 32 frames of the scene ``name`` (1024 px) in memory against 32 frames of the
    per-frame path, the two taking turns in each round (a change of the machine's load falls on
    both), medians."""
    from skynav.renderer.render import RenderOptions

    scene, options = scene_of_size(1024, name, psf), RenderOptions(backend=backend)
    runs = {"per-frame": lambda: per_frame(scene, options, 32, None),
            "batch": lambda: batched(scene, options, 32, None, {}, "host"),
            "device stars": lambda: batched(scene, options, 32, None, {}, "device")}
    for fn in runs.values():
        fn()
    wall, cpu = {k: [] for k in runs}, {k: [] for k in runs}
    for _ in range(repeat):
        for k, fn in runs.items():
            t0, c0 = time.perf_counter(), time.process_time()
            fn()
            wall[k].append(time.perf_counter() - t0)
            cpu[k].append(time.process_time() - c0)
    w = {k: 32 / float(np.median(v)) for k, v in wall.items()}
    c = {k: 32 / float(np.median(v)) for k, v in cpu.items()}
    print(f"acceptance ({psf} PSF): a batch of 32 {name} frames (1024 px) in memory: {w['batch']:.1f} frames/s against the "
          f"per-frame path's {w['per-frame']:.1f}: {w['batch'] / w['per-frame']:.2f}x wall, "
          f"{c['batch'] / c['per-frame']:.2f}x CPU (taking turns, medians of {repeat}; load average "
          f"{os.getloadavg()[0]:.1f})")
    print(f"acceptance: the same batch with its stars (and ray-traced bodies' blur) drawn by Dr.Jit "
          f"(star_splat='device'): "
          f"{w['device stars']:.1f} frames/s, {w['device stars'] / w['per-frame']:.2f}x wall, "
          f"{c['device stars'] / c['per-frame']:.2f}x CPU; {w['device stars'] / w['batch']:.2f}x the numpy splat's "
          "batch (wall)")


if __name__ == "__main__":
    sys.exit(main())
