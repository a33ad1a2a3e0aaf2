"""Wahba's problem by SVD (Andreis et al. (2023a), Eq. 10-12) against a closed-form case and against scipy's
``Rotation.align_vectors`` (an independent solver: Markley's SVD in scipy's own code)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from skynav.pipeline.attitude import attitude_covariance, rotation_angle_rad, wahba_svd

ARCSEC = np.pi / 180 / 3600


def test_closed_form_two_orthogonal_vectors():
    # A rotation of 30 deg about z: the reference x and y axes go to (cos, sin, 0) and (-sin, cos, 0)
    # in the body frame; with exact vectors the SVD must return exactly that matrix.
    c, s = np.cos(np.radians(30)), np.sin(np.radians(30))
    A_true = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])
    r = np.array([[1.0, 0, 0], [0, 1.0, 0]])
    b = r @ A_true.T
    A = wahba_svd(b, r)
    assert np.allclose(A, A_true, atol=1e-14)
    assert np.isclose(np.linalg.det(A), 1.0)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_against_scipy_align_vectors_with_noise_and_weights(seed):
    rng = np.random.default_rng(seed)
    A_true = Rotation.random(random_state=seed).as_matrix()
    r = rng.normal(size=(12, 3))
    r /= np.linalg.norm(r, axis=1, keepdims=True)
    b = r @ A_true.T + rng.normal(0, 1e-4, (12, 3))
    b /= np.linalg.norm(b, axis=1, keepdims=True)
    w = rng.uniform(0.5, 2.0, 12)
    A = wahba_svd(b, r, w)
    # scipy: the rotation R minimising sum w |a - R b|^2 with a = body, b = reference
    R, _ = Rotation.align_vectors(b, r, weights=w)
    assert rotation_angle_rad(A, R.as_matrix()) < 1e-3 * ARCSEC
    assert rotation_angle_rad(A, A_true) < 60 * ARCSEC


def test_reflection_is_never_returned():
    # three coplanar vectors make B rank 2; the det(U) det(V) factor keeps A a proper rotation
    r = np.array([[1.0, 0, 0], [0, 1.0, 0], [np.sqrt(0.5), np.sqrt(0.5), 0]])
    A = wahba_svd(r, r)
    assert np.isclose(np.linalg.det(A), 1.0)
    assert np.allclose(A, np.eye(3), atol=1e-12)


def test_covariance_matches_monte_carlo():
    # the QUEST covariance against the scatter of SVD solutions with simulated direction noise
    rng = np.random.default_rng(5)
    r = rng.normal([0, 0, 1], 0.1, (10, 3))
    r /= np.linalg.norm(r, axis=1, keepdims=True)
    sigma = 20 * ARCSEC
    P = attitude_covariance(r, sigma)
    errs = []
    for _ in range(2000):
        n = rng.normal(0, sigma, r.shape)
        n -= np.einsum("ij,ij->i", n, r)[:, None] * r  # noise perpendicular to the direction
        b = r + n
        b /= np.linalg.norm(b, axis=1, keepdims=True)
        A = wahba_svd(b, r)
        errs.append(Rotation.from_matrix(A).as_rotvec())
    C = np.cov(np.array(errs).T)
    assert np.allclose(np.sqrt(np.diag(C)), np.sqrt(np.diag(P)), rtol=0.1)  # 2000 samples: ~3 % sampling error
