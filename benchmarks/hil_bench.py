"""Hardware-in-the-loop bench campaign: calibration accuracy and speed, screen-frame export speed.

Run: ``python benchmarks/hil_bench.py [--preset screen] [--scenarios realistic,stress,shifted,roll90]
[--frames 16] [--phases 4] [--closed-loop [--loop-frames 100] [--loop-seed S]] [--skip-export] [--timing-reps 9]``. For each virtual-bench scenario it writes the patterns (``phases**2``
dot grids + 3 flats + 1 dark: 20 patterns for ``--phases 4``), captures them on the virtual bench,
fits, and prints the uncalibrated error, the held-out residuals (p50/p99/max arcsec, measurement
noise included), the error of the fitted model against the virtual bench's truth (which only a
virtual bench can give) and the fit time. Then it times a software frame and the screen frame of
the same scene (``default`` preset, resolved bodies as the scene has them): the median of
``--timing-reps`` warm runs of each, in this process, and their ratio; and the screen frame with
its PNG and JSON written, as ``skynav hil export`` makes it. ``--closed-loop`` runs
:func:`skynav.calibration.bench_files.run_closed_loop` on the calibrated realistic bench: a
``montecarlo`` dataset of ``--loop-frames`` frames, exported, captured and measured.
"""

from __future__ import annotations

import argparse
import dataclasses
import tempfile
import time

import numpy as np


def truth_error_arcsec(facility, calibrated, truth, n=60):
    from skynav.scenes.facility import ARCSEC

    cam = facility.camera
    g = np.stack(np.meshgrid(np.linspace(8, cam.width - 9, n), np.linspace(8, cam.height - 9, n)), -1).reshape(-1, 2)
    xy = calibrated.projection.project(cam.line_of_sight(g))
    true = dataclasses.replace(facility.projection, model=truth.geometric).line_of_sight(xy)
    return np.linalg.norm(np.cross(true, calibrated.projection.line_of_sight(xy)), axis=-1) / ARCSEC


def print_closed_loop(s: dict, seconds: float) -> None:
    """The closed-loop figures: per source kind, capture vs true direction (and vs the software
    frame's rendered photocentre), photometry capture vs software frame."""
    print(f"closed loop: {s['frames']} montecarlo frames, realistic bench (calibrated), V < {s['v_max']:g} stars and "
          f"unresolved planets; left out: {s['skipped']} ({seconds:.0f} s)")
    head = ("", "kind", "n", "<5as truth", "rms", "max", "sw rms", "<5as phc", "rms", "max", "n phot", "dmag rms", "bias", "scr.clip")
    print("{:<11} {:<7} {:>5} {:>10} {:>6} {:>6} {:>7} {:>9} {:>6} {:>6} {:>6} {:>8} {:>7} {:>8}".format(*head))
    for label in ("noisy", "noise_free"):
        for kind in ("star", "planet"):
            r = s[label][kind]
            if not r["n"]:
                print(f"{label:<11} {kind:<7} {0:>5}")
                continue
            g = lambda k, f="6.2f": format(r[k], f) if k in r else "-"  # noqa: E731
            print(f"{label:<11} {kind:<7} {r['n']:>5} {100 * r['within_5_arcsec']:9.1f}% {g('rms_arcsec')} {g('max_arcsec')} "
                  f"{g('software_rms_arcsec', '7.2f')} {100 * r['vs_photocentre_within_5_arcsec']:8.1f}% {g('vs_photocentre_rms_arcsec')} "
                  f"{g('vs_photocentre_max_arcsec')} {r['n_photometry']:>6} {g('dmag_rms', '8.4f')} {g('dmag_bias', '+7.4f')} "
                  f"{r['screen_clipped']:>8}")
    print("(arcsec; truth: the true apparent direction; phc: the software frame's noise-free centroid, i.e. the rendered "
          "photocentre, which for a planet's disc includes its phase offset; dmag = capture - software frame)")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--preset", default="screen")
    ap.add_argument("--scenarios", default="realistic,stress,shifted,roll90")
    ap.add_argument("--frames", type=int, default=16)
    ap.add_argument("--phases", type=int, default=4)
    ap.add_argument("--skip-export", action="store_true")
    ap.add_argument("--closed-loop", action="store_true", help="also run the closed loop on the realistic bench")
    ap.add_argument("--loop-frames", type=int, default=100, help="closed loop: montecarlo frames")
    ap.add_argument("--loop-seed", type=int, default=20260101, help="closed loop: dataset master seed")
    ap.add_argument("--timing-reps", type=int, default=9, help="export timing: warm repetitions (median)")
    a = ap.parse_args(argv)

    from skynav.calibration.errors import IdentificationError
    from skynav.calibration.virtual_bench import scenario, uncalibrated_error_arcsec
    from skynav.calibration.bench_files import calibrate_geometric, simulate, write_patterns
    from skynav.scenes.facility import PRESETS

    fac = PRESETS[a.preset]()
    calibrated = {}
    with tempfile.TemporaryDirectory() as tmp:
        pats = write_patterns(fac, f"{tmp}/pat", phases=a.phases)
        print(f"{a.preset}: {len(pats)} patterns, camera {fac.camera.width} px "
              f"({np.degrees(fac.camera.ifov_rad) * 3600:.1f} arcsec/px)")
        print(f"{'scenario':<10} {'uncal.':>8} {'hold-out p50':>12} {'p99':>7} {'max':>7} {'truth p99':>9} {'max':>7} {'fit s':>6}")
        for name in [n for n in a.scenarios.split(",") if n]:
            truth = scenario(name, fac)
            simulate(fac, f"{tmp}/pat", f"{tmp}/cap_{name}", scenario_name=name, frames=a.frames)
            try:
                res = calibrate_geometric(fac, f"{tmp}/pat", f"{tmp}/cap_{name}")
            except IdentificationError as exc:
                print(f"{name:<10} refused: {exc}")
                continue
            if name == "realistic" and a.closed_loop:
                from skynav.calibration.radiometric import calibrate_radiometric

                calibrated[name] = calibrate_radiometric(res.facility, f"{tmp}/cap_{name}/power_meter.csv").facility
            s = res.summary()
            e = truth_error_arcsec(fac, res.facility, truth)
            print(f"{name:<10} {uncalibrated_error_arcsec(fac, truth):8.0f} {s['p50']:12.3f} {s['p99']:7.3f} {s['max']:7.3f} "
                  f"{np.percentile(e, 99):9.3f} {e.max():7.3f} {res.seconds:6.1f}")

    if "realistic" in calibrated:
        from skynav.calibration.bench_files import run_closed_loop

        t0 = time.perf_counter()
        with tempfile.TemporaryDirectory() as tmp:
            res = run_closed_loop(fac, calibrated["realistic"], tmp, frames=a.loop_frames, dataset_seed=a.loop_seed)
        print_closed_loop(res.summary(), time.perf_counter() - t0)
    if a.skip_export:
        return
    from skynav.renderer.display import screen_frame
    from skynav.renderer.render import RenderOptions, render
    from skynav.scenes import config, presets
    from skynav.scenes.scene import build_from_spec

    scene = build_from_spec(config.scene_spec_from_mapping(presets.preset_mapping("default")))

    def median_s(fn, reps=a.timing_reps):
        fn()  # warm: caches, imports, the first allocation of each size
        t = []
        for _ in range(reps):
            t0 = time.perf_counter()
            fn()
            t.append(time.perf_counter() - t0)
        return float(np.median(t))

    # each in its own run of repetitions, as a dataset generation and an export make them
    sw = median_s(lambda: render(scene, seed=0, options=RenderOptions()))
    hil = median_s(lambda: screen_frame(scene, fac, rng=np.random.default_rng(0)))
    print(f"export: software frame {sw:.3f} s, screen frame {hil:.3f} s ({fac.screen.width_px}x{fac.screen.height_px}), "
          f"medians of {a.timing_reps} warm runs in this process: ratio {hil / sw:.2f} (target <= 1.5)")
    from skynav.datasets.hil_export import write_screen_frame

    from skynav.datasets.frame_files import write_frame

    with tempfile.TemporaryDirectory() as tmp:
        sw_files = median_s(lambda: write_frame(render(scene, seed=0, options=RenderOptions()), tmp, "sw"))
        files = median_s(lambda: write_screen_frame(fac, scene, tmp, "000000", source={"scene": "default"}))
    print(f"        with their files written: software frame (PNG, EXR, JSON, as dataset generate) {sw_files:.3f} s, "
          f"screen frame (PNG, JSON, as hil export) {files:.3f} s: ratio {files / sw_files:.2f} (target <= 1.5)")


if __name__ == "__main__":
    main()
