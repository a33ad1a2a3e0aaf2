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


def test_dcm_of_dcm_is_eq14_of_the_quaternion():
    """Reference: the module's own numpy pair dcm_from_quat(quat_from_dcm(A)) (Eq. 14), on
    random rotations (scipy) and the four quaternion branches (trace, and each axis largest).
    Two implementations (Python floats and numpy): element-wise within 4 ulps of 1 (the
    entries of a rotation matrix are <= 1; 4 ulps is 9e-16 rad of attitude), while a wrong
    branch or sign is off by ~1."""
    from scipy.spatial.transform import Rotation

    from skynav.pipeline.beacons import _dcm_of_dcm, dcm_from_quat, quat_from_dcm

    mats = list(Rotation.random(3000, random_state=12).as_matrix())
    mats += [Rotation.from_rotvec(np.pi * 0.999 * e).as_matrix() for e in np.eye(3)] + [np.eye(3)]
    for A in mats:
        np.testing.assert_allclose(_dcm_of_dcm(A), dcm_from_quat(quat_from_dcm(A)), rtol=0,
                                   atol=4 * np.finfo(float).eps)


def test_one_beacon_assignment_equals_linear_sum_assignment_ties_included():
    """Reference: scipy.optimize.linear_sum_assignment on the cost matrix _assign_from_m2 builds
    for several beacons (one row plus its "not found" column). Costs drawn from a few integers,
    so that equal costs (between spots, and with "not found") are common."""
    from scipy.optimize import linear_sum_assignment

    from skynav.pipeline.process import _assign_from_m2

    rng = np.random.default_rng(21)
    nf = CHI2_2DOF_3SIGMA + 9.0
    for _ in range(3000):
        m = int(rng.integers(1, 8))
        m2 = rng.choice([0.5, 2.0, 2.0, CHI2_2DOF_3SIGMA, 20.0, np.inf], size=(1, m))
        vmag = float(rng.choice([1.0, np.nan]))
        spot_mag = None
        if rng.random() < 0.7:
            spot_mag = rng.choice([1.0, 2.0, 1.0 + np.sqrt(9.0 + CHI2_2DOF_3SIGMA - 2.0), 4.0, np.nan], size=m)
        got = _assign_from_m2([{"v_mag": vmag}], m2, spot_mag, 1.0)
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


def test_inv_2x2_stack_is_numpy_inv_exactly():
    """Reference: numpy.linalg.inv one matrix at a time (None where it raises LinAlgError).
    Exact: the same code (the gufunc numpy.linalg.inv itself calls, one LAPACK gesv per matrix),
    not a second implementation."""
    from skynav.pipeline.process import _inv_2x2_stack

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
        got = _inv_2x2_stack(mats)
        for M, g in zip(mats, got):
            try:
                want = np.linalg.inv(M)
            except np.linalg.LinAlgError:
                want = None
            if want is None:
                assert g is None
            else:
                np.testing.assert_array_equal(g, want)


def test_median_agrees_with_numpy_median():
    """Reference: numpy.median, odd and even lengths, repeated values. Odd lengths pick one
    element (exact); even lengths average the two middle values, which numpy may round
    differently (its mean): within 1 ulp of the larger middle value, and between the two."""
    from skynav.pipeline.process import _median

    rng = np.random.default_rng(23)
    for _ in range(3000):
        n = int(rng.integers(3, 400))
        a = rng.normal(size=n) * 10 ** rng.uniform(-3, 3) + rng.uniform(-20, 20)
        if rng.random() < 0.3:
            a = np.round(a, 1)
        got, want = _median(a.copy()), float(np.median(a))
        s = np.sort(a)
        lo, hi = s[(n - 1) // 2], s[n // 2]
        assert lo <= got <= hi
        assert abs(got - want) <= np.spacing(max(abs(lo), abs(hi))), (got, want)


def test_lines_of_sight_agrees_with_camera_line_of_sight():
    """Reference: Camera.line_of_sight (numpy), for the undistorted lens; a distorted one is
    passed through. Two implementations (Python floats and numpy): unit vectors within 4 ulps
    of 1 per component (9e-16 rad)."""
    from skynav.pipeline.process import _lines_of_sight
    from skynav.scenes.camera import Camera

    rng = np.random.default_rng(24)
    for k in range(3000):
        cam = Camera(width=1024, height=768, focal_length_mm=float(rng.uniform(20, 200)), pixel_pitch_um=5.5,
                     pixel_pitch_y_um=None if k % 2 else 5.0, cx=float(rng.uniform(400, 600)),
                     cy=float(rng.uniform(300, 450)))
        xys = list(rng.uniform(-2 * cam.width, 3 * cam.width, (int(rng.integers(1, 4)), 2)))
        np.testing.assert_allclose(_lines_of_sight(cam, xys), cam.line_of_sight(np.array(xys)), rtol=0,
                                   atol=4 * np.finfo(float).eps)


def test_inv_2x2_stack_fast_path_raises_nothing_and_matches():
    """Matrices _clearly_invertible accepts invert without any floating-point exception (under
    errstate(all="raise")) to numpy.linalg.inv's bits (the same code: the gufunc it calls);
    singular, non-finite and extreme ones are refused (and go through numpy.linalg.inv's error
    handling)."""
    from skynav.pipeline.process import _clearly_invertible, _inv_2x2_stack

    rng = np.random.default_rng(25)
    for _ in range(2000):
        L = rng.normal(size=(2, 2)) * 10.0 ** rng.uniform(-14, 14)
        M = L @ L.T * (1.0 if rng.random() < 0.8 else -1.0)
        if rng.random() < 0.2:
            M[0, 1] = M[1, 0] = 0.0
        if not _clearly_invertible(M[None]):
            continue
        with np.errstate(all="raise"):
            got = _inv_2x2_stack([M])[0]
        np.testing.assert_array_equal(got, np.linalg.inv(M))
    for bad in (np.zeros((2, 2)), np.ones((2, 2)), np.array([[1.0, np.nan], [0.0, 1.0]]),
                np.array([[1e-40, 0.0], [0.0, 1.0]]), np.array([[1e31, 0.0], [0.0, 1.0]]),
                np.array([[1.0, 1.0], [1.0, 1.0 + 1e-12]])):
        assert not _clearly_invertible(bad[None])
