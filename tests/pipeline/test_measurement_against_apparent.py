"""First-order light-time (Andreis et al. (2024), Eq. 26-31) and aberration (Eq. 33) against the renderer's exact
ones (``skynav.scenes.apparent``: iterated light-time, relativistic aberration), at 1 AU and 30 km/s.

Andreis et al. (2024) (after Eq. 33) says the neglected higher orders are "orders of magnitude below 15 arcsec",
the attitude-determination floor. Measured here: < 0.01 arcsec for Venus, Mars, Jupiter, Saturn
(the light-time residual is the planet's acceleration over tau, ~1e-3 arcsec; the aberration one
is beta^2 ~ 1e-8 rad ~ 2 mas), i.e. more than three orders of magnitude below 15 arcsec, while the
effects themselves are 5-60 arcsec (they partly cancel for some geometries).
"""

import numpy as np
import pytest

from skynav.pipeline.measurement import CASES, planet_pixel
from skynav.scenes.apparent import apparent_body
from skynav.scenes.camera import paper_camera
from skynav.scenes.constants import AU_KM
from skynav.scenes.ephemeris_jpl import default_ephemeris

ARCSEC = np.pi / 180 / 3600
T_TDB_S = 8.5e8  # 2026-12


def _angle(a, b):
    return np.arctan2(np.linalg.norm(np.cross(a, b)), a @ b)


@pytest.mark.parametrize("body", ["venus", "mars", "jupiter", "saturn"])
def test_first_order_matches_exact_at_1au_30kms(body):
    eph = default_ephemeris()
    sun = eph.position("sun", T_TDB_S)
    r_e, v_e = eph.position_velocity("earth", T_TDB_S)
    # 1 AU from the Sun, Earth-like 30 km/s (a cruise spacecraft just after departure)
    r = sun + (r_e - sun) / np.linalg.norm(r_e - sun) * AU_KM
    v = v_e / np.linalg.norm(v_e) * 30.0
    rp, vp = eph.position_velocity(body, T_TDB_S)
    exact = apparent_body(eph, body, r, v, T_TDB_S, deflection=False)
    model = planet_pixel(r, v, rp, vp, np.eye(3), paper_camera(), corrections=CASES[1])
    err_arcsec = _angle(model.los_icrs, exact.u_apparent) / ARCSEC
    light_time_arcsec = _angle(exact.u_geometric, exact.u_light_time) / ARCSEC
    aberration_arcsec = _angle(exact.u_light_time, exact.u_apparent) / ARCSEC
    assert err_arcsec < 0.01, err_arcsec  # paper: higher orders << 15 arcsec
    assert max(light_time_arcsec, aberration_arcsec) > 5.0  # the effects themselves are not tiny
    assert abs(model.light_time_s - exact.light_time_s) < 1e-3  # s; the exact tau is ~500-5000 s
