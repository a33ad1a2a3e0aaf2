"""``skynav hil``: facility (write a facility file), export (a dataset as screen frames)."""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

from skynav.calibration.errors import CalibrationInputError
from skynav.calibration.facility_io import load_facility, write_facility
from skynav.datasets.frame_files import png_bytes, read_png
from skynav.datasets.hil_export import export_dataset, write_screen_frame
from skynav.datasets.quicklook import quicklook_u8
from skynav.infra.atomic_files import atomic_write_bytes
from skynav.scenes.facility import PRESETS as FACILITY_PRESETS
from skynav.scenes.facility import facility_from_mapping
from skynav.scenes.overrides import apply_overrides
from skynav.scenes.scene import build_from_spec

from .cli_args import (
    MAX_WORKERS,
    add_dask_arg,
    add_dataset_arg,
    add_facility_arg,
    add_output_arg,
    add_quiet,
    add_set_arg,
    add_workers_arg,
)
from .cli_common import COMMAND_HELP, ProgressBar, check_output, say, warn


def uncalibrated_note(facility, name) -> str | None:
    """The warning for a facility without a calibration record (None when it has both)."""
    missing = [what for what, rec in (("geometric", facility.calibrated_geometric),
                                      ("radiometric", facility.calibrated_radiometric)) if not rec]
    if not missing:
        return None
    if len(missing) == 2:
        return (f"facility {name} was never calibrated (no geometric or radiometric calibration record): the screen "
                "frames use its nominal model; calibrate it first (skynav calibrate geometric, then radiometric)")
    return (f"facility {name} has no {missing[0]} calibration record: the screen frames use its nominal {missing[0]} "
            f"model; run skynav calibrate {missing[0]} first")


def cmd_facility(args) -> int:
    check_output(args.output, [("facility", args.facility)], kind="file")
    fac = load_facility(args.facility)
    fac.check_coverage()
    write_facility(fac, args.output)
    sc, cam = fac.screen, fac.camera
    scale = fac.geometric.focal_length_mm / (sc.pixel_pitch_um * 1e-3) / cam.focal_length_px
    say(args, f"wrote {args.output}: {sc.width_px}x{sc.height_px} px {sc.bit_depth}-bit screen, {sc.pixel_pitch_um:g} um, "
          f"collimator {fac.geometric.focal_length_mm:g} mm; camera {cam.width}x{cam.height}; {scale:.2f} screen px per camera px; "
          f"field margin {fac.coverage():.0f} screen px")
    return 0


def cmd_export(args) -> int:
    check_output(args.output, [("dataset", args.dataset), ("facility", args.facility)])
    fac = load_facility(args.facility)
    if args.overrides:  # the facility's file form, every key written out (what `skynav hil facility` writes)

        mapping = apply_overrides(fac.to_mapping(), args.overrides, known_keys_only=True, what="the facility")
        if any(path[0] == "camera" and path[1:] != ("K",) for _, path, _ in args.overrides):
            mapping["camera"].pop("K", None)  # derived from the other camera keys, which an override changed
            cam0, set_keys = fac.camera, {path[1] for _, path, _ in args.overrides if path[0] == "camera" and len(path) > 1}
            for c, size in (("cx", cam0.width), ("cy", cam0.height)):
                if c not in set_keys and getattr(cam0, c) == 0.5 * (size - 1):  # the old centre: the new one
                    mapping["camera"].pop(c, None)
        paths = {path for _, path, _ in args.overrides}
        focal = ("geometric", "parameters", "focal_length_mm")
        if ("collimator", "focal_length_mm") in paths and focal not in paths and not fac.calibrated_geometric:
            # a nominal facility: the collimator's focal length is the model's (one key to set)
            mapping["geometric"]["parameters"]["focal_length_mm"] = mapping["collimator"]["focal_length_mm"]
        fac = facility_from_mapping(mapping)
    fac.check_coverage()
    with ProgressBar("exporting", "frame", quiet=args.quiet) as bar:
        s = export_dataset(fac, args.dataset, args.output, workers=args.workers, dask_scheduler=args.dask_scheduler,
                           progress=bar)
    note = uncalibrated_note(fac, args.facility)
    if note:  # after the work: an error stays one line, and the warning is not lost above the bar
        warn(note)
    say(args, f"{s['exported']} screen frames written to {args.output}/frames ({s['skipped']} already there) of {s['frames']}"
          f" on {s['workers']} worker(s) ({s['executor']})")
    return 0


def render_facility(args):
    """The facility of ``skynav render --facility FACILITY`` (or its former spelling ``--hil``),
    checked with the other flags before any work; the error names the spelling given."""
    option = (getattr(args, "_facility_given", None) or ("--facility",))[0]
    if not args.facility.strip():
        raise CalibrationInputError(f"{option} {args.facility!r}: expected a facility YAML file or a preset "
                                    f"({', '.join(FACILITY_PRESETS)})")
    if args.fits:
        raise CalibrationInputError(f"--fits with {option}: a screen frame has no sky WCS to write as FITS (FITS is the "
                                    f"camera frame's format); drop --fits, or render the camera frame without {option}")
    return load_facility(args.facility)


def camera_differences(a, b, prefix: str = "camera") -> list:
    """``[(dotted key, value in a, value in b)]`` where two cameras differ (nested records too)."""
    out = []
    for f in dataclasses.fields(a):
        va, vb = getattr(a, f.name), getattr(b, f.name)
        if va == vb:
            continue
        if dataclasses.is_dataclass(va) and type(va) is type(vb):
            out += camera_differences(va, vb, f"{prefix}.{f.name}")
        else:
            out.append((f"{prefix}.{f.name}", va, vb))
    return out


def render_hil(args, fac, spec, seed) -> int:
    """``skynav render [SCENE] --facility FACILITY``: one screen frame, ``OUT/NAME.png`` and ``.json``."""
    scene = build_from_spec(spec)
    if scene.camera != fac.camera:
        diff = camera_differences(scene.camera, fac.camera)
        key, mine, theirs = diff[0] if diff else ("camera", scene.camera, fac.camera)
        others = [k for k, _, _ in diff[1:]]
        more = f" (also {', '.join(others[:4])}{', ...' if len(others) > 4 else ''})" if others else ""
        raise CalibrationInputError(
            f"the scene's camera is not the facility's: {key} is {_short(mine)} in the scene, {_short(theirs)} in the "
            f"facility{more}; a screen frame is made for the facility's camera: give the scene that camera, or no "
            "scene file (the default scene is then seen by the facility's camera)")
    if args.scene is None:
        say(args, f"no scene file: the default scene, seen by the facility's camera ({fac.camera.width}x{fac.camera.height} px, "
                  f"f {fac.camera.focal_length_mm:g} mm, {fac.camera.pixel_pitch_um:.4g} um pixels)")
    fac.check_coverage()
    t0 = time.perf_counter()
    rec = write_screen_frame(fac, scene, args.output, args.name, source={"scene": args.scene or "default", "seed": seed},
                             seed=seed, subfolder="")
    seconds = time.perf_counter() - t0  # timed here: the frame's JSON holds no timing (same bytes on every run)
    on = sum(s["on_screen"] for s in rec["stars"])
    say(args, f"screen frame {fac.screen.width_px}x{fac.screen.height_px} {fac.screen.bit_depth}-bit in {seconds:.2f} s: "
          f"{on} stars placed on the screen, {len(rec['bodies'])} {'body' if len(rec['bodies']) == 1 else 'bodies'}; clipped: {rec['clipped']['too_bright_px']} "
          f"screen px brighter than the screen's full scale, {rec['clipped']['too_faint_sources']} sources fainter "
          "than its first DN step")
    say(args, f"  png   {Path(args.output) / (args.name + '.png')}", f"  json  {Path(args.output) / (args.name + '.json')}")
    if args.preview:  # the screen's DN back from its PNG (scaled to the PNG's full range there)
        say(args, f"  preview {write_preview(read_png(Path(args.output) / (args.name + '.png')), args.output, args.name)}")
    note = uncalibrated_note(fac, args.facility)
    if note:  # after the work, as hil export: an error stays one line
        warn(note)
    return 0


def write_preview(dn, out, name: str) -> Path:
    """``OUT/NAME_preview.png``: the 8-bit quick look of a frame's DN for the eye (zscale limits,
    asinh stretch: :func:`skynav.datasets.quicklook.quicklook_u8`), beside its physical PNG."""
    path = Path(out) / f"{name}_preview.png"
    atomic_write_bytes(path, png_bytes(quicklook_u8(dn)))
    return path


def _short(value) -> str:
    text = f"{value:g}" if isinstance(value, float) else repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def add_parser(sub) -> None:
    h = sub.add_parser("hil", help=COMMAND_HELP["hil"],
                       description="Hardware in the loop: a screen seen by the camera through a collimator (a facility). FACILITY: a YAML file or a preset (screen, screen_small).")
    hs = h.add_subparsers(dest="hil_command", metavar="STEP")
    h.set_defaults(func=lambda a: (h.print_help(), 2)[1])
    f = hs.add_parser("facility", help="write a facility file from a preset")
    add_facility_arg(f, required=False, default="screen", former_positional=True,
                     help="the preset (screen, screen_small) or facility file to write out")
    add_output_arg(f, help="facility YAML file to write")
    add_quiet(f)
    f.set_defaults(func=cmd_facility)
    e = hs.add_parser("export", help="export a dataset as screen frames",
                      description="Export a dataset as the screen frames a facility shows its camera. --set changes "
                      "a key of the facility (file or preset, in the form 'skynav hil facility' writes), e.g. "
                      "--set radiometric.parameters.gamma=2.4 or --set screen.bit_depth=8; the dataset itself "
                      "is read as it is (to change what it shows, regenerate it with 'dataset generate --set').")
    add_dataset_arg(e, "the dataset to export")
    add_facility_arg(e, required=True)
    add_output_arg(e, help="screen-frame folder")
    add_workers_arg(e, default=1, why="each holds a screen frame in memory",
                    help=f"local processes, 1..{MAX_WORKERS} (default 1; each holds a screen frame in memory)")
    add_dask_arg(e)
    add_quiet(e)
    add_set_arg(e, "the facility (screen.*, collimator.*, camera.*, geometric.parameters.*, "
                        "radiometric.parameters.*; keys as 'skynav hil facility' writes them)")
    e.set_defaults(func=cmd_export)
