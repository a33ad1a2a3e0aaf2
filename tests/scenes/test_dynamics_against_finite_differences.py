"""The EKF's dynamics derivatives against central finite differences (an independent reference).

``A(x, t) = df/dx`` from :func:`skynav.scenes.dynamics.acceleration_jacobian` is checked against
central differences of ``f`` itself, and the state transition matrix ``Phi(t, t0)`` integrated
with the variational equations against central differences of :func:`propagate` (a separate
integration of the state alone, at a tighter tolerance). Each tolerance is derived from the step:
central differences err by ``~ (h / L)^2`` (truncation, ``L`` the length over which the field
varies) plus ``~ eps |f| / (h |f'|)`` (rounding), or by the integrator's error divided by ``2 h``.
"""

from __future__ import annotations

import numpy as np
import pytest

from skynav.scenes.constants import GM_KM3_S2
from skynav.scenes.dynamics import (ForceField, ForceModel, SpacecraftSRP, acceleration, acceleration_jacobian, propagate,
                                    propagate_stm)
from skynav.scenes.ephemeris_jpl import default_ephemeris
from skynav.scenes.timescales import tdb_seconds

T0 = float(tdb_seconds("2026-12-01T00:00:00"))
DAY = 86400.0
BLOCKS = {"dr/dr0": (slice(0, 3), slice(0, 3)), "dr/dv0": (slice(0, 3), slice(3, 6)),
          "dv/dr0": (slice(3, 6), slice(0, 3)), "dv/dv0": (slice(3, 6), slice(3, 6))}


@pytest.fixture(scope="module")
def eph():
    return default_ephemeris()


@pytest.fixture(scope="module")
def x0(eph):
    """A cruise state ~6e6 km from the Earth (its gravity gradient is 4 % of the Sun's there)."""
    r, v = eph.position_velocity("earth", T0)
    return np.concatenate([r + np.array([5e6, 3e6, 1e6]), v + np.array([2.5, 1.0, 0.3])])


def _block_rel_err(exact, approx, block):
    a, b = BLOCKS[block]
    return np.abs(exact[a, b] - approx[a, b]).max() / np.abs(exact[a, b]).max()


def _central_jacobian(fun, x, h):
    cols = []
    for j in range(x.size):
        e = np.zeros(x.size)
        e[j] = h[j]
        cols.append((fun(x + e) - fun(x - e)) / (2.0 * h[j]))
    return np.stack(cols, axis=1)


def test_state_jacobian_against_central_differences(eph, x0):
    ff = ForceField(eph, T0, T0 + DAY)  # default model: 10 bodies, SRP, 1PN
    t = T0 + 1234.5  # off the body table's grid
    A = ff.jacobian(t, x0)
    # h_r = 100 km: truncation (100 km / 6e6 km)^2 ~ 3e-10, rounding eps |a| / (h |da/dr|) ~ 3e-10.
    # h_v = 1 km/s: a is quadratic in v, so central differences are exact but for rounding,
    # eps |a| / (h |da/dv|) = 2.2e-16 * 6e-6 / 6e-15 ~ 2e-7 (the 1PN da/dv is 1e-9 of a).
    fd = _central_jacobian(lambda x: ff.derivative(t, x), x0, np.array([100.0] * 3 + [1.0] * 3))
    np.testing.assert_array_equal(A[:3, :3], 0.0)
    np.testing.assert_array_equal(A[:3, 3:], np.eye(3))
    assert np.abs(fd[:3] - A[:3]).max() < 1e-12  # dr/dt = v: exact up to rounding of (v + h - (v - h)) / 2h
    assert _block_rel_err(A, fd, "dv/dr0") < 2e-9
    assert _block_rel_err(A, fd, "dv/dv0") < 1e-6


@pytest.mark.parametrize("term", ["srp", "1pn"])
def test_srp_and_1pn_jacobians_alone_against_central_differences(eph, x0, term):
    # In the full field the SRP and 1PN gradients are 1e-6 and 1e-8 of the Sun's Newtonian one, so
    # a wrong term would hide there: difference each term alone (no point masses in the sum).
    sun_r, sun_v = eph.position_velocity("sun", T0)
    srp = SpacecraftSRP().accel_1au_km_s2 if term == "srp" else 0.0
    rel = term == "1pn"
    none_r, none_gm = np.zeros((0, 3)), np.zeros(0)

    def f(x):
        return acceleration(x[:3], x[3:], none_r, none_gm, sun_r, sun_v, srp_accel_1au_km_s2=srp, relativity=rel)

    da_dr, da_dv = acceleration_jacobian(x0[:3], x0[3:], none_r, none_gm, sun_r, sun_v,
                                         srp_accel_1au_km_s2=srp, relativity=rel)
    # h_r = 1500 km = 1e-5 r: truncation ~ 10 (h / r)^2 = 1e-9 (terms up to r^-5), rounding eps / 1e-5 = 2e-11;
    # h_v = 1 km/s: exact for a quadratic in v (rounding only).
    fd = _central_jacobian(f, x0, np.array([1500.0] * 3 + [1.0] * 3))
    assert np.abs(fd[:, :3] - da_dr).max() / np.abs(da_dr).max() < 1e-8
    if rel:
        assert np.abs(fd[:, 3:] - da_dv).max() / np.abs(da_dv).max() < 1e-9
    else:
        np.testing.assert_array_equal(da_dv, 0.0)  # SRP does not depend on velocity


def test_force_field_refuses_epochs_outside_its_table(eph):
    ff = ForceField(eph, T0, T0 + DAY)
    with pytest.raises(ValueError, match="outside the force field"):
        ff.jacobian(T0 + 30 * DAY, np.ones(6))


def test_point_mass_jacobian_is_the_gravity_gradient():
    # one body: -GM (I / d^3 - 3 d d^T / d^5), symmetric and trace-free (Laplace) away from the mass
    gm = GM_KM3_S2["earth"]
    d = np.array([7000.0, -2000.0, 1500.0])
    da_dr, _ = acceleration_jacobian(d, np.zeros(3), np.zeros((1, 3)), np.array([gm]))
    dn = np.linalg.norm(d)
    np.testing.assert_allclose(da_dr, -gm * (np.eye(3) / dn**3 - 3 * np.outer(d, d) / dn**5), rtol=1e-14, atol=0)
    assert abs(np.trace(da_dr)) < 1e-15 * np.abs(da_dr).max() * 10


@pytest.mark.parametrize("days", [1.0, 10.0])
def test_stm_against_central_differences_of_propagate(eph, x0, days):
    t1 = T0 + days * DAY
    phi = propagate_stm(eph, x0[:3], x0[3:], T0, t1).stm(t1)

    def flow(x):
        arc = propagate(eph, x[:3], x[3:], T0, t1, rtol=3e-14, atol_km=1e-8, atol_km_s=1e-14)
        return np.concatenate(arc.state(t1))

    # h = 100 km, 0.1 m/s: the flow's nonlinearity over the step is (h / 6e6 km)^2 ~ 3e-10; the
    # propagations' error (rtol 3e-14 x 1.5e8 km ~ 5e-6 km, mostly common to the +h and -h runs)
    # over 2h gives <~ 2e-8 of a block; 1e-7 leaves a factor 5.
    fd = _central_jacobian(flow, x0, np.array([100.0] * 3 + [1e-4] * 3))
    for block in BLOCKS:
        assert _block_rel_err(phi, fd, block) < 1e-7, block


def test_stm_state_equals_propagate_state(eph, x0):
    # the state part of the 42-equation run follows the same equations; only step control differs
    t1 = T0 + 10 * DAY
    a = propagate_stm(eph, x0[:3], x0[3:], T0, t1, model=ForceModel(relativity=False)).state(t1)
    b = propagate(eph, x0[:3], x0[3:], T0, t1, model=ForceModel(relativity=False)).state(t1)
    assert np.linalg.norm(a[0] - b[0]) < 1e-5  # km: both at rtol 1e-12, ~1e-7 km observed
    assert np.linalg.norm(a[1] - b[1]) < 1e-11  # km/s
