"""The k-vector returns exactly the catalog pairs in an angle range (brute force over all pairs)."""

from __future__ import annotations

import numpy as np
import pytest

from skynav.pipeline.kvector import KVector


@pytest.mark.parametrize("seed", [0, 1])
def test_random_values_exact(seed):
    rng = np.random.default_rng(seed)
    v = np.sort(rng.uniform(0, 1, 5000) ** 2)
    kv = KVector.build(v)
    for lo in rng.uniform(-0.1, 1.1, 300):
        hi = lo + rng.uniform(0, 0.05)
        s = kv.range(lo, hi)
        assert np.array_equal(np.flatnonzero((v >= lo) & (v <= hi)), np.arange(s.start, s.stop))
    lo = rng.uniform(0, 1, 300)
    hi = lo + rng.uniform(0, 0.01, 300)
    st, en = kv.ranges(lo, hi)
    for a, b, x, y in zip(lo, hi, st, en):
        assert np.array_equal(np.flatnonzero((v >= a) & (v <= b)), np.arange(x, y))


def test_catalog_pairs_exact(onboard):
    # brute force over every pair of the on-board stars: the same set of (i, j) in the range
    u = onboard.u_icrs
    ang = np.arccos(np.clip(u @ u.T, -1, 1))
    iu, ju = np.triu_indices(len(u), 1)
    a = ang[iu, ju]
    for lo_deg, hi_deg in ((0.5, 0.52), (5.0, 5.01), (12.34, 12.345), (20.0, 20.0 + 1 / 3600)):
        lo, hi = np.radians(lo_deg), np.radians(hi_deg)
        I, J = onboard.pairs_in_range(lo, hi)
        got = {(min(i, j), max(i, j)) for i, j in zip(I.tolist(), J.tolist())}
        m = (a >= lo) & (a <= hi)
        want = set(zip(iu[m].tolist(), ju[m].tolist()))
        assert got == want and len(want) > 0


def test_catalog_is_cached_and_fast(onboard, paper_cam):
    from skynav.pipeline import OnboardCatalog

    assert OnboardCatalog.cache_file(max_angle_rad=2 * paper_cam.half_diagonal_fov_rad).exists()
    built = OnboardCatalog.build(camera=paper_cam)
    assert built.build_time_s < 5.0  # the k-vector build's budget: 5 s
    assert len(built.pair_i) == len(onboard.pair_i)
    assert np.all(built.v_mag < 5.5)
