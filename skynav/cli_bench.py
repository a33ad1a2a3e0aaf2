"""``skynav bench``: benchmark navigation software on datasets.

The group is extensible: :data:`SUBCOMMAND_MODULES` names modules (``skynav.cli_bench_*``) that
expose ``add_parser(bench_subparsers)``; those present are registered, so ``nav`` (the EKF's
``skynav/cli_bench_nav.py``) joins ``ip`` without an edit here.
"""

from __future__ import annotations

import importlib

SUBCOMMAND_MODULES = ("skynav.cli_bench_nav",)


def cmd_ip(args) -> int:
    from skynav.pipeline.errors import BenchInputError
    from skynav.pipeline.scoring import run_benchmark, summarise
    from skynav.pipeline.scoring_report import write_report

    if args.mode not in ("paper", "improved"):
        raise BenchInputError(f"--mode {args.mode!r}: give paper or improved")
    if any(not (s > 0) for s in args.position_sigma_km):
        raise BenchInputError("--position-sigma-km: every sigma must be > 0 km")
    sigmas = tuple(float(s) for s in args.position_sigma_km)
    rows, info = run_benchmark(args.dir, sigmas_km=sigmas, mode=args.mode, seed=args.seed, progress=not args.quiet,
                               limit=args.limit)
    if args.peers:
        info["peers_note"] = ("--peers: tetra3rs and cedar-solve are not installed here (no offline package); "
                              "peers were not run.")
    summary = summarise(rows, frames=info["frames"], sigmas_km=sigmas)
    out = write_report(args.output, rows, summary, sigmas_km=sigmas, mode=args.mode, seed=args.seed, source=args.dir,
                       info=info)
    a = summary["attitude"]
    print(f"{summary['frames']} frames ({args.mode}): attitude correct {100 * a['correct_rate']:.2f} %, wrong "
          f"{100 * a['wrong_rate']:.2f} %, none {100 * a['none_rate']:.2f} %, median {a['error_arcsec_median']:.2f} arcsec; "
          f"time median {summary['time_ms']['median']:.2f} ms")
    for s in sigmas:
        b = summary["beacon"][f"{s:g}"]
        print(f"  beacons sigma_r {s:g} km: {b['beacons']} beacons, correct {100 * (b['correct_rate'] or 0):.2f} %, "
              f"wrong {100 * (b['wrong_rate'] or 0):.2f} %, none {100 * (b['none_rate'] or 0):.2f} %")
    print(f"report: {out}/report.html")
    return 0


def _add_ip(bsub) -> None:
    p = bsub.add_parser("ip", help="score the image processing (stars, attitude, beacons) on a dataset",
                        description="Run the image-processing pipeline on every frame of DIR (a skynav dataset or any "
                        "folder of NNNNNN.png + .json frames in the frame schema) and score it against the truth.")
    p.add_argument("dir", help="dataset folder or folder of frames")
    p.add_argument("--position-sigma-km", type=float, nargs="+", default=[1e4, 1e5, 1e6, 1e7],
                   help="predicted-position errors to test, km per axis (default: 1e4 1e5 1e6 1e7)")
    p.add_argument("--mode", default="improved", choices=("paper", "improved"), help="pipeline mode (default: improved)")
    p.add_argument("--peers", action="store_true", help="also run tetra3rs and cedar-solve (if installed)")
    p.add_argument("--seed", type=int, default=0, help="seed of the predicted-state draws (default 0)")
    p.add_argument("--limit", type=int, default=None, help="only the first N frames")
    p.add_argument("-o", "--output", required=True, help="report folder")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_ip)


REGISTRARS = [_add_ip]


def add_parser(sub) -> None:
    """Register ``bench`` and its sub-commands on the top-level subparsers."""
    b = sub.add_parser("bench", help="benchmark navigation software on datasets",
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
