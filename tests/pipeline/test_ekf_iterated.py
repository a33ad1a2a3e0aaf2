"""The iterated EKF update against an independent solution of the same problem: the maximum a
posteriori estimate ``argmin |P^-1/2 (x - x_p)|^2 + |R^-1/2 (z - h(x))|^2`` found by
scipy.optimize.least_squares (trust region, numerical Jacobian of h)."""

import numpy as np
import pytest
from scipy.optimize import least_squares

from skynav.pipeline.ekf import NavFilter, initial_covariance
from skynav.pipeline.filter_dynamics import FilterDynamics
from skynav.pipeline.measurement import planet_pixel
from skynav.scenes.camera import paper_camera
from skynav.scenes.ephemeris_jpl import default_ephemeris

T0 = 8.5e8


def _look_at(u):
    z = u / np.linalg.norm(u)
    x = np.cross([0.0, 0.0, 1.0], z)
    x /= np.linalg.norm(x)
    return np.vstack([x, np.cross(z, x), z])


def test_iterated_update_reaches_the_map_estimate_where_the_ekf_does_not():
    """A close planet (Earth at 3e6 km) and a prior 1.5e5 km off (after 10 days on Andreis et al. (2023b)'s
    0.1 km/s velocity sigma): the measurement is nonlinear over the prior's spread. The iterated
    update lands on the MAP estimate (10 iterations: 0.04 km, asserted < 1 km; 3, the campaign's
    setting, within 1 % of the EKF's miss); the one-step EKF misses it by 7100 km (asserted > 1000)."""
    eph = default_ephemeris()
    dyn = FilterDynamics().bind(eph, T0 - 86400.0, T0 + 86400.0)
    cam = paper_camera()
    r_e, v_e = eph.position_velocity("earth", T0)
    sun = eph.position("sun", T0)
    r_true = r_e + np.array([2.0e6, 2.0e6, 0.5e6])
    v_true = v_e + np.array([1.0, -0.5, 0.2])
    R = _look_at(r_e - r_true + np.array([2e4, -1e4, 0.0]))
    P0 = initial_covariance(sigma_position_km=1e5)
    x_prior = np.concatenate([r_true + np.array([1.2e5, -0.8e5, 0.3e5]), v_true, np.zeros(6)])
    sigma = 0.1
    z = planet_pixel(r_true, v_true, r_e, v_e, R, cam, sun_position_km=sun, planet_radius_km=6371.0).xy_px

    def h(x):
        return planet_pixel(x[:3], x[3:6], r_e, v_e, R, cam, sun_position_km=sun, planet_radius_km=6371.0).xy_px

    L = np.linalg.cholesky(np.linalg.inv(P0[:6, :6]))
    sol = least_squares(lambda x: np.concatenate([L.T @ (x - x_prior[:6]), (z - h(x)) / sigma]),
                        x_prior[:6], x_scale=np.sqrt(np.diag(P0[:6, :6])), xtol=1e-14, ftol=1e-14, gtol=1e-14)
    out = {}
    for n in (1, 3, 10):
        kf = NavFilter(dyn, x_prior[None], P0, T0, iterations=n, gate_k=1e6)
        kf.update(z[None], r_e, v_e, R, cam, sigma, sun_position_km=sun, planet_radius_km=6371.0)
        out[n] = np.linalg.norm(kf.x[0, :3] - sol.x[:3])
    assert out[10] < 1.0
    assert out[1] > 1000.0
    assert out[3] < 0.01 * out[1]


def test_iterations_must_be_positive():
    eph = default_ephemeris()
    dyn = FilterDynamics().bind(eph, T0, T0 + 10.0)
    with pytest.raises(ValueError):
        NavFilter(dyn, np.zeros((1, 12)), initial_covariance(), T0, iterations=0)
