"""``skynav calibrate``: patterns, simulate, geometric, radiometric (thin wrappers over skynav.calibration and its file side, skynav.calibration.bench_files)."""

from __future__ import annotations

from pathlib import Path

from skynav.calibration.bench_files import calibrate_geometric, simulate, write_patterns
from skynav.calibration.facility_io import load_facility, write_facility
from skynav.calibration.geometric import MAX_HOLDOUT
from skynav.calibration.patterns import MAX_PHASES
from skynav.calibration.plots import radiometric_figure, residual_figure
from skynav.calibration.radiometric import calibrate_radiometric
from skynav.calibration.virtual_bench import MAX_FRAMES, SCENARIO_NAMES
from skynav.datasets.plots import figure_png
from skynav.infra.atomic_files import atomic_write_bytes
from skynav.infra.count_cap import cap_count

from .cli_args import add_facility_arg, add_output_arg, add_quiet, add_seed_arg, float_in, int_in
from .cli_common import COMMAND_HELP, ProgressBar, check_output, say


def _write_figure(fig, path) -> Path:
    """Write a calibration figure as PNG (atomic), next to the facility file."""
    atomic_write_bytes(path, figure_png(fig))
    return Path(path)


def _check_plot_path(output, suffix, inputs) -> None:
    """The figure written next to ``output`` must not overwrite an input either."""
    out = Path(output)
    check_output(out.with_name(out.stem + suffix), [("input", p) for p in inputs], flag=f"-o {output}: its figure",
                 kind="file")


def cmd_patterns(args) -> int:
    check_output(args.output, [("facility", args.facility)])
    fac = load_facility(args.facility)
    pats = write_patterns(fac, args.output, phases=args.phases)
    dots = [p for p in pats if p.kind == "dots"]
    say(args, f"wrote {len(pats)} patterns to {args.output}: {len(dots)} dot grids ({len(dots[0].dots)} dots each, step "
          f"{dots[0].grid_step_px:g} screen px, {len(dots[0].fiducials)} fiducials), "
          f"{sum(p.kind == 'flat' for p in pats)} flats, 1 dark; {fac.screen.width_px}x{fac.screen.height_px} px, {fac.screen.bit_depth}-bit")
    return 0


def cmd_simulate(args) -> int:
    check_output(args.output, [("facility", args.facility), ("--patterns", args.patterns)])
    args.frames = cap_count(args.frames, "--frames (exposures averaged per capture)")
    fac = load_facility(args.facility)
    fac.check_coverage()
    with ProgressBar("capturing", "capture", quiet=args.quiet) as bar:
        s = simulate(fac, args.patterns, args.output, scenario_name=args.scenario, seed=args.seed, frames=args.frames,
                     progress=bar)
    say(args, f"virtual bench '{s['scenario']}': wrote {s['captures']} captures and power_meter.csv ({s['measurements']} readings) to {args.output}")
    return 0


def cmd_geometric(args) -> int:
    check_output(args.output, [("facility", args.facility), ("--patterns", args.patterns), ("--captures", args.captures)],
                 kind="file")
    _check_plot_path(args.output, "_residuals.png", [args.facility])
    fac = load_facility(args.facility)
    fac.check_coverage()
    res = calibrate_geometric(fac, args.patterns, args.captures, holdout=args.holdout, seed=args.seed)
    out = Path(args.output)
    write_facility(res.facility, out)
    plot = _write_figure(residual_figure(res.holdout_arcsec, res.fit_arcsec), out.with_name(out.stem + "_residuals.png"))
    s = res.summary()
    fit = res.facility.calibrated_geometric["fit"]
    say(args, f"identified {sum(v[0] for v in res.per_pattern.values())} dots in {len(res.per_pattern)} captures; "
              f"fit on {s['n_fit']}, held out {s['n_holdout']}; {res.seconds:.1f} s",
        f"held-out line-of-sight residual: p50 {s['p50']:.3f}  p99 {s['p99']:.3f}  max {s['max']:.3f} arcsec "
        f"({fit['excluded_outliers']} gross outliers excluded, {fit['excluded_holdout_outliers']} of them held out)",
        f"wrote {out} and {plot}")
    return 0


def cmd_radiometric(args) -> int:
    check_output(args.output, [("facility", args.facility), ("--measurements", args.measurements)], kind="file")
    _check_plot_path(args.output, "_radiometric.png", [args.facility, args.measurements])
    fac = load_facility(args.facility)
    res = calibrate_radiometric(fac, args.measurements)
    out = Path(args.output)
    write_facility(res.facility, out)
    plot = _write_figure(radiometric_figure(res), out.with_name(out.stem + "_radiometric.png"))
    rm = res.facility.radiometric
    say(args, f"fit: black {rm.black_w_m2:.4g} W/m^2, peak {rm.peak_w_m2:.4g} W/m^2 per lit pixel, gamma {rm.gamma:.4f}; "
              f"rms {100 * res.rms_relative:.2f} % over {len(res.dn)} readings",
        f"usable: DN {res.usable_dn[0]}..{res.usable_dn[1]}, V {res.usable_v_mag[1]:.2f} .. {res.usable_v_mag[0]:.2f} "
        f"(A0V star over {res.facility.calibrated_radiometric['usable_range']['psf_pixels']:g} screen px)",
        f"wrote {out} and {plot}")
    return 0


def add_parser(sub) -> None:
    c = sub.add_parser("calibrate", help=COMMAND_HELP["calibrate"],
                       description="Facility calibration: write patterns, simulate captures on a virtual bench, fit the "
                       "geometric and radiometric models into a facility file. FACILITY: a YAML file or a preset (screen, screen_small).")
    cs = c.add_subparsers(dest="calibrate_command", metavar="STEP")
    c.set_defaults(func=lambda a: (c.print_help(), 2)[1])

    p = cs.add_parser("patterns", help="write pattern PNGs and patterns.json")
    add_facility_arg(p, required=True, former_positional=True)
    add_output_arg(p, help="pattern folder")
    p.add_argument("--phases", type=int_in(1, MAX_PHASES, f"{MAX_PHASES}: {MAX_PHASES ** 2} dot grids, each a screen PNG "
                                             "and a capture"), default=3,
                   help=f"grid phases per axis, 1..{MAX_PHASES} (default 3: 9 dot grids; {MAX_PHASES}: {MAX_PHASES ** 2}, "
                        "each a screen-sized PNG and a capture)")
    add_quiet(p)
    p.set_defaults(func=cmd_patterns)

    s = cs.add_parser("simulate", help="capture the patterns on a virtual bench (+ power_meter.csv)")
    add_facility_arg(s, required=True, former_positional=True)
    s.add_argument("--patterns", required=True, help="pattern folder")
    add_output_arg(s, help="captures folder")
    s.add_argument("--scenario", choices=SCENARIO_NAMES, default="realistic", help="the virtual bench's true facility (default realistic)")
    s.add_argument("--frames", type=int_in(1, MAX_FRAMES, "each is a full camera frame of noise"), default=16,
                   help=f"exposures averaged per capture, 1..{MAX_FRAMES} (default 16; each is a full camera frame of "
                        "noise per pattern: time grows with it)")
    add_seed_arg(s, default=0, help="seed of the virtual bench's noise (default 0)")
    add_quiet(s)
    s.set_defaults(func=cmd_simulate)

    g = cs.add_parser("geometric", help="fit the geometric model (and flat field) from captures")
    add_facility_arg(g, required=True, former_positional=True)
    g.add_argument("--patterns", required=True, help="pattern folder")
    g.add_argument("--captures", required=True, help="captures folder")
    add_output_arg(g, help="calibrated facility YAML")
    g.add_argument("--holdout", type=float_in(0, MAX_HOLDOUT, low_open=True), default=0.2,
                   help=f"fraction of dots held out of the fit to measure its error, in (0, {MAX_HOLDOUT:g}] (default 0.2)")
    add_seed_arg(g, default=0, help="seed of the held-out draw (default 0)")
    add_quiet(g)
    g.set_defaults(func=cmd_geometric)

    r = cs.add_parser("radiometric", help="fit the radiometric curve from power-meter readings")
    add_facility_arg(r, required=True, former_positional=True)
    r.add_argument("--measurements", required=True, help="CSV: digital_count,lit_pixels,irradiance_w_m2")
    add_output_arg(r, help="calibrated facility YAML")
    add_quiet(r)
    r.set_defaults(func=cmd_radiometric)
