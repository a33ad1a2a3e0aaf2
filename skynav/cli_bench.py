"""``skynav bench``: benchmark navigation software on datasets.

The group is extensible: :data:`SUBCOMMAND_MODULES` names modules (``skynav.cli_bench_*``) that
expose ``add_parser(bench_subparsers)``; those present are registered, so ``nav`` (the EKF's
``skynav/cli_bench_nav.py``) joins ``ip`` without an edit here.
"""

from __future__ import annotations

import importlib

from skynav.pipeline.errors import BenchInputError
from skynav.pipeline.process import ProcessOptions
from skynav.pipeline.scoring import run_benchmark, summarise, summarise_peers
from skynav.pipeline.scoring_report import write_report
from skynav.scenes.overrides import dataclass_from_overrides

from .cli_args import add_dataset_arg, add_limit_arg, add_output_arg, add_quiet, add_seed_arg, add_set_arg, float_in
from .cli_common import COMMAND_HELP, check_output, say

#: the largest predicted-position sigma: 1e10 km is 67 au, beyond any mission's uncertainty
MAX_SIGMA_KM = 1e10
#: most predicted-position sigmas (every frame is processed once per sigma)
MAX_SIGMAS = 16

SUBCOMMAND_MODULES = ("skynav.cli_bench_nav", "skynav.cli_bench_loop")


def cmd_ip(args) -> int:
    if args.mode not in ("paper", "improved"):
        raise BenchInputError(f"--mode {args.mode!r}: give paper or improved")
    if len(args.position_sigma_km) > MAX_SIGMAS:
        raise BenchInputError(f"--position-sigma-km: {len(args.position_sigma_km)} values; at most {MAX_SIGMAS} (every "
                              "frame is processed once per value)")
    if any(not (s > 0) for s in args.position_sigma_km):
        raise BenchInputError("--position-sigma-km: every sigma must be > 0 km")
    sigmas = tuple(float(s) for s in args.position_sigma_km)
    check_output(args.output, [("DATASET", args.dataset)])

    options = dataclass_from_overrides(ProcessOptions, args.overrides, what="ProcessOptions")
    rows, info = run_benchmark(args.dataset, sigmas_km=sigmas, mode=args.mode, seed=args.seed, progress=not args.quiet,
                               limit=args.limit, peers=args.peers, options=options)
    summary = summarise(rows, frames=info["frames"], sigmas_km=sigmas)
    peer_rows = info.pop("peer_rows")
    notes = info.pop("peer_notes")
    if args.peers:
        summary["peers"] = summarise_peers(peer_rows, rows, sigmas[0])
        lines = [f"- {name}: solved {100 * p['solved_rate']:.2f} %, wrong {100 * p['wrong_rate']:.2f} %, median "
                 f"{p['error_arcsec_median']:.2f} arcsec, {p['time_ms_median']:.1f} ms per frame"
                 + (f"; on the {p['both_solved_frames']} frames both solve: peer {p['both_solved_error_arcsec_median']['peer']:.2f}"
                    f" vs ours {p['both_solved_error_arcsec_median']['ours']:.2f} arcsec median" if "both_solved_frames" in p else "")
                 for name, p in summary["peers"].items()]
        lines += [f"- {name}: not run ({why})" for name, why in notes.items()]
        info["peers_note"] = "\n".join(lines)
        say(args, *lines)
    out = write_report(args.output, rows, summary, sigmas_km=sigmas, mode=args.mode, seed=args.seed, source=args.dataset,
                       info=info)
    a = summary["attitude"]
    say(args, f"{summary['frames']} frames ({args.mode}): attitude correct {100 * a['correct_rate']:.2f} %, wrong "
              f"{100 * a['wrong_rate']:.2f} %, none {100 * a['none_rate']:.2f} %, median {a['error_arcsec_median']:.2f} arcsec; "
              f"time median {summary['time_ms']['median']:.2f} ms")
    for s in sigmas:
        b = summary["beacon"][f"{s:g}"]
        say(args, f"  beacons sigma_r {s:g} km: {b['beacons']} beacons, correct {100 * (b['correct_rate'] or 0):.2f} %, "
                  f"wrong {100 * (b['wrong_rate'] or 0):.2f} %, none {100 * (b['none_rate'] or 0):.2f} %")
    say(args, f"report: {out}/report.html")
    return 0


def _add_ip(bsub) -> None:
    p = bsub.add_parser("ip", help="score the image processing (stars, attitude, beacons) on a dataset",
                        description="Run the image-processing pipeline on every frame of DATASET (a skynav dataset or any "
                        "folder of NNNNNN.png + .json frames in the frame schema) and score it against the truth. "
                        "--set changes a field of the pipeline's options (skynav.pipeline.ProcessOptions: T, inlier_px, "
                        "n_max, min_matches, refine_v_mag, track_window_px, ...), e.g. --set inlier_px=2.5.")
    add_dataset_arg(p, "dataset folder, or a folder of NNNNNN.png + .json frames")
    p.add_argument("--position-sigma-km", type=float_in(0, MAX_SIGMA_KM, low_open=True, unit="km"), nargs="+",
                   default=[1e4, 1e5, 1e6, 1e7],
                   help=f"predicted-position errors to test, km per axis, in (0, {MAX_SIGMA_KM:g}], at most {MAX_SIGMAS} values "
                        "(default: 1e4 1e5 1e6 1e7)")
    p.add_argument("--mode", default="improved", choices=("paper", "improved"), help="pipeline mode (default: improved)")
    p.add_argument("--peers", action="store_true", help="also run tetra3rs and cedar-solve (if installed)")
    add_seed_arg(p, default=0, help="seed of the predicted-state draws (default 0)")
    add_limit_arg(p)
    add_output_arg(p, help="report folder")
    add_quiet(p)
    add_set_arg(p, "the pipeline options (ProcessOptions fields, e.g. inlier_px=2.5, n_max=16)")
    p.set_defaults(func=cmd_ip)


REGISTRARS = [_add_ip]


def add_parser(sub) -> None:
    """Register ``bench`` and its sub-commands on the top-level subparsers."""
    b = sub.add_parser("bench", help=COMMAND_HELP["bench"],
                       description="Benchmarks: score the pipeline against the ground truth of a dataset.")
    bsub = b.add_subparsers(dest="bench_command", metavar="ACTION")
    for reg in REGISTRARS:
        reg(bsub)
    for name in SUBCOMMAND_MODULES:
        try:
            mod = importlib.import_module(name)
        except ImportError:
            continue
        mod.add_parser(bsub)
    b.set_defaults(func=lambda args: (b.print_help(), 2)[1])


register = add_parser
