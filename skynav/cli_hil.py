"""``skynav hil``: facility (write a facility file), export (a dataset as bench screen frames)."""

from __future__ import annotations

import sys
import time


def cmd_facility(args) -> int:
    from skynav.calibration.facility_io import load_facility, write_facility

    fac = load_facility(args.preset)
    fac.check_coverage()
    write_facility(fac, args.output)
    sc, cam = fac.screen, fac.camera
    scale = fac.geometric.focal_length_mm / (sc.pixel_pitch_um * 1e-3) / cam.focal_length_px
    print(f"wrote {args.output}: {sc.width_px}x{sc.height_px} px {sc.bit_depth}-bit screen, {sc.pixel_pitch_um:g} um, "
          f"collimator {fac.geometric.focal_length_mm:g} mm; camera {cam.width}x{cam.height}; {scale:.2f} screen px per camera px; "
          f"field margin {fac.coverage():.0f} screen px")
    return 0


def cmd_export(args) -> int:
    from skynav.calibration.facility_io import load_facility
    from skynav.datasets.hil_export import export_dataset

    from .cli_calibrate import _progress

    if args.workers < 1:
        print(f"skynav: error: --workers {args.workers}: expected a positive integer", file=sys.stderr)
        return 2
    fac = load_facility(args.facility)
    fac.check_coverage()
    s = export_dataset(fac, args.dataset, args.output, workers=args.workers, dask_scheduler=args.dask_scheduler,
                       progress=None if args.quiet else _progress("exporting"))
    print(f"{s['exported']} screen frames written to {args.output}/frames ({s['skipped']} already there) of {s['frames']}"
          f" on {s['workers']} worker(s) ({s['executor']})")
    return 0


def render_hil(args, spec, seed) -> int:
    """``skynav render SCENE --hil FACILITY``: one screen frame."""
    from skynav.calibration.facility_io import load_facility
    from skynav.datasets.hil_export import write_screen_frame
    from skynav.scenes.scene import build_from_spec

    fac = load_facility(args.hil)
    scene = build_from_spec(spec)
    if scene.camera != fac.camera:
        from skynav.calibration.errors import CalibrationInputError

        raise CalibrationInputError(f"the scene's camera ({scene.camera.width}x{scene.camera.height}, f {scene.camera.focal_length_mm:g} mm) "
                                    f"is not the facility's ({fac.camera.width}x{fac.camera.height}, f {fac.camera.focal_length_mm:g} mm)")
    fac.check_coverage()
    t0 = time.perf_counter()
    rec = write_screen_frame(fac, scene, args.output, args.name, source={"scene": args.scene or "default", "seed": seed}, seed=seed)
    seconds = time.perf_counter() - t0  # timed here: the frame's JSON holds no timing (same bytes on every run)
    on = sum(s["on_screen"] for s in rec["stars"])
    print(f"screen frame {fac.screen.width_px}x{fac.screen.height_px} {fac.screen.bit_depth}-bit in {seconds:.2f} s: "
          f"{on} stars placed, {len(rec['bodies'])} bodies; clipped: {rec['clipped']['too_bright_px']} px too bright, "
          f"{rec['clipped']['too_faint_sources']} sources too faint")
    print(f"  {args.output}/frames/{args.name}.png and .json")
    return 0


def add_parser(sub) -> None:
    h = sub.add_parser("hil", help="hardware-in-the-loop bench: facility files, screen-frame export",
                       description="Hardware-in-the-loop bench. FACILITY: a YAML file or a preset (bench, bench_small).")
    hs = h.add_subparsers(dest="hil_command", metavar="STEP")
    h.set_defaults(func=lambda a: (h.print_help(), 2)[1])
    f = hs.add_parser("facility", help="write a facility file from a preset")
    f.add_argument("preset", nargs="?", default="bench", help="preset name or facility file (default: bench)")
    f.add_argument("-o", "--output", required=True)
    f.set_defaults(func=cmd_facility)
    e = hs.add_parser("export", help="export a dataset as screen frames")
    e.add_argument("dataset")
    e.add_argument("--facility", required=True)
    e.add_argument("-o", "--output", required=True)
    e.add_argument("--workers", type=int, default=1, help="local processes (default 1)")
    e.add_argument("--dask-scheduler", default=None, metavar="ADDRESS", help="run on a Dask distributed cluster")
    e.add_argument("-q", "--quiet", action="store_true")
    e.set_defaults(func=cmd_export)
