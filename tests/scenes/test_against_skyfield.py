"""Apparent directions and light-times of the Sun, Moon and planets against skyfield.

Oracle: skyfield (test-only dependency; an independent implementation of NOVAS: its own
light-time loop, ``_compute_deflection`` and ``add_aberration``) reading the SAME de421.bsp from
``skyfield-data`` (no download). The observer is a ``skyfield.positionlib.Barycentric`` at an
arbitrary barycentric position and velocity, vectorised over the random cases.

Like-for-like: skyfield's ``Astrometric.apparent()`` deflects by the Sun, Jupiter and Saturn
(deflectors=(10, 599, 699)) and by the Earth for observers on or near it (not the case for a
``Barycentric`` observer: ``_observer_gcrs_au`` is None). skynav models the Sun only, so the main
comparison asks skyfield for ``apparent(deflectors=(10,))``; a second test measures the neglected
Jupiter + Saturn deflection against skyfield's default and bounds it by its physical maximum.
"""

import numpy as np
import pytest

from skynav.infra.data_files import de421_path
from skynav.scenes.apparent import apparent_body
from skynav.scenes.ephemeris_jpl import BODIES, default_ephemeris

skyfield_api = pytest.importorskip("skyfield.api")
from skyfield.positionlib import Barycentric  # noqa: E402

ARCSEC_RAD = np.pi / 180.0 / 3600.0
AU_KM = 149597870.7
DAY_S = 86400.0
N_CASES = 500  # per body
SKYFIELD_NAMES = {
    "sun": "sun", "mercury": "mercury", "venus": "venus", "earth": "earth", "moon": "moon",
    "mars": "mars", "jupiter": "jupiter barycenter", "saturn": "saturn barycenter",
    "uranus": "uranus barycenter", "neptune": "neptune barycenter",
}  # fmt: skip
OBLIQUITY_J2000_RAD = np.deg2rad(84381.406 / 3600.0)  # IAU 2006


@pytest.fixture(scope="module")
def sky():
    ts = skyfield_api.load.timescale(builtin=True)  # builtin leap-second/UT1 tables: no download
    planets = skyfield_api.load_file(str(de421_path()))
    return ts, planets


@pytest.fixture(scope="module")
def cases():
    """Random observers 0.3..5 AU from the Sun within 10 deg of the ecliptic, |v| <= 40 km/s,
    epochs 1950..2050 (own seed so the module fixture does not consume the shared ``rng``)."""
    g = np.random.default_rng(20240515)
    eph = default_ephemeris()
    t = g.uniform(-50.0, 50.0, N_CASES) * 365.25 * DAY_S
    r = g.uniform(0.3, 5.0, N_CASES) * AU_KM
    lon = g.uniform(0.0, 2 * np.pi, N_CASES)
    lat = np.deg2rad(g.uniform(-10.0, 10.0, N_CASES))
    ecl = r[:, None] * np.stack([np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)], -1)
    ce, se = np.cos(OBLIQUITY_J2000_RAD), np.sin(OBLIQUITY_J2000_RAD)
    equ = np.stack([ecl[:, 0], ce * ecl[:, 1] - se * ecl[:, 2], se * ecl[:, 1] + ce * ecl[:, 2]], -1)
    pos = eph.position("sun", t) + equ
    vdir = g.normal(size=(N_CASES, 3))
    vel = vdir / np.linalg.norm(vdir, axis=1, keepdims=True) * g.uniform(0.0, 40.0, N_CASES)[:, None]
    return t, pos, vel


def _skyfield_observer(sky, t, pos, vel):
    ts, planets = sky
    days = np.floor(t / DAY_S)
    tt = ts.tdb_jd(2451545.0 + days, (t - days * DAY_S) / DAY_S)  # two-part TDB, as skynav
    obs = Barycentric(pos.T / AU_KM, vel.T * DAY_S / AU_KM, tt)
    obs._ephemeris = planets  # what ephemeris['ssb'].at(t) would set; apparent() reads it
    return obs


def _sep_rad(a, b):
    """Angle between unit vectors, robust at tiny angles (2 asin(|a-b|/2))."""
    a = a / np.linalg.norm(a, axis=-1, keepdims=True)
    b = b / np.linalg.norm(b, axis=-1, keepdims=True)
    return 2 * np.arcsin(np.linalg.norm(a - b, axis=-1) / 2)


def _skynav(body, t, pos, vel, deflection=True):
    eph = default_ephemeris()
    out = [apparent_body(eph, body, p, v, tk, deflection=deflection) for tk, p, v in zip(t, pos, vel)]
    return out


@pytest.mark.parametrize("body", BODIES)
def test_apparent_light_time_geometric_against_skyfield(body, sky, cases):
    t, pos, vel = cases
    ts, planets = sky
    target = planets[SKYFIELD_NAMES[body]]
    obs = _skyfield_observer(sky, t, pos, vel)
    astrometric = obs.observe(target)
    apparent = astrometric.apparent(deflectors=(10,))  # Sun only: like skynav
    geometric = target.at(obs.t).xyz.km.T - pos

    ours = _skynav(body, t, pos, vel)
    u_app = np.array([o.u_apparent for o in ours])
    u_lt = np.array([o.u_light_time for o in ours])
    u_geo = np.array([o.u_geometric for o in ours])
    lt_s = np.array([o.light_time_s for o in ours])

    sep_app = _sep_rad(u_app, apparent.xyz.km.T) / ARCSEC_RAD
    sep_lt = _sep_rad(u_lt, astrometric.xyz.km.T) / ARCSEC_RAD
    sep_geo = _sep_rad(u_geo, geometric) / ARCSEC_RAD
    dlt = np.abs(lt_s - astrometric.light_time * DAY_S)
    print(f"\n{body}: max apparent {sep_app.max():.2e} as, light-time dir {sep_lt.max():.2e} as,"
          f" geometric {sep_geo.max():.2e} as, light-time {dlt.max():.2e} s")
    # 0.01 arcsec: the renderer's accuracy requirement (a few % of a pixel of a narrow-angle camera).
    assert max(sep_app.max(), sep_lt.max(), sep_geo.max()) <= 0.01
    # Both sides read the same kernel with the same formulae, so only rounding differs (measured:
    # < 1e-9 arcsec). 1e-5 arcsec = 10 micro-arcsec is far below the smallest modelled term (Sun
    # deflection >= ~0.5 mas for these observers), so omitting deflection, using the first-order
    # aberration (up to 3.7 mas off) or a first-order light-time would fail here.
    assert max(sep_app.max(), sep_lt.max(), sep_geo.max()) <= 1e-5
    assert dlt.max() <= 1e-3  # 1 ms; skyfield iterates to 1e-12 d = 86 ns
    # the corrections are really there: aberration alone is up to 27 arcsec at 40 km/s
    assert _sep_rad(u_app, u_lt).max() / ARCSEC_RAD > 5.0


@pytest.mark.parametrize("body", ["jupiter", "saturn", "mars"])
def test_neglected_planet_deflection_is_below_its_bound(body, sky, cases):
    """skyfield's default apparent() adds Jupiter and Saturn deflection, which skynav neglects:
    the difference must stay below their limb values (16.3 + 5.8 mas, Klioner 2003 table 1)."""
    t, pos, vel = cases
    ts, planets = sky
    apparent = _skyfield_observer(sky, t, pos, vel).observe(planets[SKYFIELD_NAMES[body]]).apparent()
    u_app = np.array([o.u_apparent for o in _skynav(body, t, pos, vel)])
    sep = _sep_rad(u_app, apparent.xyz.km.T) / ARCSEC_RAD
    print(f"\n{body}: max neglected Jupiter+Saturn deflection {sep.max():.2e} as")
    assert sep.max() <= 0.0221


def test_deflection_switch_against_skyfield_sun_free(sky, cases):
    """deflection=False equals skyfield's apparent(deflectors=()) (aberration only)."""
    t, pos, vel = cases
    t, pos, vel = t[:100], pos[:100], vel[:100]
    ts, planets = sky
    apparent = _skyfield_observer(sky, t, pos, vel).observe(planets["mars"]).apparent(deflectors=())
    u_app = np.array([o.u_apparent for o in _skynav("mars", t, pos, vel, deflection=False)])
    assert (_sep_rad(u_app, apparent.xyz.km.T) / ARCSEC_RAD).max() <= 0.01


def test_apparent_star_directions_against_skyfield(sky, cases, rng):
    """Stars (zero parallax and proper motion, so skyfield places them at 'infinity'):
    Sun deflection with the source at infinity, then relativistic aberration."""
    from skyfield.api import Star

    from skynav.scenes.apparent import apparent_star_directions

    t, pos, vel = cases
    ts, planets = sky
    n = 200
    u = rng.normal(size=(n, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    ra_h = np.rad2deg(np.arctan2(u[:, 1], u[:, 0])) % 360.0 / 15.0
    dec_deg = np.rad2deg(np.arcsin(u[:, 2]))
    eph = default_ephemeris()
    worst = 0.0
    for k in range(20):  # 20 observers x 200 stars
        obs = _skyfield_observer(sky, t[k : k + 1], pos[k : k + 1], vel[k : k + 1])
        obs = Barycentric(obs.xyz.au[:, 0], obs.velocity.au_per_d[:, 0], obs.t[0])
        obs._ephemeris = planets
        star = Star(ra_hours=ra_h, dec_degrees=dec_deg)
        theirs = obs.observe(star).apparent(deflectors=(10,)).xyz.au.T
        ours = apparent_star_directions(u, pos[k], vel[k], eph.position("sun", t[k]))
        worst = max(worst, (_sep_rad(ours, theirs) / ARCSEC_RAD).max())
        assert _sep_rad(ours, u).max() / ARCSEC_RAD > 1.0  # aberration is really applied
    print(f"\nstars: max apparent {worst:.2e} as")
    # skyfield takes the Sun when the ray passed it, we take it at the observation epoch:
    # <= 40 km of solar motion, ~1e-4 of the deflection; 1e-5 arcsec as above.
    assert worst <= 1e-5
