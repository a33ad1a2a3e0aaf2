"""``skynav bench``: benchmark navigation software on datasets.

The group is extensible: :data:`SUBCOMMAND_MODULES` names modules (``skynav.cli_bench_*``) that
expose ``add_parser(bench_subparsers)``; those present are registered, so ``nav`` (the EKF's
``skynav/cli_bench_nav.py``) joins ``ip`` without an edit here. ``bench score`` (results files
written by any program) is a group of its own: ``ip`` is here, and a module of
:data:`SUBCOMMAND_MODULES` with ``add_score_parser(score_subparsers)`` adds its own (``nav``).
"""

from __future__ import annotations

import functools
import importlib
from pathlib import Path

from skynav.pipeline.errors import BenchInputError
from skynav.pipeline.plugins import BUILTIN, SkynavProcessor, load_factory
from skynav.pipeline.process import ProcessOptions
from skynav.pipeline.scoring import DEFAULT_FRAME_TIMEOUT_S, run_benchmark, summarise, summarise_peers
from skynav.pipeline.scoring_results_file import score_results_file, write_predictions
from skynav.pipeline.scoring_report import write_report
from skynav.scenes.constants import SECONDS_PER_DAY
from skynav.scenes.overrides import dataclass_from_overrides

from .cli_args import add_dataset_arg, add_limit_arg, add_output_arg, add_quiet, add_seed_arg, add_set_arg, float_in
from .cli_common import COMMAND_HELP, check_output, say

#: the largest predicted-position sigma: 1e10 km is 67 au, beyond any mission's uncertainty
MAX_SIGMA_KM = 1e10
#: most predicted-position sigmas (every frame is processed once per sigma)
MAX_SIGMAS = 16

SUBCOMMAND_MODULES = ("skynav.cli_bench_nav", "skynav.cli_bench_loop")


def _sigmas(args) -> tuple:
    if len(args.position_sigma_km) > MAX_SIGMAS:
        raise BenchInputError(f"--position-sigma-km: {len(args.position_sigma_km)} values; at most {MAX_SIGMAS} (every "
                              "frame is processed once per value)")
    if any(not (s > 0) for s in args.position_sigma_km):
        raise BenchInputError("--position-sigma-km: every sigma must be > 0 km")
    return tuple(float(s) for s in args.position_sigma_km)


def _pipelines(args, options) -> list:
    """The processors of ``bench ip``: ``--pipeline`` in order (``skynav``: skynav's pipeline in
    ``--mode`` with ``--set``), default ``skynav``; ``--peers`` adds tetra3rs and cedar-solve."""
    specs = args.pipeline or ["skynav"]
    if args.overrides and "skynav" not in specs:
        raise BenchInputError("--set changes skynav's pipeline: add --pipeline skynav (the pipeline in --mode with "
                              "these options) or leave --pipeline out")
    out = [(f"skynav-{args.mode}", functools.partial(SkynavProcessor, mode=args.mode, options=options))
           if spec == "skynav" else spec for spec in specs]
    for spec in specs:
        if spec != "skynav":
            load_factory(spec)  # a bad import path: one line before any frame is read
    peers = [p for p in ("tetra3rs", "cedar-solve") if args.peers and p not in specs and BUILTIN[p] not in specs]
    return out + [BUILTIN[p] for p in peers]


def cmd_ip(args) -> int:
    if args.mode not in ("paper", "improved"):
        raise BenchInputError(f"--mode {args.mode!r}: give paper or improved")
    sigmas = _sigmas(args)
    check_output(args.output, [("DATASET", args.dataset)] + [("--results", r) for r in args.results])
    options = dataclass_from_overrides(ProcessOptions, args.overrides, what="ProcessOptions")
    rows, info = run_benchmark(args.dataset, sigmas_km=sigmas, mode=args.mode, seed=args.seed, progress=not args.quiet,
                               limit=args.limit, pipelines=_pipelines(args, options), frame_timeout_s=args.frame_timeout,
                               peers=args.peers)
    runs = info.pop("pipelines")
    info.pop("peer_rows")
    info.pop("peer_notes")
    for path in args.results:
        r_rows, _ = score_results_file(args.dataset, path, sigmas_km=sigmas, limit=args.limit)
        runs[Path(path).name] = r_rows
    if args.peers:
        summary_peers = summarise_peers({k: v for k, v in runs.items() if v is not rows}, rows, sigmas[0])
        info["peers"] = summary_peers
    return _report(args, runs, info, sigmas, source=args.dataset, mode=args.mode, seed=args.seed)


def _report(args, runs, info, sigmas, *, source, mode, seed) -> int:
    """Summaries of every processor's scores, the report, and the lines on stdout."""
    names = list(runs)
    summaries = {name: summarise(rs, frames=info["frames"], sigmas_km=sigmas) for name, rs in runs.items()}
    summary = dict(summaries[names[0]])
    summary["pipelines"] = summaries
    if "peers" in info:
        summary["peers"] = info.pop("peers")
    out = write_report(args.output, runs[names[0]], summary, sigmas_km=sigmas, mode=mode, seed=seed, source=source,
                       info=info, others={n: (runs[n], summaries[n]) for n in names[1:]})
    for name in names:
        s = summaries[name]
        a = s["attitude"]
        faults = sum(s["faults"].values())
        say(args, f"{name}: {s['frames']} frames: attitude correct {100 * a['correct_rate']:.2f} %, wrong "
                  f"{100 * a['wrong_rate']:.2f} %, none {100 * a['none_rate']:.2f} %, median {a['error_arcsec_median']:.2f} "
                  f"arcsec; time median {s['time_ms']['median']:.2f} ms" + (f"; {faults} faulted runs" if faults else ""))
        for why, k in s["faults"].items():
            say(args, f"  fault x {k}: {why}")
        for sig in sigmas:
            b = s["beacon"][f"{sig:g}"]
            say(args, f"  beacons sigma_r {sig:g} km: {b['beacons']} beacons, correct {100 * (b['correct_rate'] or 0):.2f} %, "
                      f"wrong {100 * (b['wrong_rate'] or 0):.2f} %, none {100 * (b['none_rate'] or 0):.2f} %")
    for name, why in info.get("notes", {}).items():
        say(args, f"{name}: not run ({why})")
    say(args, f"report: {out}/report.html")
    return 0


def cmd_score_ip(args) -> int:
    sigmas = _sigmas(args) if args.position_sigma_km else None
    check_output(args.output, [("DATASET", args.dataset)] + [("RESULTS", r) for r in args.results])
    runs, info = {}, {}
    for path in args.results:
        rows, info = score_results_file(args.dataset, path, sigmas_km=sigmas, limit=args.limit)
        sigmas = info["sigmas_km"]
        runs[Path(path).name] = rows
    info = {"frames": info["frames"], "results_files": [str(r) for r in args.results]}
    return _report(args, runs, info, sigmas, source=args.dataset, mode="results file", seed=0)


def cmd_predictions(args) -> int:
    sigmas = _sigmas(args)
    if Path(args.output).is_dir():
        raise BenchInputError(f"-o {args.output}: is a folder; give a file name (e.g. {Path(args.output) / 'predictions.jsonl'})")
    check_output(args.output, [("DATASET", args.dataset)], kind="file")
    n = write_predictions(args.dataset, args.output, sigmas_km=sigmas, seed=args.seed, limit=args.limit)
    say(args, f"{n} predicted states ({len(sigmas)} sigma(s) per frame): {args.output}")
    return 0


def _add_predictions(bsub) -> None:
    p = bsub.add_parser("predictions", help="write the predicted states bench ip gives every processor (JSON Lines)",
                        description="Write the on-board predicted states 'skynav bench ip' gives every processor, one "
                        "JSON line per frame and sigma (frame, sigma_km, position_km, velocity_km_s, position_cov_km2), "
                        "for a program that runs apart and writes a results file: a result line that repeats the "
                        "sigma_km is scored at that sigma.")
    add_dataset_arg(p, "dataset folder, or a folder of NNNNNN.png + .json frames")
    _add_sigmas(p, [1e4, 1e5, 1e6, 1e7])
    add_seed_arg(p, default=0, help="seed of the predicted-state draws (default 0, as bench ip's)")
    add_limit_arg(p)
    add_output_arg(p, help="the JSON Lines file to write")
    add_quiet(p)
    p.set_defaults(func=cmd_predictions)


def _add_sigmas(p, default) -> None:
    p.add_argument("--position-sigma-km", type=float_in(0, MAX_SIGMA_KM, low_open=True, unit="km"), nargs="+",
                   default=default,
                   help=f"predicted-position errors to test, km per axis, in (0, {MAX_SIGMA_KM:g}], at most {MAX_SIGMAS} values "
                        + ("(default: 1e4 1e5 1e6 1e7)" if default else "(default: those the results name, else 1e4)"))


def _add_ip(bsub) -> None:
    p = bsub.add_parser("ip", help="score the image processing (stars, attitude, beacons) on a dataset",
                        description="Run image processors on every frame of DATASET (a skynav dataset or any "
                        "folder of NNNNNN.png + .json frames in the frame schema), all on the same frames with the same "
                        "predicted states, and score them against the truth side by side. --pipeline MODULE:FACTORY "
                        "adds anyone's processor (FACTORY(camera) -> an object with process(observation, prediction); "
                        "skynav.pipeline.protocols). --set changes a field of skynav's pipeline options "
                        "(skynav.pipeline.ProcessOptions: T, inlier_px, n_max, min_matches, refine_v_mag, "
                        "track_window_px, ...), e.g. --set inlier_px=2.5.")
    add_dataset_arg(p, "dataset folder, or a folder of NNNNNN.png + .json frames")
    _add_sigmas(p, [1e4, 1e5, 1e6, 1e7])
    p.add_argument("--mode", default="improved", choices=("paper", "improved"),
                   help="skynav's pipeline mode (default: improved)")
    p.add_argument("--pipeline", action="append", metavar="MODULE:FACTORY", default=None,
                   help="an image processor to benchmark (repeatable; default: skynav). 'skynav' is skynav's pipeline "
                        f"in --mode with --set; short names: {', '.join(BUILTIN)}")
    p.add_argument("--results", action="append", metavar="RESULTS", default=[],
                   help="a results file written by another program (JSON Lines, skynav.ip_results/1) to score beside "
                        "the processors (repeatable)")
    p.add_argument("--frame-timeout", type=float_in(0, SECONDS_PER_DAY, low_open=True, unit="s"), default=DEFAULT_FRAME_TIMEOUT_S,
                   help=f"a processor's time limit per frame, s (default {DEFAULT_FRAME_TIMEOUT_S:g}); a frame past it "
                        "fails with that reason")
    p.add_argument("--peers", action="store_true", help="also run tetra3rs and cedar-solve (if installed)")
    add_seed_arg(p, default=0, help="seed of the predicted-state draws (default 0)")
    add_limit_arg(p)
    add_output_arg(p, help="report folder")
    add_quiet(p)
    add_set_arg(p, "the pipeline options (ProcessOptions fields, e.g. inlier_px=2.5, n_max=16)")
    p.set_defaults(func=cmd_ip)


def _add_score(bsub) -> None:
    """``bench score``: results files written by other programs, scored against the truth. Modules
    of :data:`SUBCOMMAND_MODULES` with ``add_score_parser(score_subparsers)`` add theirs (``nav``)."""
    p = bsub.add_parser("score", help="score a results file written by any program against a dataset's truth",
                        description="Score results files written by any program (JSON Lines, one record per frame, "
                        "in the schemas published with skynav) against a dataset's truth.")
    ssub = p.add_subparsers(dest="score_command", metavar="WHAT")
    ip = ssub.add_parser("ip", help="image-processing results (skynav.ip_results/1): attitude and beacons per frame",
                         description="Score image-processing results files (JSON Lines; schema "
                         "skynav/datasets/schemas/ip_results.schema.json: frame, R_cam_icrs, optional sigma_km, status, "
                         "time_ms, beacons) against DATASET's truth, side by side when several are given.")
    add_dataset_arg(ip, "dataset folder, or a folder of NNNNNN.png + .json frames")
    ip.add_argument("results", nargs="+", metavar="RESULTS", help="results file(s), JSON Lines")
    _add_sigmas(ip, None)
    add_limit_arg(ip)
    add_output_arg(ip, help="report folder")
    add_quiet(ip)
    ip.set_defaults(func=cmd_score_ip)
    p.set_defaults(func=lambda args: (p.print_help(), 2)[1])
    return ssub


REGISTRARS = [_add_ip, _add_predictions]


def add_parser(sub) -> None:
    """Register ``bench`` and its sub-commands on the top-level subparsers."""
    b = sub.add_parser("bench", help=COMMAND_HELP["bench"],
                       description="Benchmarks: score the pipeline against the ground truth of a dataset.")
    bsub = b.add_subparsers(dest="bench_command", metavar="ACTION")
    for reg in REGISTRARS:
        reg(bsub)
    mods = []
    for name in SUBCOMMAND_MODULES:
        try:
            mods.append(importlib.import_module(name))
        except ImportError:
            continue
        mods[-1].add_parser(bsub)
    ssub = _add_score(bsub)
    for mod in mods:
        if hasattr(mod, "add_score_parser"):
            mod.add_score_parser(ssub)
    b.set_defaults(func=lambda args: (b.print_help(), 2)[1])


register = add_parser
