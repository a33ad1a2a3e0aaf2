"""Filter dynamics: batched acceleration against scenes.dynamics, F against central differences,
non-dimensional propagation against the dimensional STM identity P1 = Phi P0 Phi^T (Q = 0)."""

import numpy as np

from skynav.pipeline.filter_dynamics import FilterDynamics
from skynav.scenes.dynamics import acceleration
from skynav.scenes.ephemeris_jpl import default_ephemeris

T0 = 8.5e8


def _dyn(**kw):
    return FilterDynamics(**kw).bind(default_ephemeris(), T0, T0 + 5 * 86400.0)


def _states():
    eph = default_ephemeris()
    r, v = eph.position_velocity("earth", T0)
    x = np.concatenate([r + [3e6, -1e6, 2e5], v * 1.05, np.full(6, 1e-9)])
    return np.vstack([x, x + np.r_[4e7, -2e7, 1e6, 1, -2, 0.5, np.zeros(6)]])


def test_acceleration_matches_scenes_dynamics():
    dyn = _dyn()
    x = _states()
    a = dyn.acceleration(T0, x[:, :3])
    pos = dyn.table.positions(T0)
    for i in range(len(x)):
        ref = acceleration(x[i, :3], x[i, 3:6], pos, dyn.gm, pos[0], None,
                           srp_accel_1au_km_s2=dyn.model.srp.accel_1au_km_s2, relativity=False)
        np.testing.assert_allclose(a[i], ref, rtol=1e-13)


def test_jacobian_against_central_differences():
    dyn = _dyn()
    x = _states()
    F = dyn.jacobian(T0, x)
    h = np.array([1e2] * 3 + [1e-3] * 3 + [1e-10] * 6)
    for j in range(12):
        xp, xm = x.copy(), x.copy()
        xp[:, j] += h[j]
        xm[:, j] -= h[j]
        num = (dyn.derivative(T0, xp) - dyn.derivative(T0, xm)) / (2 * h[j])
        np.testing.assert_allclose(F[:, :, j], num, rtol=1e-6, atol=1e-6 * np.abs(num).max() + 1e-300)


def test_covariance_propagation_matches_linear_mapping():
    dyn = _dyn(sigma_residual_km_s2=0.0, sigma_srp_km_s2=0.0, correlation_time_s=1e6)
    x = _states()[:1]
    P0 = np.diag([1e2] * 3 + [1e-6] * 3 + [1e-20] * 6)
    t1 = T0 + 2 * 86400.0
    _, P1 = dyn.propagate(T0, t1, x, P0[None])
    # Phi by central differences of the state propagation
    h = np.sqrt(np.diag(P0))
    Phi = np.zeros((12, 12))
    for j in range(12):
        xp, xm = x.copy(), x.copy()
        xp[0, j] += h[j]
        xm[0, j] -= h[j]
        Phi[:, j] = (dyn.propagate(T0, t1, xp)[0][0] - dyn.propagate(T0, t1, xm)[0][0]) / (2 * h[j])
    ref = Phi @ P0 @ Phi.T
    d = np.sqrt(np.diag(ref))
    np.testing.assert_allclose(P1[0][:6, :6] / np.outer(d, d)[:6, :6], ref[:6, :6] / np.outer(d, d)[:6, :6], atol=1e-5)
