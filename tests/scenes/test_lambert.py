"""Izzo's Lambert solver checked by propagating its arc on the two-body problem (SciPy DOP853)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from skynav.scenes.errors import LambertError
from skynav.scenes.lambert import solve_lambert

MU_SUN = 1.32712440040944e11  # km^3/s^2


def _two_body(r, v, tof, mu):
    def f(_t, y):
        return np.concatenate([y[3:], -mu * y[:3] / np.linalg.norm(y[:3]) ** 3])

    sol = solve_ivp(f, (0.0, tof), np.concatenate([r, v]), method="DOP853", rtol=1e-13, atol=1e-9)
    return sol.y[:3, -1], sol.y[3:, -1]


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("tof_days", [5.0, 60.0, 250.0, 420.0])
def test_arc_reaches_r2_against_scipy_two_body(seed, tof_days):
    rng = np.random.default_rng(seed)
    r1 = rng.normal(size=3) * 1.5e8
    r2 = rng.normal(size=3) * 2.0e8
    tof = tof_days * 86400.0
    for prograde in (True, False):
        sol = solve_lambert(r1, r2, tof, MU_SUN, prograde=prograde)
        r_end, v_end = _two_body(r1, sol.v1_km_s, tof, MU_SUN)
        # 1e8 km arcs at rtol 1e-13: the integrator itself is good to ~1 m; 10 m leaves margin
        assert np.linalg.norm(r_end - r2) < 0.01
        assert np.linalg.norm(v_end - sol.v2_km_s) < 1e-8
        h = np.cross(r1, sol.v1_km_s)
        assert (h[2] > 0) == prograde  # direction of motion as asked


def test_quarter_circular_orbit_analytic():
    # unit circle, mu = 1: a quarter orbit takes pi/2 and starts at speed 1 along +y
    sol = solve_lambert([1.0, 0.0, 0.0], [0.0, 1.0, 0.0], np.pi / 2, 1.0)
    np.testing.assert_allclose(sol.v1_km_s, [0.0, 1.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(sol.v2_km_s, [-1.0, 0.0, 0.0], atol=1e-12)


def test_near_parabolic_branch():
    # parabolic time of flight (Barker/Euler: T_p = sqrt(2/mu)/3 (s^1.5 - sign (s-c)^1.5))
    r1, r2 = np.array([1.0, 0.0, 0.0]), np.array([0.0, 2.0, 0.0])
    c = np.linalg.norm(r2 - r1)
    s = 0.5 * (1.0 + 2.0 + c)
    tp = np.sqrt(2.0) / 3.0 * (s**1.5 - (s - c) ** 1.5)
    for tof in (0.98 * tp, tp, 1.02 * tp):
        sol = solve_lambert(r1, r2, tof, 1.0)
        r_end, _ = _two_body(r1, sol.v1_km_s, tof, 1.0)
        assert np.linalg.norm(r_end - r2) < 1e-9
    sol = solve_lambert(r1, r2, tp, 1.0)
    energy = 0.5 * sol.v1_km_s @ sol.v1_km_s - 1.0
    assert abs(energy) < 1e-9  # parabola: zero energy


def test_bad_inputs_are_clear_errors():
    with pytest.raises(LambertError, match="time of flight"):
        solve_lambert([1, 0, 0], [0, 1, 0], -1.0, 1.0)
    with pytest.raises(LambertError, match="collinear"):
        solve_lambert([1, 0, 0], [2, 0, 0], 1.0, 1.0)
    with pytest.raises(LambertError, match="revolutions"):
        solve_lambert([1, 0, 0], [0, 1, 0], 10.0, 1.0, revolutions=1)
