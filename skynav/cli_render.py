"""``skynav scene`` and ``skynav render``: what a scene holds, and one rendered frame."""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np

from skynav.datasets.frame_files import check_output_dir, check_stem, write_frame
from skynav.renderer.render import RenderOptions, render
from skynav.scenes import config, presets, scene_files
from skynav.scenes.constants import AU_KM
from skynav.scenes.errors import SceneFileError
from skynav.scenes.frames import unit_to_radec
from skynav.scenes.overrides import apply_overrides, keep_field_of_view
from skynav.scenes.scene import build_from_spec

from .cli_args import add_facility_arg, add_output_arg, add_quiet, add_scene_arg, add_seed_arg, add_set_arg
from .cli_common import COMMAND_HELP, say
from .cli_hil import render_facility, render_hil, write_preview


def _load_spec(arg: str | None, overrides=(), camera=None):
    """The scene of a file or preset, with the ``--set`` overrides applied to its mapping;
    ``camera`` (a Camera) replaces the default scene's camera when no file or preset is given."""
    if arg is None or arg in presets.PRESETS:
        mapping = presets.preset_mapping(arg or "default")
        if arg is None and camera is not None:
            # the facility's camera as a scene file writes it (K and bit_depth follow from the rest)
            mapping["camera"] = {k: v for k, v in camera.to_dict().items() if k not in ("K", "bit_depth")}
    else:
        path = Path(arg)
        if path.suffix.lower() not in (".yaml", ".yml") and not path.exists():
            raise SceneFileError(f"{arg}: no such scene file (give a .yaml file or a preset: {', '.join(presets.PRESETS)})")
        mapping = scene_files.load_scene_mapping(path)
    if overrides:
        before, mapping = mapping, apply_overrides(mapping, overrides)
        keep_field_of_view(before, mapping, overrides)  # a size override keeps the field (one line says so)
    return config.scene_spec_from_mapping(mapping)


# ----------------------------------------------------------------------------- scene
def _fmt(x, spec="8.2f"):
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        width = "".join(c for c in spec.split(".")[0] if c.isdigit())
        return "-".rjust(int(width) if width else 1)  # a column's dash as wide as its numbers
    return format(x, spec)


def cmd_scene(args) -> int:
    spec = _load_spec(args.scene, args.overrides)
    scene = build_from_spec(spec)
    cam = scene.camera
    ra, dec = (math.degrees(a) for a in unit_to_radec(scene.R_cam_icrs[2]))
    print(f"epoch {spec.epoch_tdb_iso} TDB   boresight RA {ra:.4f} deg  Dec {dec:.4f} deg   "
          f"camera {cam.width}x{cam.height}, FOV {math.degrees(cam.fov_x_rad):.2f} deg, {cam.exposure_s * 1e3:.0f} ms")
    r_au = np.linalg.norm(scene.position_km) / AU_KM
    print(f"observer {r_au:.4f} AU from the barycentre, {np.linalg.norm(scene.velocity_km_s):.3f} km/s;  "
          f"Sun {math.degrees(scene.boresight_sun_angle_rad):.2f} deg from the boresight "
          f"(exclusion {math.degrees(scene.visibility.sun_exclusion_rad):.0f} deg; visible: V <= {scene.visibility.limiting_v_mag:g})")
    print()
    print(f"{'body':<9} {'V':>7} {'x px':>9} {'y px':>9} {'light-time s':>13} {'aberr. arcsec':>14} "
          f"{'diam px':>8} {'phase deg':>9} {'elong deg':>9}  flags")
    for b in sorted(scene.bodies, key=lambda b: (not b.in_fov, b.v_mag)):
        flags = ",".join(f for f, on in (("in_fov", b.in_fov), ("visible", b.visible), ("resolved", b.resolved)) if on)
        print(f"{b.name:<9} {_fmt(b.v_mag, '7.2f')} {_fmt(b.xy[0], '9.2f') if b.in_fov else '        -'} "
              f"{_fmt(b.xy[1], '9.2f') if b.in_fov else '        -'} {b.light_time_s:13.3f} {b.aberration_arcsec:14.3f} "
              f"{b.angular_diameter_px:8.3f} {math.degrees(b.phase_angle_rad):9.2f} {math.degrees(b.elongation_rad):9.2f}  {flags}")
    print()
    vm = scene.stars.v_mag[scene.stars.in_fov]
    edges = [-2, 3, 4, 5, 6, 7, 8, scene.catalog_limiting_v_mag]
    edges = sorted(set(e for e in edges if e <= scene.catalog_limiting_v_mag))
    counts = [int(((vm > lo) & (vm <= hi)).sum()) for lo, hi in zip(edges[:-1], edges[1:])]
    print(f"stars in view: {len(vm)} (V <= {scene.catalog_limiting_v_mag:g})   " +
          "  ".join(f"V {lo:g}..{hi:g}: {n}" for lo, hi, n in zip(edges[:-1], edges[1:], counts)))
    return 0


# ----------------------------------------------------------------------------- render
def cmd_render(args) -> int:
    facility = render_facility(args) if args.facility is not None else None
    spec = _load_spec(args.scene, args.overrides, camera=facility.camera if facility is not None else None)
    seed = spec.seed if args.seed is None else args.seed
    check_stem(args.name, what="--name")
    check_output_dir(args.output, what="-o/--output folder")  # before the work, not after
    if facility is not None:
        return render_hil(args, facility, spec, seed)
    t0 = time.perf_counter()
    scene = build_from_spec(spec)
    options = RenderOptions(noise=not args.no_noise, backend=args.backend,
                            cosmic_rays_per_frame=spec.cosmic_rays_per_frame, mitsuba_spp=spec.mitsuba_spp)
    frame = render(scene, seed=seed, options=options)
    t1 = time.perf_counter()
    out = Path(args.output)
    formats = ("png", "exr", "json") + (("fits",) if args.fits else ())
    files = write_frame(frame, out, args.name, formats=formats)
    if args.preview:
        files["preview"] = write_preview(frame.dn, out, args.name)
    t2 = time.perf_counter()
    truth = frame.truth
    stars = truth["stars"]
    maxdn = (1 << scene.camera.sensor.bit_depth) - 1
    say(args, f"rendered {scene.camera.width}x{scene.camera.height} frame in {t1 - t0:.2f} s (seed {seed}), wrote in {t2 - t1:.2f} s")
    say(args, f"sources: {len(stars)} stars in view, "
          f"{sum(b['in_fov'] for b in truth['bodies'])} bodies in view, {len(truth['cosmic_rays'])} cosmic rays")
    for b in truth["bodies"]:
        if b["in_fov"]:
            say(args, f"  {b['name']}: V {b['v_mag']:.2f} at ({b['xy'][0]:.2f}, {b['xy'][1]:.2f}) px, "
                  f"{b['electrons']:.4g} e-, {b['rendered_as']}{', visible' if b['visible'] else ''}")
    if stars:
        s = min(stars, key=lambda s: s["v_mag"])
        say(args, f"  brightest star: HIP {s['hip']} V {s['v_mag']:.2f} at ({s['xy'][0]:.2f}, {s['xy'][1]:.2f}) px, {s['electrons']:.4g} e-")
    say(args, f"saturated pixels: {int((frame.dn >= maxdn).sum())}   max DN {int(frame.dn.max())} of {maxdn}")
    for fmt, path in files.items():
        say(args, f"  {fmt:<5} {path}")
    return 0


# ----------------------------------------------------------------------------- parser
def add_parser(sub) -> None:
    """Register ``scene`` and ``render`` on the top-level subparsers."""
    s = sub.add_parser("scene", help=COMMAND_HELP["scene"],
                       description="Compute a scene and print what the camera sees: bodies with magnitude, "
                       "apparent pixel position, light-time and aberration; star counts by magnitude; Sun angle.")
    add_scene_arg(s)
    add_set_arg(s, "the scene file (or preset), e.g. --set camera.fov_deg=10")
    s.set_defaults(func=cmd_scene)

    r = sub.add_parser("render", help=COMMAND_HELP["render"],
                       description="Render one frame of a scene: PNG (digital counts), EXR (electrons, irradiance), "
                       "ground-truth JSON; optional FITS with a TAN WCS. --set changes any key of the scene file "
                       "(or preset) before it is read, e.g. --set camera.exposure_s=0.2 --set "
                       "render.cosmic_rays_per_frame=0 --set camera.width=256 --set camera.height=256.")
    add_scene_arg(r)
    add_output_arg(r, required=False, default="skynav-out", help="output folder (default: skynav-out)")
    r.add_argument("--name", default="frame", help="file stem (default: frame)")
    add_seed_arg(r, default=None, help="random seed (default: the scene's render.seed)")
    r.add_argument("--fits", action="store_true", help="also write FITS with a TAN WCS")
    r.add_argument("--no-noise", action="store_true", help="digital counts of the expected signal: no sensor noise, no cosmic rays (the same frame for every seed)")
    r.add_argument("--preview", action="store_true",
                   help="also write NAME_preview.png, an 8-bit quick look for the eye (zscale limits, asinh stretch; "
                        "the PNG beside it keeps the physical DN, which a viewer shows nearly black)")
    add_quiet(r)
    r.add_argument("--backend", choices=("auto", "llvm", "cuda", "numpy"), default="auto", help="sensor noise backend")
    add_facility_arg(r, required=False, former_option="--hil",
                     help="render the screen frame of this hardware-in-the-loop facility instead (a facility YAML "
                          "file or preset: screen, screen_small)")
    add_set_arg(r, "the scene file (or preset): camera.*, observer.*, attitude.*, visibility.*, render.*")
    r.set_defaults(func=cmd_render)
