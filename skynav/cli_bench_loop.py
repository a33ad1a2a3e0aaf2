"""``skynav bench loop``: closed-loop navigation against the render service (docs/service.md).

Registered by ``skynav/cli_bench.py`` (``SUBCOMMAND_MODULES``) through :func:`add_parser`.
"""

from __future__ import annotations

import contextlib
import json
import time
from pathlib import Path

import numpy as np

from skynav.datasets.recipes import recipe_camera
from skynav.pipeline.ekf import initial_covariance
from skynav.pipeline.flight import initial_states, pipeline_spec
from skynav.pipeline.scoring_nav import NavInputError
from skynav.pipeline.scoring_nav_filters import filter_specs, filters_figure_html, filters_lines, filters_markdown, filters_summary
from skynav.pipeline.scoring_nav_report import summarise, write_report
from skynav.pipeline.star_id import star_id_camera_check
from skynav.service.client import Client, LocalServer
from skynav.service.loop import (
    CALIBRATION_FRAMES,
    Simulator,
    bias_for_lost_planet,
    calibrate_loop_noise,
    campaign_result,
    centroid_noise,
    loop_summary,
    nav_plan,
    perpendicular_bias,
    run_loop,
)

from .cli_args import (
    MAX_WORKERS,
    add_limit_arg,
    add_output_arg,
    add_quiet,
    add_recipe_arg,
    add_seed_arg,
    add_set_arg,
    add_workers_arg,
    positive_int,
)
from .cli_bench_nav import add_filter_arg, add_pipeline_arg
from .cli_common import ProgressBar, say, warn
from .cli_dataset import recipe_from_args


def _bias_km(args):
    """Check the flags no argparse type checks; the ``--bias-km`` start: None, ``"auto"`` or km."""
    if args.runs < 1:
        raise NavInputError(f"--runs {args.runs}: give at least 1")
    if args.realtime is not None and not args.realtime > 0:
        raise NavInputError(f"--realtime {args.realtime}: give a positive number of simulated seconds per wall second")
    if args.sigma_px is not None and not args.sigma_px > 0:
        raise NavInputError(f"--sigma-px {args.sigma_px}: give a positive number of pixels")
    if args.sigma_px is not None and args.calibration_stride is not None:
        raise NavInputError("--sigma-px and --calibration-stride: give one or the other (a given sigma is not measured)")
    if args.case not in (1, 2, 3, 4, 5):
        raise NavInputError(f"--case {args.case}: give 1, 2, 3, 4 or 5")
    bias = None if args.bias_km in ("0", "none") else args.bias_km
    if bias not in (None, "auto"):
        try:
            bias = float(bias)
        except ValueError:
            bias = -1.0
        if not bias > 0:
            raise NavInputError(f"--bias-km {args.bias_km}: give auto, none or a positive number of km")
    return bias


def _noise(args, sim, client):
    """The centroid noise the filter assumes: ``--sigma-px``, or measured through the service."""
    if args.sigma_px is not None:
        return centroid_noise(args.sigma_px)
    stride = args.calibration_stride or max(1, sim.frames // CALIBRATION_FRAMES)
    with ProgressBar("noise calibration", "frame", quiet=args.quiet) as bar:
        n_cal, done_cal = len(range(0, sim.frames, stride)), [0]

        def tick_cal(n):
            done_cal[0] += n
            bar(done_cal[0], n_cal)

        return calibrate_loop_noise(sim, client, stride=stride, seed=args.seed, progress=tick_cal, pipeline=args.pipeline,
                                    frame_timeout_s=args.frame_timeout)


def _fly(args, sim, client, noise, bias, filters):
    """The Monte Carlo runs of every filter, then (with a bias) the first filter's biased start
    pointed from the truth and from the estimate: ``({filter: runs}, {pointing: run}, bias km or None)``."""
    r0, v0 = sim.state(sim.schedule()[0][0])
    x0s, P0 = initial_states(r0, v0, args.runs, args.seed)   # as bench nav's runs (Andreis et al. (2024), Eq. 45)
    nominal = np.concatenate([r0, v0, np.zeros(6)])
    extra = 2 if bias is not None else 0
    biased, b_km, flown = {}, None, {}
    with ProgressBar("closed loop", "frame", quiet=args.quiet) as bar:
        done = [0]

        def tick(n):
            done[0] += n
            bar(done[0], sim.frames * (args.runs * len(filters) + extra))

        # run i sees a rendering of its own (run 0 the recipe's), as bench nav --realisations; every
        # filter the same renderings and initial states
        for spec in filters:
            flown[spec] = [run_loop(sim, client, x0=x0, P0=P0, noise=noise, case=args.case, realtime=args.realtime,
                                    rendering=i, progress=tick, filter_spec=spec, pipeline=args.pipeline,
                                    frame_timeout_s=args.frame_timeout)
                          for i, x0 in enumerate(x0s)]
        if bias is not None:
            b_km = bias_for_lost_planet(sim) if bias == "auto" else bias
            xb = nominal.copy()
            xb[:3] += perpendicular_bias(sim, b_km)
            Pb = initial_covariance(sigma_position_km=b_km)   # the filter knows how uncertain it is
            for pointing in ("truth", "estimate"):
                biased[pointing] = run_loop(sim, client, x0=xb, P0=Pb, noise=noise, case=args.case,
                                            pointing=pointing, progress=tick, filter_spec=filters[0],
                                            pipeline=args.pipeline, frame_timeout_s=args.frame_timeout)
    return flown, biased, b_km


def _biased_summary(biased, b_km, camera) -> dict:
    """``loop.json``'s ``biased_initial_state``: the same biased start open and closed loop."""
    return {"bias_km": b_km, "initial_position_sigma_km": b_km, **{
        ("open_loop" if p == "truth" else "closed_loop"): {
            **{k: v for k, v in loop_summary([r], camera, realtime=None).items()
               if k in ("target_in_field_fraction", "target_centred_fraction", "first_frame_lost")},
            "final_position_error_km": float(np.linalg.norm(r.error[-1, :3])),
            "final_velocity_error_m_s": 1e3 * float(np.linalg.norm(r.error[-1, 3:])),
            "measurements_accepted": int(r.accepted.sum())}
        for p, r in biased.items()}}


def _say_summary(args, summary, loop, noise, res, total, setup_s, out) -> None:
    f = summary["final"]
    say(args, f"{summary['runs']} closed-loop runs x {summary['frames']} frames, case {args.case}: final 3-sigma "
              f"{f['position_3sigma_km']:.0f} km (filter {f['filter_position_3sigma_km']:.0f}), "
              f"{f['velocity_3sigma_m_s']:.3f} m/s (filter {f['filter_velocity_3sigma_m_s']:.3f})",
        f"  target in the field {100 * loop['target_in_field_fraction']:.1f} % of frames, centred (within "
        f"{loop['centred_within_px']:.0f} px) {100 * loop['target_centred_fraction']:.1f} %; latency median "
        f"{1e3 * loop['latency_s']['median']:.0f} ms, p99 {1e3 * loop['latency_s']['p99']:.0f} ms"
        + (f"; {loop['deadline_misses']} deadline misses at {args.realtime:g}x real time" if args.realtime else ""),
        f"  R, the filter's measurement noise (sigma: the standard deviation of a planet's measured centre, D: its "
        f"predicted apparent diameter in px): {noise.describe()}")
    if "biased_initial_state" in loop:
        b = loop["biased_initial_state"]
        for key, name in (("open_loop", "open loop (pointed from the truth, as a dataset)"),
                          ("closed_loop", "closed loop (pointed from the estimate)")):
            v = b[key]
            say(args, f"  biased start ({b['bias_km']:.3g} km): {name}: target in the field "
                      f"{100 * v['target_in_field_fraction']:.0f} %, final error {v['final_position_error_km']:.0f} km")
    for line in filters_lines(summary["filters"]):
        say(args, "  " + line)
    say(args, f"  time {total:.1f} s (setup {setup_s:.1f}, image processing {res.ip_time_s:.1f}, "
              f"filter and commands {res.filter_time_s:.1f})", f"report: {out}/report.html")


def cmd_loop(args) -> int:
    bias = _bias_km(args)
    filters = filter_specs(args.filter)   # a bad import path is one line before the service starts
    args.pipeline = pipeline_spec(args.pipeline)
    recipe = recipe_from_args(args.recipe, None, None, args.overrides)
    t0 = time.perf_counter()
    sim = Simulator(recipe, limit=args.limit)
    camera = recipe_camera(recipe)
    error, warning = star_id_camera_check(camera)
    if error:
        raise NavInputError(error)
    if warning:
        warn(warning)
    server = contextlib.nullcontext(args.service) if args.service else LocalServer(workers=args.workers)
    with server as url:
        client = Client(url, token=args.token)
        client.wait_ready(60)
        noise = _noise(args, sim, client)
        setup_s = time.perf_counter() - t0
        flown, biased, b_km = _fly(args, sim, client, noise, bias, filters)
        client.close()
    total = time.perf_counter() - t0
    runs = flown[filters[0]]
    plan = nav_plan(sim, runs)
    by_filter = {spec: campaign_result(r, plan, noise=noise, case=args.case, filter_name=spec) for spec, r in flown.items()}
    res = by_filter[filters[0]]
    summary = summarise({args.case: res}, primary=args.case, time_s=total, plan=plan)
    summary["filters"] = filters_summary(by_filter, plan=plan)
    loop = loop_summary(runs, camera, realtime=args.realtime)
    if biased:
        loop["biased_initial_state"] = _biased_summary(biased, b_km, camera)
    summary["closed_loop"] = loop
    info = {"source": f"{args.recipe} (closed loop through {'the service at ' + args.service if args.service else 'a local skynav serve'})",
            "seed": int(args.seed), "runs": int(args.runs), "cases": [args.case], "noise": noise.describe(),
            "setup_time_s": setup_s, "ip_time_s": res.ip_time_s, "filter_time_s": res.filter_time_s, "filters": filters,
            "pipeline": args.pipeline}
    side = len(by_filter) > 1
    out = write_report(args.output, {args.case: res}, summary, primary=args.case, plan=plan, info=info,
                       extra_md=filters_markdown(summary["filters"]) if side else (),
                       extra_html=[filters_figure_html(by_filter)] if side else ())
    Path(out, "loop.json").write_text(json.dumps(loop, indent=1) + "\n", encoding="utf-8")
    _say_summary(args, summary, loop, noise, res, total, setup_s, out)
    return 0


def add_parser(sub) -> None:
    p = sub.add_parser(
        "loop", help="closed-loop navigation: the EKF points the camera and asks the render service for frames",
        description="Closed-loop navigation on a sequence recipe (file or preset): at each frame time the flight "
        "software (skynav.pipeline) commands the attitude from its own estimate, the simulator adds the pointing "
        "controller's error (the recipe's pointing_error_deg) and asks the render service for the frame at the true "
        "state, the flight software processes it and updates the filter. The report is bench nav's plus loop.json: "
        "how often the target was in the field and centred, the latency, deadline misses with --realtime, and with "
        "--bias-km the same biased start pointed from the truth (as a dataset) and from the estimate.")
    add_recipe_arg(p, "sequence recipe YAML file or the preset 'sequence'")
    add_output_arg(p, help="report folder")
    p.add_argument("--runs", type=int, default=1, help="Monte Carlo runs, each its own closed loop (default 1)")
    p.add_argument("--realtime", type=float, default=None, metavar="SCALE",
                   help="run on a wall clock: SCALE simulated seconds per wall second")
    p.add_argument("--service", default=None, metavar="URL", help="use this running skynav serve (default: start one)")
    p.add_argument("--token", default=None, help="the service's token")
    add_workers_arg(p, default=1, help=f"workers of the server started here, 1..{MAX_WORKERS} (default 1)")
    p.add_argument("--sigma-px", type=float, default=None,
                   help="centroid noise the filter assumes, px (default: measured as bench nav measures it, on a "
                        "rendering of the cruise pointed from the truth that no run sees)")
    p.add_argument("--calibration-stride", type=positive_int, default=None, metavar="N",
                   help="measure the noise on every N-th frame (default: frames // 180, at least 1: about 180 frames; "
                        "each costs a frame from the service and its image processing)")
    p.add_argument("--case", type=int, default=1, help="light-effect case of the measurement model, 1-5 (default 1)")
    add_seed_arg(p, default=0,
                 help="seed of the initial states (the controller's pointing errors and the image noise come "
                        "from the recipe's seed, frame by frame as in its dataset: --set seed=N)")
    add_filter_arg(p)
    add_pipeline_arg(p)
    add_limit_arg(p, minimum=2, help="only the first N frames of the plan (at least 2)")
    p.add_argument("--bias-km", default="auto", metavar="KM",
                   help="also run a start this far off (auto: 1.5 half-fields at the first target; none: skip)")
    add_quiet(p)
    add_set_arg(p, "the recipe, e.g. --set sequence.legs=2 --set camera.width=256")
    p.set_defaults(func=cmd_loop)
