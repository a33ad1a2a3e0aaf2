"""The light-time iteration of ``apparent_bodies``: each body's row is its own computation, and
the emission position is where the ephemeris puts the body at ``t - tau``.

Independent checks: a fresh ephemeris read at the converged emission epoch (the iteration moves
its last position by ``-v step`` instead of reading again), and the light-time equation
``|r_b(t - tau) - r_o| = c tau`` itself. Directions against skyfield: test_against_skyfield.py.
"""

import numpy as np
import pytest

from skynav.scenes.apparent import apparent_bodies, apparent_body
from skynav.scenes.constants import C_KM_S
from skynav.scenes.ephemeris_jpl import BODIES, default_ephemeris

AU_KM = 149597870.7


def _observers():
    """A cruise observer 1.3 AU out, and one 10,000 km from the Earth (light-times from 0.03 s
    to 4 h in one call, so that the bodies' iterations end after different numbers of steps)."""
    eph = default_ephemeris()
    t = 2.9e8
    r_earth, v_earth = eph.position_velocity("earth", t + 1234.5)
    far = eph.position("sun", t) + 1.3 * AU_KM * np.array([0.6, 0.7, 0.3939])
    return [(t, far, np.array([12.0, -25.0, 4.0])), (t + 1234.5, r_earth + [1e4, 0.0, 0.0], v_earth + [0.0, 3.0, 0.0])]


@pytest.mark.parametrize("case", [0, 1])
def test_bodies_together_equal_each_alone(case):
    """One call for all bodies gives each body what a call for it alone gives: a row's numbers
    never depend on another row (the rows stop iterating at different steps)."""
    eph = default_ephemeris()
    t, r, v = _observers()[case]
    together = apparent_bodies(eph, BODIES, r, v, t)
    taus = [d.light_time_s for d in together]
    if case == 1:
        assert min(taus) < 0.1 and max(taus) > 1e4
    for body, d in zip(BODIES, together):
        alone = apparent_body(eph, body, r, v, t)
        for field in ("u_geometric", "u_light_time", "u_icrs", "position_km", "sun_position_km"):
            np.testing.assert_allclose(getattr(d, field), getattr(alone, field), rtol=1e-15, atol=0, err_msg=f"{body} {field}")
        assert d.light_time_s == pytest.approx(alone.light_time_s, rel=1e-15, abs=0)


@pytest.mark.parametrize("case", [0, 1])
def test_emission_position_is_the_ephemeris_at_t_minus_tau(case):
    """The position at emission equals a fresh read of the ephemeris at ``t - tau`` to 1e-6 km
    (the Chebyshev sums round at ~1e-8 km at 1-30 AU; the first-order move's neglected term is
    < 1e-24 km), and solves the light-time equation to c x 1e-10 s = 3e-5 km (the iteration's
    stopping step)."""
    eph = default_ephemeris()
    t, r, v = _observers()[case]
    for body, d in zip(BODIES, apparent_bodies(eph, BODIES, r, v, t)):
        read = eph.position(body, t, offset_s=-d.light_time_s)
        assert np.max(np.abs(d.position_km - read)) <= 1e-6, body
        assert abs(np.linalg.norm(d.position_km - r) - C_KM_S * d.light_time_s) <= C_KM_S * 1e-10, body
        sun = eph.position("sun", t, offset_s=-d.light_time_s)
        assert np.array_equal(d.sun_position_km, sun), body
