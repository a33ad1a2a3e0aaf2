"""Monte Carlo visibility campaign of Andreis et al. (2023a), Sec. V.A: how many scenes show a planet?

Andreis et al. (2023a) draws 3000 scenes (position N(0, diag(3, 3, 0.07) AU) about the barycentre, attitude
ra ~ U[0, 2 pi), dec with 3-sigma 0.6 rad, twist ~ U[0, 2 pi)) and finds "at least one planet
present" in 1031 of them (34.4 %). This script draws the same distribution with the dataset
sampler (scenes only, no images: frame k from SeedSequence([seed, k])) and prints the fractions
under several definitions of "present", with binomial 95 % intervals.

    python benchmarks/montecarlo_visibility.py [--scenes 3000] [--seed 20230214] [--attitude-frame ecliptic|icrs]
"""

from __future__ import annotations

import argparse
import math
import sys
import time

import numpy as np


def wilson(k: int, n: int, z: float = 1.96):
    p = k / n
    d = 1 + z * z / n
    c = (p + z * z / (2 * n)) / d
    h = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / d
    return c - h, c + h


def campaign(n_scenes: int = 3000, seed: int = 20230214, attitude_frame: str = "ecliptic", progress: bool = True) -> dict:
    """Counts of scenes with a body in the field under several definitions (see the output)."""
    from skynav.datasets import preset_recipe, validate_recipe
    from skynav.datasets.samplers import frame_rng, keep_filters_pass, make_plan

    rec = preset_recipe("montecarlo")
    rec.update(frames=n_scenes, seed=seed)
    rec["montecarlo"].update(keep=[], attitude_frame=attitude_frame)
    plan = make_plan(validate_recipe(rec))
    cam = plan.camera
    counts = {"any_body_in_fov": 0, "visible_v7": 0, "visible_v6": 0, "planet_in_fov_no_moon": 0,
              "visible_v7_and_boresight_sun_ok": 0}
    per_body: dict = {}
    it = range(n_scenes)
    if progress:
        from tqdm.auto import tqdm

        it = tqdm(it, unit="scene", file=sys.stderr)
    for k in it:
        req = plan.frame_request(k, frame_rng(seed, k))
        _, facts = keep_filters_pass([], req.sky, req.R_cam_icrs, cam, plan.visibility)
        bodies = {b.name: b for b in req.sky[0]}
        in_fov = facts["bodies_in_fov"]
        vis = facts["visible_bodies"]
        counts["any_body_in_fov"] += bool(in_fov)
        counts["planet_in_fov_no_moon"] += bool([b for b in in_fov if b != "moon"])
        counts["visible_v7"] += bool(vis)
        counts["visible_v6"] += bool([b for b in vis if bodies[b].v_mag <= 6.0])
        counts["visible_v7_and_boresight_sun_ok"] += bool(vis) and bool(plan.visibility.outside_sun_exclusion(
            math.radians(facts["boresight_sun_angle_deg"])))
        for b in vis:
            per_body[b] = per_body.get(b, 0) + 1
    return {"n": n_scenes, "counts": counts, "per_body_visible": per_body}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", type=int, default=3000)
    ap.add_argument("--seed", type=int, default=20230214)
    ap.add_argument("--attitude-frame", choices=("ecliptic", "icrs"), default="ecliptic")
    a = ap.parse_args(argv)
    t0 = time.perf_counter()
    res = campaign(a.scenes, a.seed, a.attitude_frame)
    dt = time.perf_counter() - t0
    n = res["n"]
    print(f"Monte Carlo visibility campaign: {n} scenes, seed {a.seed}, attitude in {a.attitude_frame} axes, "
          f"paper camera (20 deg FOV, limiting V 7, Sun exclusion 20 deg); {dt:.0f} s ({n / dt:.0f} scenes/s)")
    print(f"{'definition of a scene with a planet':58s} {'count':>6s} {'fraction':>9s}   95 % interval")
    labels = {
        "any_body_in_fov": "any body in the FOV (any brightness, Moon included)",
        "planet_in_fov_no_moon": "a planet in the FOV (any brightness)",
        "visible_v7": "a visible body: in FOV, V <= 7, > 20 deg from the Sun",
        "visible_v7_and_boresight_sun_ok": "  ... and the boresight > 20 deg from the Sun",
        "visible_v6": "a visible body with V <= 6 (miniaturised sensor, Andreis et al. (2023b))",
    }
    for key, label in labels.items():
        k = res["counts"][key]
        lo, hi = wilson(k, n)
        print(f"{label:58s} {k:6d} {k / n:9.3f}   [{lo:.3f}, {hi:.3f}]")
    lo, hi = wilson(1031, 3000)
    print(f"{'Andreis et al. (2023a): at least one planet present':58s} {1031:6d} {1031 / 3000:9.3f}   [{lo:.3f}, {hi:.3f}]")
    print("visible bodies: " + ", ".join(f"{b} {c}" for b, c in sorted(res["per_body_visible"].items(), key=lambda x: -x[1])))
    print("Why the fractions differ from the paper: its scenes were rendered by the DART sky simulator with its own")
    print("visibility rule (not stated: any planet in the image, possibly down to the detection threshold of its")
    print("rendered images rather than a V limit), its epochs are not given (the outer planets' positions on the sky")
    print("set most hits), and its N frame and the attitude distribution (normal in all three angles with 3-sigma")
    print("intervals [0, 2 pi], [-0.6, 0.6], [0, 2 pi]) are stated loosely; here ra and twist are uniform, dec is")
    print("normal about the ecliptic, epochs uniform over 2026-2030, and a planet is visible at V <= 7.")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
