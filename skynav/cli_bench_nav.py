"""``skynav bench nav``: Monte Carlo EKF campaign on a ``sequence`` dataset.

Registered by ``skynav/cli_bench.py`` (``SUBCOMMAND_MODULES``) through :func:`add_parser`.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import time
from dataclasses import replace
from pathlib import Path

from tqdm.auto import tqdm

import skynav.datasets as sdat
from skynav.infra.count_cap import cap_count
from skynav.pipeline.filter_dynamics import FilterDynamics
from skynav.pipeline.flight import DEFAULT_FILTER, DEFAULT_PIPELINE, pipeline_spec
from skynav.pipeline.references import NAVIGATION
from skynav.pipeline.scoring import DEFAULT_FRAME_TIMEOUT_S
from skynav.pipeline.scoring_nav import (
    CentroidNoise,
    NavInputError,
    calibrate_sigma_px,
    check_realisations,
    load_plan,
    run_campaign,
    run_realisations,
)
from skynav.pipeline.scoring_nav_filters import (
    filter_specs,
    filters_figure_html,
    filters_lines,
    filters_markdown,
    filters_summary,
)
from skynav.pipeline.scoring_nav_report import PAPER_002, summarise, write_report
from skynav.pipeline.scoring_nav_results import NAV_RESULTS_SCHEMA, score_nav_results, write_nav_results
from skynav.pipeline.star_id import star_id_camera_check
from skynav.scenes.constants import SECONDS_PER_DAY
from skynav.scenes.overrides import OverrideError

from .cli_args import (
    MAX_WORKERS,
    add_dataset_arg,
    add_limit_arg,
    add_output_arg,
    add_quiet,
    add_seed_arg,
    add_set_arg,
    add_workers_arg,
    float_in,
    int_in,
    positive_int,
)
from .cli_common import check_output, say, warn

#: most Monte Carlo runs (each run's filter history, frames x 6 states, is kept for the report)
MAX_RUNS = 100_000
#: the largest centroid sigma (px) --sigma-px takes: beyond it no star is matched anyway
MAX_SIGMA_PX = 100.0


def cmd_nav(args) -> int:
    check_output(args.output, [("dataset", args.dataset), ("--images", args.images)])
    cases = list(dict.fromkeys(args.case))
    for c in cases:
        if c not in (1, 2, 3, 4, 5):
            raise NavInputError(f"--case {c}: give 1, 2, 3, 4 or 5")
    if args.runs < 2:
        raise NavInputError(f"--runs {args.runs}: at least 2 runs are needed for sample statistics")

    args.runs = cap_count(args.runs, "--runs", minimum=2)
    if args.sigma_px is not None and not args.sigma_px > 0:
        raise NavInputError(f"--sigma-px {args.sigma_px}: give a positive number of pixels")
    _dynamics(args)  # refuse a bad --set or --gm-sigma before reading the dataset
    filters = filter_specs(args.filter)   # refuse a bad import path before reading the dataset
    args.pipeline = pipeline_spec(args.pipeline)
    t0 = time.perf_counter()
    plan, realisations, calib = _datasets(args)
    if args.sigma_px is None:
        noise = calibrate_sigma_px(calib, stride=args.calibration_stride, seed=args.seed,
                                   phase_offset=not args.no_phase_offset, pipeline=args.pipeline,
                                   frame_timeout_s=args.frame_timeout)

        noise = replace(noise, track_bias_in_r=bool(args.track_bias_in_r))
    else:
        noise = CentroidNoise(sigma0_px=float(args.sigma_px))
    dynamics = _dynamics(args)
    setup_s = time.perf_counter() - t0
    results, by_filter = {}, {}
    for spec in filters:   # the first filter flies every case; the others the first case, beside it
        for c in (cases if spec == filters[0] else cases[:1]):
            res = _campaign(args, plan, realisations, c, spec, noise, dynamics)
            if spec == filters[0]:
                results[c] = res
            if c == cases[0]:
                by_filter[spec] = res
    ip_s = sum(r.ip_time_s for r in results.values()) + sum(r.ip_time_s for s, r in by_filter.items() if s != filters[0])
    fl_s = sum(r.filter_time_s for r in results.values()) + sum(r.filter_time_s for s, r in by_filter.items()
                                                                 if s != filters[0])
    total = time.perf_counter() - t0
    primary = cases[0]
    summary = summarise(results, primary=primary, time_s=total, plan=plan)
    summary["filters"] = filters_summary(by_filter, plan=plan)
    info = {"source": str(args.dataset), "realisations": [str(d) for d in args.realisations or []],
            "phase_offset": not args.no_phase_offset, "images": args.images, "seed": int(args.seed), "workers": int(args.workers),
            "cases": cases, "calibrated_on": [str(p.root) for p in calib], "gm_sigma_km_s2": args.gm_sigma, "dynamics": {k: getattr(dynamics or _default_dynamics(), k) for k in DYNAMICS_KEYS}, "noise": noise.describe(), "setup_time_s": setup_s, "ip_time_s": ip_s,
            "filter_time_s": fl_s, "filters": filters, "pipeline": args.pipeline}
    side = len(by_filter) > 1
    out = write_report(args.output, results, summary, primary=primary, plan=plan, info=info,
                       extra_md=filters_markdown(summary["filters"]) if side else (),
                       extra_html=[filters_figure_html(by_filter)] if side else ())
    if args.write_states:
        write_nav_results(Path(out, "states.jsonl"), results[primary], plan)
    _say_summary(args, summary, noise, total, setup_s, ip_s, fl_s, out)
    return 0


def _datasets(args):
    """``(plan, realisations or None, calibration plans)`` of the command line, checked."""
    plan = load_plan(args.dataset, images=args.images, limit=args.limit)
    error, warning = star_id_camera_check(sdat.open(plan.root).camera)
    if error:
        raise NavInputError(f"{args.dataset}: {error}")
    if warning:
        warn(f"{args.dataset}: {warning}")
    realisations = None
    if args.realisations:
        if args.images is not None:
            raise NavInputError("--images and --realisations: give one or the other")
        realisations = [load_plan(d, limit=args.limit) for d in args.realisations]
        check_realisations(realisations, plan)
    calib = [plan]
    if args.calibrate_on:
        if args.sigma_px is not None:
            raise NavInputError("--sigma-px and --calibrate-on: give one or the other")
        calib += [load_plan(d, limit=args.limit) for d in args.calibrate_on]
        check_realisations(calib[1:], plan)
    if realisations is not None and args.sigma_px is None:
        # R comes from DATASET (and --calibrate-on): none of them may be a navigated rendering
        navigated = {Path(p.root).resolve() for p in realisations}
        for i, p in enumerate(calib):
            if Path(p.root).resolve() in navigated:
                raise NavInputError(f"{p.root}: in both {'DATASET' if i == 0 else '--calibrate-on'} and "
                                    "--realisations; R must be calibrated out of sample (give other renderings)")
    return plan, realisations, calib


def _campaign(args, plan, realisations, case, spec, noise, dynamics):
    """One campaign (case ``case``, filter ``spec``) with its progress bar."""
    name = "" if spec == DEFAULT_FILTER else f", {spec}"
    bar = None
    if realisations is not None:
        if not args.quiet:
            bar = tqdm(total=len(realisations), unit="sequence", desc=f"case {case}{name}, {args.runs} runs")
        res = run_realisations(realisations, runs=args.runs, case=case, seed=args.seed, workers=args.workers,
                               noise=noise, phase_offset=not args.no_phase_offset, reference=plan, dynamics=dynamics,
                               progress=None if bar is None else bar.update, filter_spec=spec, pipeline=args.pipeline,
                               frame_timeout_s=args.frame_timeout)
    else:
        if not args.quiet and args.workers == 1:
            bar = tqdm(total=plan.frames, unit="frame", desc=f"case {case}{name}, {args.runs} runs")
        res = run_campaign(plan, runs=args.runs, case=case, seed=args.seed, workers=args.workers, noise=noise,
                           dynamics=dynamics, phase_offset=not args.no_phase_offset,
                           progress=None if bar is None else bar.update, filter_spec=spec, pipeline=args.pipeline,
                           frame_timeout_s=args.frame_timeout)
    if bar is not None:
        bar.close()
    return res


def _say_summary(args, summary, noise, total, setup_s, ip_s, fl_s, out) -> None:
    f = summary["final"]
    n = summary["nees"]
    primary = summary["case"]
    say(args, f"{summary['runs']} runs x {summary['frames']} frames, case {primary}: final 3-sigma "
              f"{f['position_3sigma_km']:.0f} km (filter {f['filter_position_3sigma_km']:.0f}), "
              f"{f['velocity_3sigma_m_s']:.3f} m/s (filter {f['filter_velocity_3sigma_m_s']:.3f}); {NAVIGATION.cite}: "
              f"{PAPER_002['position_3sigma_km']:.0f} km, {PAPER_002['velocity_3sigma_m_s']:.2f} m/s")
    say(args, f"  NEES (normalised estimation error squared: the squared error over the filter's own covariance; a "
          f"consistent filter stays in the band) mean {n['mean']:.2f} (band {n['band_low']:.2f}..{n['band_high']:.2f}, "
          f"{100 * n['fraction_inside']:.0f} % of frames inside; band of the {n['independent_sequences']} independent "
          f"image sequence(s) {n['band_sequences_low']:.2f}..{n['band_sequences_high']:.2f})",
          f"  R, the filter's measurement noise (sigma: the standard deviation of a planet's measured centre, "
          f"D: its predicted apparent diameter in px): {noise.describe()}")
    for c, v in summary["cases"].items():
        say(args, f"  case {c}: RMSE {v['position_rmse_km']:.0f} km, {v['velocity_rmse_m_s']:.3f} m/s")
    for line in filters_lines(summary["filters"]):
        say(args, "  " + line)
    say(args, f"  time {total:.1f} s (setup {setup_s:.1f}, image processing {ip_s:.1f}, filter {fl_s:.1f})",
        f"report: {out}/report.html")


def cmd_score_nav(args) -> int:
    """``bench score nav``: navigation states written by any program, scored as ``bench nav`` scores its runs."""
    check_output(args.output, [("dataset", args.dataset)] + [("RESULTS", r) for r in args.results])
    t0 = time.perf_counter()
    plan = load_plan(args.dataset, limit=args.limit)
    by_file, plans, infos = {}, {}, []
    for path in dict.fromkeys(args.results):
        res, sub, info = score_nav_results(plan, path)
        by_file[str(path)], plans[str(path)] = res, sub
        infos.append(info)
    first = next(iter(by_file))
    res, sub = by_file[first], plans[first]
    summary = summarise({res.case: res}, primary=res.case, time_s=time.perf_counter() - t0, plan=sub)
    summary["filters"] = filters_summary(by_file, plan=sub, plans=plans)
    info = {"source": f"{args.dataset}: {', '.join(by_file)}", "seed": None, "noise": "not given (a results file)",
            "results_files": infos, "schema": NAV_RESULTS_SCHEMA}
    out = write_report(args.output, {res.case: res}, summary, primary=res.case, plan=sub, info=info,
                       extra_md=filters_markdown(summary["filters"]), extra_html=[filters_figure_html(by_file)])
    for row, i in zip(summary["filters"], infos):
        f, n = row["final"], row["nees"]
        nees = "no covariance" if not i["with_covariance"] else f"NEES mean {n['mean']:.2f} (band {n['band_low']:.2f}.."
        nees += "" if not i["with_covariance"] else f"{n['band_high']:.2f})"
        say(args, f"{row['filter']}: {i['runs']} runs x {i['frames_scored']} of {i['frames']} frames: final 3-sigma "
                  f"{f['position_3sigma_km']:.0f} km, {f['velocity_3sigma_m_s']:.3f} m/s; RMS error over the last leg "
                  f"{f['position_error_rms_km']:.0f} km; {nees}")
    say(args, f"report: {out}/report.html")
    return 0


def add_score_parser(ssub) -> None:
    """Register ``nav`` on the ``bench score`` sub-parsers."""
    p = ssub.add_parser("nav", help=f"navigation states ({NAV_RESULTS_SCHEMA}) written by any program, per frame and run",
                        description="Score navigation results files (JSON Lines; schema "
                        "skynav/datasets/schemas/nav_results.schema.json: frame, run, position_km, velocity_km_s, "
                        "optional t_tdb_s, covariance_km_km_s, status, time_ms) against a sequence dataset's truth, as "
                        "bench nav scores its runs (final 3-sigma, RMS error, NEES), side by side when several are given.")
    add_dataset_arg(p, "the 'sequence' dataset the states were estimated on")
    p.add_argument("results", nargs="+", metavar="RESULTS", help="results file(s), JSON Lines")
    add_limit_arg(p)
    add_output_arg(p, help="report folder")
    add_quiet(p)
    p.set_defaults(func=cmd_score_nav)


#: FilterDynamics fields ``--set dynamics.FIELD=VALUE`` may change (the scalar ones)
DYNAMICS_KEYS = ("correlation_time_s", "sigma_residual_km_s2", "sigma_srp_km_s2", "rtol", "atol")


def _default_dynamics():
    return FilterDynamics()


def _dynamics(args):
    """The filter's FilterDynamics from ``--gm-sigma`` then ``--set dynamics.FIELD=VALUE`` (in order),
    or None for the defaults. Each value must be a positive finite number."""
    kw = {}
    if args.gm_sigma is not None:
        if not 0 < args.gm_sigma < 1e-6:
            raise NavInputError(f"--gm-sigma {args.gm_sigma}: give a steady-state sigma in km/s^2 between 0 and 1e-6")
        kw.update(sigma_residual_km_s2=args.gm_sigma, sigma_srp_km_s2=args.gm_sigma)
    for text, path, value in args.overrides:
        name = ".".join(str(p) for p in path)
        if len(path) != 2 or path[0] != "dynamics" or path[1] not in DYNAMICS_KEYS:
            raise OverrideError(f"--set {text}: bench nav has no key {name}; allowed keys: "
                                + ", ".join(f"dynamics.{k}" for k in DYNAMICS_KEYS))
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not (math.isfinite(value) and value > 0):
            raise OverrideError(f"--set {text}: {name} = {value!r} is not allowed; expected a positive finite number")
        kw[path[1]] = float(value)
    return dataclasses.replace(FilterDynamics(), **kw) if kw else None


def add_filter_arg(p) -> None:
    """``--filter MODULE:FACTORY`` (repeatable), shared by ``bench nav`` and ``bench loop``."""
    p.add_argument("--filter", action="append", metavar="MODULE:FACTORY", default=None,
                   help=f"the navigation filter to fly, imported by path (docs/navigation.md, 'Bring your own filter'); "
                        f"repeat it to compare several side by side on the same frames and initial states "
                        f"(default {DEFAULT_FILTER}, skynav's EKF)")


def add_pipeline_arg(p) -> None:
    """``--pipeline MODULE:FACTORY`` (once), shared by ``bench nav`` and ``bench loop``."""
    p.add_argument("--pipeline", action="append", metavar="MODULE:FACTORY", default=None,
                   help=f"the image processor of the flight, imported by path (docs/benchmark.md, 'Bring your own "
                        f"image processing'; the noise calibration measures its centroids); one per run (compare "
                        f"processors side by side with 'skynav bench ip') (default skynav: {DEFAULT_PIPELINE})")
    p.add_argument("--frame-timeout", type=float_in(0, SECONDS_PER_DAY, low_open=True, unit="s"),
                   default=DEFAULT_FRAME_TIMEOUT_S,
                   help=f"the image processor's time limit per frame, s (default {DEFAULT_FRAME_TIMEOUT_S:g}); a frame "
                        "past it is a failed measurement with that reason")


def add_parser(bsub) -> None:
    """Register ``nav`` on the ``bench`` sub-parsers."""
    p = bsub.add_parser("nav", help="Monte Carlo EKF navigation campaign on a sequence dataset",
                        description="Run the image processing on every frame of a 'sequence' dataset and the EKF "
                        "(planet centroids, first-order light-time and aberration) over Monte Carlo initial errors; "
                        "score against the truth and write runs.csv, frames.csv, summary.json, report.md, report.html. "
                        "--set dynamics.FIELD=VALUE changes the filter's force and noise model; --pipeline MODULE:FACTORY "
                        "flies anyone's image processor; skynav's image processing "
                        "runs with the pipeline's default ProcessOptions (try others on single frames with "
                        "'skynav bench ip --set'; change the images with 'skynav dataset generate --set').")
    add_dataset_arg(p, "a 'sequence' dataset folder")
    p.add_argument("--runs", type=int_in(2, MAX_RUNS, "every run's filter history is kept for the report"), default=50,
                   help=f"Monte Carlo runs, 2..{MAX_RUNS} (default 50; every run's filter history is kept in memory for "
                        "the report)")
    p.add_argument("--case", type=int, nargs="+", default=[1],
                   help="measurement-model cases of Andreis et al. (2024), Sec. 5.2 (1..5; several run in turn; "
                   "the first is plotted)")
    add_seed_arg(p, default=0, help="seed of the initial-error draws (default 0)")
    add_workers_arg(p, default=1, help=f"processes, 1..{MAX_WORKERS}; the runs are split among them (default 1)")
    p.add_argument("--images", default=None, help="folder of NNNNNN.png to use instead of the dataset's images")
    p.add_argument("--realisations", nargs="+", metavar="SEQ", default=None,
                   help="other renderings of the same cruise (skynav dataset generate sequence --seed K): the runs are "
                   "dealt over them, so they have independent image noise (the filter-consistency Monte Carlo); "
                   "DATASET then only calibrates R (out of sample)")
    p.add_argument("--calibrate-on", nargs="+", metavar="SEQ", default=None,
                   help="more renderings of the same cruise whose frames are pooled with DATASET's to measure R "
                   "(the track-constant errors then describe the ensemble of sensors, not one rendering's draw)")
    p.add_argument("--sigma-px", type=float_in(0, MAX_SIGMA_PX, low_open=True, unit="px"), default=None,
                   help="measurement noise, px (default: measured on the dataset's frames)")
    p.add_argument("--no-phase-offset", action="store_true",
                   help="model the planet's centre, not its Lambert centre of light (the model of Andreis et al. 2024)")
    p.add_argument("--track-bias-in-r", action=argparse.BooleanOptionalAction, default=True,
                   help="add each class's measured track-constant error to R as n sigma_b^2 per frame (default; "
                   "--no-track-bias-in-r: the class RMS only)")
    p.add_argument("--gm-sigma", type=float, default=None,
                   help="steady-state sigma of the filter's Gauss-Markov accelerations, km/s^2 (default 1e-11)")
    p.add_argument("--calibration-stride", type=positive_int, default=1,
                   help="frames between calibration frames (default 1: all)")
    add_filter_arg(p)
    add_pipeline_arg(p)
    p.add_argument("--write-states", action="store_true",
                   help=f"also write states.jsonl: every run's state at every frame (first filter, first case) in the "
                        f"results-file schema {NAV_RESULTS_SCHEMA} that 'bench score nav' reads")
    add_limit_arg(p)
    add_output_arg(p, help="report folder")
    add_quiet(p)
    add_set_arg(p, "the filter's dynamics (dynamics." + ", dynamics.".join(DYNAMICS_KEYS)
                     + "; e.g. dynamics.sigma_residual_km_s2=5e-12), applied after --gm-sigma")
    p.set_defaults(func=cmd_nav)


register_nav = add_parser
