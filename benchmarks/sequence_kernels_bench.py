"""A sequence driven by SPICE kernels against the built-in one: ``dataset generate`` wall clock.

    nice -n 10 python benchmarks/sequence_kernels_bench.py [--legs L] [--frames N] [--size PX] [--repeat R]

The ``sequence`` preset cut to ``--legs`` legs (default 1) and ``--frames`` frames (default: all
the legs plan, 36 a leg) of a ``--size`` px camera (default 256, the paper camera's 20 deg
field), JSON truth only, one worker. Its cruise (hourly states, Type 13 SPK) and its frames'
attitudes (Type 3 CK with its SCLK and FK) are written with spiceypy once; then, in one process
and in alternating order (so that a shared machine's load moves both), ``R`` rounds (default 3)
each generate the built-in recipe and the same recipe with ``sequence.observer`` and
``sequence.attitude`` from the kernels into fresh folders (``skynav.datasets.generate``,
what ``skynav dataset generate --workers 1`` runs). A first round of each (Dr.Jit kernels,
catalogue, DE421 read) is left out. Printed: the median wall clock of each, their ratio
(SPICE / built-in; the criterion is <= 1.2), and the planning alone of each (``make_plan``,
median of the rounds): the built-in plan searches the Lambert transfer and propagates the
cruise, the SPICE plan reads the kernels.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "datasets"))


def _recipes(legs: int, frames: int | None, size: int):
    from test_sequence_kernels import small_recipe  # the acceptance test's recipe and kernel writers

    r = small_recipe()
    r["sequence"]["legs"] = legs
    r["camera"].update(width=size, height=size)
    if frames:
        r["frames"] = frames
    else:
        r.pop("frames")
    return r


def _write_kernels(recipe, folder: Path) -> dict:
    import json

    import numpy as np
    from test_sequence_kernels import write_cruise_spk, write_frames_ck

    from skynav.datasets import generate, validate_recipe
    from skynav.datasets.samplers import make_plan

    write_cruise_spk(folder / "cruise.bsp", make_plan(validate_recipe(recipe)))
    generate(recipe, folder / "ref", workers=1, progress=False)
    truths = [json.loads(p.read_text()) for p in sorted((folder / "ref" / "frames").glob("*.json"))]
    write_frames_ck(folder, np.array([t["epoch"]["tdb_seconds_past_j2000"] for t in truths]),
                    [t["attitude"]["R_cam_icrs"] for t in truths], [t["attitude"]["angular_velocity_rad_s"] for t in truths])
    spice = {**recipe, "sequence": dict(recipe["sequence"])}
    spice["sequence"]["observer"] = {"spice": {"kernels": [str(folder / "cruise.bsp")], "body": "-999"}}
    spice["sequence"]["attitude"] = {"spice": {"kernels": [str(folder / n) for n in ("craft.bc", "craft.tsc", "craft.tf")],
                                               "frame": "SKYNAV_CAM"}}
    return spice


def _time_generate(recipe, out: Path) -> float:
    from skynav.datasets import generate

    t0 = time.perf_counter()
    generate(recipe, out, workers=1, progress=False)
    return time.perf_counter() - t0


def _time_plan(recipe) -> float:
    from skynav.datasets import validate_recipe
    from skynav.datasets.samplers import make_plan

    t0 = time.perf_counter()
    make_plan(validate_recipe(recipe))
    return time.perf_counter() - t0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--legs", type=int, default=1)
    ap.add_argument("--frames", type=int, default=None)
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args(argv)
    os.environ.setdefault("SKYNAV_THREADS", "1")
    built_in = _recipes(args.legs, args.frames, args.size)
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        spice = _write_kernels(built_in, tmp)
        times = {"built-in": [], "spice": []}
        plans = {"built-in": [], "spice": []}
        for rnd in range(args.repeat + 1):  # round 0: warm-up, left out
            order = (("built-in", built_in), ("spice", spice)) if rnd % 2 == 0 else (("spice", spice), ("built-in", built_in))
            for name, recipe in order:
                t = _time_generate(recipe, tmp / f"{name}_{rnd}")
                p = _time_plan(recipe)
                if rnd:
                    times[name].append(t)
                    plans[name].append(p)
        n = len(list((tmp / "spice_1" / "frames").glob("*.json")))
    med = {k: statistics.median(v) for k, v in times.items()}
    pmed = {k: statistics.median(v) for k, v in plans.items()}
    print(f"sequence preset, {args.legs} leg(s), {n} frames of {args.size} px, JSON, 1 worker; "
          f"medians of {args.repeat} (1-min load {os.getloadavg()[0]:.2f})")
    for k in ("built-in", "spice"):
        print(f"  {k:>9}: generate {med[k]:7.2f} s   plan {pmed[k]:6.2f} s   "
              f"(runs: {', '.join(f'{x:.2f}' for x in times[k])})")
    print(f"  SPICE / built-in: generate {med['spice'] / med['built-in']:.3f} (criterion <= 1.2), "
          f"plan {pmed['spice'] / pmed['built-in']:.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
