"""Monte Carlo visibility campaign (Andreis et al. (2023a), Sec. V.A, 3000 scenes) against an independent estimate.

The dataset sampler (light-time, aberration, apparent directions through ``sky_bodies``) and a
separate, plain-geometry re-implementation of the paper's distribution (own draws from a
different seed, ecliptic rotation from astropy, geometric directions straight from DE421) must
give the same fraction of scenes with a body in the field, within a two-proportion z-test.
The paper's 1031/3000 is printed by ``benchmarks/montecarlo_visibility.py`` with the reasons it
differs; it is not asserted here.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

pytestmark = pytest.mark.slow


def _independent_fraction(n: int, seed: int, camera) -> float:
    from astropy.coordinates import BarycentricMeanEcliptic, ICRS, SkyCoord

    from skynav.scenes.ephemeris_jpl import default_ephemeris
    from skynav.scenes.frames import radec_twist_to_dcm
    from skynav.scenes.sky import SCENE_BODIES
    from skynav.scenes.timescales import tdb_seconds

    # ecliptic -> ICRS rotation from astropy (independent of the sampler's obliquity constant)
    basis = SkyCoord(x=[1, 0, 0], y=[0, 1, 0], z=[0, 0, 1], representation_type="cartesian",
                     frame=BarycentricMeanEcliptic(equinox="J2000")).transform_to(ICRS())
    R_icrs_ecl = basis.cartesian.xyz.value  # columns: ecliptic axes in ICRS
    eph = default_ephemeris()
    rng = np.random.default_rng(seed)
    t0, t1 = tdb_seconds("2026-01-01T00:00:00"), tdb_seconds("2031-01-01T00:00:00")
    au = 149597870.7
    hits = 0
    for _ in range(n):
        t = rng.uniform(t0, t1)
        r = R_icrs_ecl @ (rng.normal(size=3) * np.array([3.0, 3.0, 0.07]) * au)
        R = radec_twist_to_dcm(rng.uniform(0, 2 * math.pi), rng.normal(0, 0.2), rng.uniform(0, 2 * math.pi)) @ R_icrs_ecl.T
        for name in SCENE_BODIES:
            xy = camera.project((R @ (eph.position(name, t) - r))[None])
            if camera.in_image(xy)[0]:
                hits += 1
                break
    return hits / n


def test_visibility_campaign_against_plain_geometry():
    import importlib.util
    from pathlib import Path

    from skynav.scenes.camera import paper_camera

    spec = importlib.util.spec_from_file_location(
        "mcvis", Path(__file__).resolve().parents[2] / "benchmarks" / "montecarlo_visibility.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    n = 3000
    res = mod.campaign(n, seed=20230214, progress=False)
    p1 = res["counts"]["any_body_in_fov"] / n
    p2 = _independent_fraction(n, seed=777, camera=paper_camera())
    p = 0.5 * (p1 + p2)
    z = (p1 - p2) / math.sqrt(p * (1 - p) * 2 / n)
    assert abs(z) < 4.0, (p1, p2)
    # visibility (V <= 7, away from the Sun) can only remove scenes
    assert res["counts"]["visible_v7"] <= res["counts"]["any_body_in_fov"]
