"""The improved mode's beacon assignment (pipeline/process.py) against brute-force references:
the joint assignment over the candidates inside some 3-sigma ellipse equals the exhaustive
minimum over every spot, and the deep-star neighbour test equals scipy's cKDTree query."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from skynav.pipeline.beacons import CHI2_2DOF_3SIGMA
from skynav.pipeline.process import _assign_beacons, _near_any

NOT_FOUND = CHI2_2DOF_3SIGMA + 9.0


def _brute_force(preds, xy, candidate, spot_mag, mag_sigma):
    """Every one-to-one choice of a candidate spot (inside the beacon's ellipse) or "not found"
    per beacon; the cheapest total cost."""
    nb = len(preds)
    costs = []
    for p in preds:
        d = xy - p["xy_px"]
        m2 = np.einsum("ni,ij,nj->n", d, np.linalg.inv(p["cov_px2"]), d)
        c = {}
        for j in np.flatnonzero(candidate):
            if m2[j] <= CHI2_2DOF_3SIGMA:
                dm = 0.0
                if spot_mag is not None and np.isfinite(p["v_mag"]) and np.isfinite(spot_mag[j]):
                    dm = (spot_mag[j] - p["v_mag"]) / mag_sigma
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
        preds.append({"name": "b", "xy_px": centre, "cov_px2": L @ L.T + np.eye(2) * 0.0625,
                      "v_mag": float(rng.uniform(-2, 8)) if rng.random() < 0.8 else float("nan")})
    candidate = rng.random(n) < 0.7
    spot_mag = rng.uniform(-3, 9, n) if rng.random() < 0.8 else None
    if spot_mag is not None:
        spot_mag[rng.random(n) < 0.2] = np.nan  # saturated spots: no brightness penalty
    got = _assign_beacons(preds, xy, candidate, spot_mag, 1.0)
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
        np.testing.assert_array_equal(_near_any(xy, ref, 1.5), np.isfinite(d))


def test_max_eig_2x2_matches_lapack_eigvalsh():
    """Reference: numpy.linalg.eigvalsh (LAPACK). The closed form is within a few ulp on random
    covariances spanning 7 decades (px^2), degenerate and diagonal ones included."""
    from skynav.pipeline.beacons import _max_eig_2x2

    rng = np.random.default_rng(11)
    cases = [np.eye(2) * 4.0, np.diag([9.0, 1.0]), np.diag([1.0, 9.0]), np.zeros((2, 2))]
    for _ in range(5000):
        m = rng.normal(size=(2, 2))
        cases.append(m @ m.T * 10.0 ** rng.uniform(-3, 4))
    for P in cases:
        ref = float(np.linalg.eigvalsh(P)[-1])
        assert abs(_max_eig_2x2(P) - ref) <= 4 * np.finfo(float).eps * max(abs(ref), 1e-300)


def test_dcm_of_dcm_is_eq14_of_the_quaternion_bit_for_bit():
    """Reference: the module's own numpy pair dcm_from_quat(quat_from_dcm(A)) (Eq. 14), on
    random rotations (scipy) and the four quaternion branches (trace, and each axis largest)."""
    from scipy.spatial.transform import Rotation

    from skynav.pipeline.beacons import _dcm_of_dcm, dcm_from_quat, quat_from_dcm

    mats = list(Rotation.random(3000, random_state=12).as_matrix())
    mats += [Rotation.from_rotvec(np.pi * 0.999 * e).as_matrix() for e in np.eye(3)] + [np.eye(3)]
    for A in mats:
        np.testing.assert_array_equal(_dcm_of_dcm(A), dcm_from_quat(quat_from_dcm(A)))
