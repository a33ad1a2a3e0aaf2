"""Identities every state transition matrix obeys, checked on :func:`propagate_stm`.

- ``Phi(t0, t0) = I``;
- the group (semigroup) property ``Phi(t2, t0) = Phi(t2, t1) Phi(t1, t0)``, with ``Phi(t2, t1)``
  from a second, separate integration started at ``x(t1)``;
- Liouville's theorem: ``det Phi = exp(integral of tr A)``, and ``tr A = 0`` for a conservative
  (Hamiltonian) field, here the point masses plus SRP (a ``1/r`` potential), so ``det Phi = 1``;
  with the velocity-dependent 1PN term on, ``det Phi - 1`` follows the quadrature of ``tr A``.
"""

from __future__ import annotations

import numpy as np
import pytest

from skynav.scenes.dynamics import ForceField, ForceModel, propagate_stm
from skynav.scenes.ephemeris_jpl import default_ephemeris
from skynav.scenes.timescales import tdb_seconds

T0 = float(tdb_seconds("2026-12-01T00:00:00"))
DAY = 86400.0
# Phi's blocks have units [[1, s], [1/s, 1]]; S Phi S^-1 with S = diag(1, 1, 1, T, T, T) makes them
# all dimensionless and O(1) for T ~ the arc, so one relative tolerance fits every entry.
S = np.diag([1.0] * 3 + [10 * DAY] * 3)


@pytest.fixture(scope="module")
def eph():
    return default_ephemeris()


@pytest.fixture(scope="module")
def x0(eph):
    r, v = eph.position_velocity("earth", T0)
    return np.concatenate([r + np.array([5e6, 3e6, 1e6]), v + np.array([2.5, 1.0, 0.3])])


def _scaled(phi):
    return S @ phi @ np.linalg.inv(S)


def test_stm_at_t0_is_identity(eph, x0):
    arc = propagate_stm(eph, x0[:3], x0[3:], T0, T0 + DAY)
    np.testing.assert_allclose(arc.stm(T0), np.eye(6), rtol=0, atol=1e-15)
    assert arc.stm([T0, T0 + DAY]).shape == (2, 6, 6)


@pytest.mark.parametrize("backwards", [False, True])
def test_group_property_against_a_restarted_integration(eph, x0, backwards):
    sign = -1.0 if backwards else 1.0
    t1, t2 = T0 + sign * 4 * DAY, T0 + sign * 10 * DAY
    whole = propagate_stm(eph, x0[:3], x0[3:], T0, t2)
    r1, v1 = whole.state(t1)
    second = propagate_stm(eph, r1, v1, t1, t2)
    composed = second.stm(t2) @ whole.stm(t1)
    # each run is good to ~1e-9 of a scaled entry (rtol 1e-12 over ~1e2 steps, see the FD test)
    err = np.abs(_scaled(composed) - _scaled(whole.stm(t2))).max()
    assert err < 1e-8
    # and stm_between inverts the first factor: Phi(t2, t1) = Phi(t2, t0) Phi(t1, t0)^-1
    err_between = np.abs(_scaled(whole.stm_between(t2, t1)) - _scaled(second.stm(t2))).max()
    assert err_between < 1e-8


def test_liouville_det_is_one_for_the_conservative_model(eph, x0):
    model = ForceModel(relativity=False)  # point masses + SRP: both gradients of a potential
    t1 = T0 + 10 * DAY
    ff = ForceField(eph, T0, t1, model=model)
    assert np.trace(ff.jacobian(T0, x0)) == 0.0  # A = [[0, I], [G, 0]]: trace zero exactly
    arc = propagate_stm(eph, x0[:3], x0[3:], T0, t1, model=model)
    dets = np.linalg.det(arc.stm(np.linspace(T0, t1, 11)))
    # integrator error of the entries (~1e-9 relative, scaled) bounds det's drift
    assert np.abs(dets - 1.0).max() < 1e-8


def test_liouville_formula_with_the_velocity_dependent_1pn_term(eph, x0):
    # With 1PN, tr A = tr(da/dv) = 14 (GM / c^2) (r . v) / r^3 (heliocentric): det Phi drifts from 1
    # by exp(integral of tr A dt) - 1 = 5.8e-10 over these 10 days, 30x the integrator's 2e-11 noise
    # on det (the conservative case above), so the velocity partials of the 1PN term are seen.
    t1 = T0 + 10 * DAY
    ff = ForceField(eph, T0, t1)
    arc = propagate_stm(eph, x0[:3], x0[3:], T0, t1)
    ts = np.linspace(T0, t1, 2001)
    r, v = arc.state(ts)
    tr = np.array([np.trace(ff.jacobian(t, np.concatenate([a, b]))) for t, a, b in zip(ts, r, v)])
    expected = np.expm1(np.trapezoid(tr, ts))  # smooth integrand, 7 min steps: quadrature error << 1e-12
    assert 3e-10 < expected < 1e-9
    assert abs((np.linalg.det(arc.stm(t1)) - 1.0) - expected) < 5e-11
