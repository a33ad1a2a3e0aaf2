"""The improved mode's beacon assignment (pipeline/beacon_id.py) against brute-force references:
the joint assignment over the candidates inside some 3-sigma ellipse equals the exhaustive
minimum over every spot, and the deep-star neighbour test equals scipy's cKDTree query."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from skynav.pipeline.beacon_id import assign_beacons, assign_from_m2, inv_2x2_stack, near_any
from skynav.pipeline.beacons import CHI2_2DOF_3SIGMA, BeaconPrediction, max_eig_2x2

NOT_FOUND = CHI2_2DOF_3SIGMA + 9.0


def _brute_force(preds, xy, candidate, spot_mag, mag_sigma):
    """Every one-to-one choice of a candidate spot (inside the beacon's ellipse) or "not found"
    per beacon; the cheapest total cost."""
    nb = len(preds)
    costs = []
    for p in preds:
        d = xy - p.xy_px
        m2 = np.einsum("ni,ij,nj->n", d, np.linalg.inv(p.cov_px2), d)
        c = {}
        for j in np.flatnonzero(candidate):
            if m2[j] <= CHI2_2DOF_3SIGMA:
                dm = 0.0
                if spot_mag is not None and np.isfinite(p.v_mag) and np.isfinite(spot_mag[j]):
                    dm = (spot_mag[j] - p.v_mag) / mag_sigma
                c[int(j)] = m2[j] + dm * dm
        costs.append(c)
    best, best_cost = None, np.inf
    for choice in itertools.product(*[[None] + sorted(c) for c in costs]):
        taken = [k for k in choice if k is not None]
        if len(taken) != len(set(taken)):
            continue
        total = sum(NOT_FOUND if k is None else costs[i][k] for i, k in enumerate(choice))
        if total < best_cost:
            best, best_cost = list(choice), total
    return best if nb else []


@pytest.mark.parametrize("seed", range(40))
def test_assignment_equals_brute_force(seed):
    rng = np.random.default_rng(seed)
    nb = int(rng.integers(0, 4))
    n = int(rng.integers(0, 25))
    xy = rng.uniform(0, 200, (n, 2))
    preds = []
    for _ in range(nb):
        # predictions near some spots, ellipses from tiny to wide, some magnitudes unknown
        centre = xy[rng.integers(n)] + rng.normal(0, 5, 2) if n else rng.uniform(0, 200, 2)
        L = rng.normal(size=(2, 2)) * rng.uniform(0.5, 12)
        preds.append(BeaconPrediction(name="b", xy_px=centre, cov_px2=L @ L.T + np.eye(2) * 0.0625, distance_km=1e8,
                                      v_mag=float(rng.uniform(-2, 8)) if rng.random() < 0.8 else float("nan")))
    candidate = rng.random(n) < 0.7
    spot_mag = rng.uniform(-3, 9, n) if rng.random() < 0.8 else None
    if spot_mag is not None:
        spot_mag[rng.random(n) < 0.2] = np.nan  # saturated spots: no brightness penalty
    got = assign_beacons(preds, xy, candidate, spot_mag, 1.0)
    want = _brute_force(preds, xy, candidate, spot_mag, 1.0)
    assert got == want


def test_near_any_equals_ckdtree_with_distance_upper_bound():
    from scipy.spatial import cKDTree

    rng = np.random.default_rng(3)
    for _ in range(200):
        ref = rng.uniform(0, 50, (int(rng.integers(1, 40)), 2))
        xy = rng.uniform(0, 50, (int(rng.integers(0, 30)), 2))
        # points exactly at the bound (strict: not near) and just inside it
        if len(xy) >= 2:
            xy[0] = ref[0] + [1.5, 0.0]
            xy[1] = ref[0] + [0.0, np.nextafter(1.5, 0.0)]
        d, _ = cKDTree(ref).query(xy, distance_upper_bound=1.5) if len(xy) else (np.zeros(0), None)
        np.testing.assert_array_equal(near_any(xy, ref, 1.5), np.isfinite(d))


def test_max_eig_2x2_matches_lapack_eigvalsh():
    """Reference: numpy.linalg.eigvalsh (LAPACK). The closed form is within a few ulp on random
    covariances spanning 7 decades (px^2), degenerate and diagonal ones included."""

    rng = np.random.default_rng(11)
    cases = [np.eye(2) * 4.0, np.diag([9.0, 1.0]), np.diag([1.0, 9.0]), np.zeros((2, 2))]
    for _ in range(5000):
        m = rng.normal(size=(2, 2))
        cases.append(m @ m.T * 10.0 ** rng.uniform(-3, 4))
    for P in cases:
        ref = float(np.linalg.eigvalsh(P)[-1])
        assert abs(max_eig_2x2(P) - ref) <= 4 * np.finfo(float).eps * max(abs(ref), 1e-300)


def test_one_beacon_assignment_equals_linear_sum_assignment_ties_included():
    """Reference: scipy.optimize.linear_sum_assignment on the cost matrix assign_from_m2 builds
    for several beacons (one row plus its "not found" column). Costs drawn from a few integers,
    so that equal costs (between spots, and with "not found") are common."""
    from scipy.optimize import linear_sum_assignment

    rng = np.random.default_rng(21)
    nf = CHI2_2DOF_3SIGMA + 9.0
    for _ in range(3000):
        m = int(rng.integers(1, 8))
        m2 = rng.choice([0.5, 2.0, 2.0, CHI2_2DOF_3SIGMA, 20.0, np.inf], size=(1, m))
        vmag = float(rng.choice([1.0, np.nan]))
        spot_mag = None
        if rng.random() < 0.7:
            spot_mag = rng.choice([1.0, 2.0, 1.0 + np.sqrt(9.0 + CHI2_2DOF_3SIGMA - 2.0), 4.0, np.nan], size=m)
        one = BeaconPrediction(name="b", xy_px=np.zeros(2), cov_px2=np.eye(2), v_mag=vmag, distance_km=1e8)
        got = assign_from_m2([one], m2, spot_mag, 1.0)
        inside = m2 <= CHI2_2DOF_3SIGMA
        c = m2.copy()
        if spot_mag is not None and np.isfinite(vmag):
            dm = spot_mag - vmag
            c = c + np.where(np.isfinite(dm), dm, 0.0) ** 2
        cost = np.full((1, m + 1), 1e9)
        cost[:, :m] = np.where(inside, c, 1e9)
        cost[0, m] = nf
        rows, cols = linear_sum_assignment(cost)
        want = [int(cols[0])] if cols[0] < m and cost[0, cols[0]] < 1e9 and inside.any() else [None]
        assert got == want, (m2, spot_mag, vmag, cost)


def test_inv_2x2_stack_is_numpy_inv_one_at_a_time():
    """Reference: numpy.linalg.inv one matrix at a time (None where it raises LinAlgError). The
    stack goes through the same function (one LAPACK gesv per matrix), but a stacked call may
    take another code path: within 4 ulps of each inverse's largest entry."""

    rng = np.random.default_rng(22)
    for _ in range(500):
        k = int(rng.integers(1, 4))
        mats = []
        for _ in range(k):
            L = rng.normal(size=(2, 2)) * 10.0 ** rng.uniform(-3, 3)
            M = L @ L.T + np.eye(2) * 0.0625
            r = rng.random()
            if r < 0.1:
                M = np.zeros((2, 2))
            elif r < 0.2:
                M = np.outer(L[0], L[0])
                M[1] = M[0]  # exactly singular rows
            mats.append(M)
        got = inv_2x2_stack(mats)
        for M, g in zip(mats, got):
            try:
                want = np.linalg.inv(M)
            except np.linalg.LinAlgError:
                want = None
            if want is None:
                assert g is None
            else:
                np.testing.assert_allclose(g, want, rtol=0, atol=4 * np.spacing(np.max(np.abs(want))))


