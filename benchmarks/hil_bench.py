"""Hardware-in-the-loop bench campaign: calibration accuracy and speed, screen-frame export speed.

Run: ``python benchmarks/hil_bench.py [--preset bench] [--scenarios realistic,stress,shifted,roll90]
[--frames 16] [--phases 4] [--closed-loop] [--skip-export]``. For each virtual-bench scenario it writes the patterns (``phases**2``
dot grids + 3 flats + 1 dark: 20 patterns for ``--phases 4``), captures them on the virtual bench,
fits, and prints the uncalibrated error, the held-out residuals (p50/p99/max arcsec, measurement
noise included), the error of the fitted model against the virtual bench's truth (which only a
virtual bench can give) and the fit time. Then it times a software frame and the screen frame of
the same scene (``default`` preset, resolved bodies as the scene has them).
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


def main(argv=None) -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--preset", default="bench")
    ap.add_argument("--scenarios", default="realistic,stress,shifted,roll90")
    ap.add_argument("--frames", type=int, default=16)
    ap.add_argument("--phases", type=int, default=4)
    ap.add_argument("--skip-export", action="store_true")
    ap.add_argument("--closed-loop", action="store_true", help="also run the closed loop on the realistic bench")
    a = ap.parse_args(argv)

    from skynav.calibration.errors import IdentificationError
    from skynav.calibration.geometric import calibrate_geometric
    from skynav.calibration.patterns import write_patterns
    from skynav.calibration.virtual_bench import scenario, simulate, uncalibrated_error_arcsec
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
        import json

        from skynav.calibration.closed_loop import closed_loop
        from skynav.calibration.virtual_bench import VirtualBench
        from skynav.scenes import config, presets
        from skynav.scenes.scene import build_from_spec

        scene = build_from_spec(config.scene_spec_from_mapping(presets.preset_mapping("default")))
        out = closed_loop(VirtualBench(fac, scenario("realistic", fac)), calibrated["realistic"], scene)
        print("closed loop (default scene, realistic bench, calibrated):")
        print(json.dumps(out, indent=1))
    if a.skip_export:
        return
    from skynav.renderer.display import screen_frame
    from skynav.renderer.render import RenderOptions, render
    from skynav.scenes import config, presets
    from skynav.scenes.scene import build_from_spec

    scene = build_from_spec(config.scene_spec_from_mapping(presets.preset_mapping("default")))
    render(scene, seed=0, options=RenderOptions())  # warm caches
    screen_frame(scene, fac, rng=np.random.default_rng(0))
    t = []
    for _ in range(5):
        t0 = time.perf_counter()
        render(scene, seed=0, options=RenderOptions())
        t1 = time.perf_counter()
        screen_frame(scene, fac, rng=np.random.default_rng(0))
        t.append((t1 - t0, time.perf_counter() - t1))
    sw, hil = np.median(np.array(t), axis=0)
    print(f"export: software frame {sw:.2f} s, screen frame {hil:.2f} s ({fac.screen.width_px}x{fac.screen.height_px}): "
          f"ratio {hil / sw:.2f} (target <= 1.5)")


if __name__ == "__main__":
    main()
