"""The beacon projection Jacobian (Andreis et al. (2023a), Eq. 16-20) against central finite differences, and
the Eq. 14 quaternion <-> DCM pair against scipy and skynav.scenes.frames."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from skynav.pipeline.beacons import project_beacon, projection_jacobian
from skynav.scenes.frames import dcm_to_quat as quat_from_dcm, quat_to_dcm as dcm_from_quat


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_jacobian_against_central_differences(seed):
    rng = np.random.default_rng(seed)
    K = np.array([[2903.7, 0, 511.5], [0, 2903.7, 511.5], [0, 0, 1.0]])
    r = rng.normal(0, 1e8, 3)
    # a beacon roughly along the boresight of a random attitude
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    A = dcm_from_quat(q)
    r_bc = r + A.T @ np.array([0.05, -0.03, 1.0]) * 3e8
    F = projection_jacobian(q, r, r_bc, K)
    x = np.concatenate([q, r, r_bc])
    f = lambda x: project_beacon(x[:4], x[4:7], x[7:10], K)  # noqa: E731
    num = np.empty((2, 10))
    for i in range(10):
        h = 1e-6 if i < 4 else 1e2  # quaternion components vs km
        d = np.zeros(10)
        d[i] = h
        num[:, i] = (f(x + d) - f(x - d)) / (2 * h)
    # relative to each column's scale: truncation error O(h^2) of a smooth function
    scale = np.abs(num).max(axis=0) + 1e-12
    assert np.all(np.abs(F - num) / scale < 1e-6), (F, num)


def test_quaternion_convention_against_scipy_and_frames():
    from skynav.scenes.frames import dcm_to_quat, quat_to_dcm

    for seed in range(5):
        R = Rotation.random(random_state=seed).as_matrix()
        q = quat_from_dcm(R)
        assert np.allclose(dcm_from_quat(q), R, atol=1e-12)
        assert np.allclose(quat_to_dcm(q), R, atol=1e-12)
        qs = np.asarray(dcm_to_quat(R))
        assert np.allclose(q, qs * np.sign(qs[0]), atol=1e-12)
