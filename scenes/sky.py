"""The solar-system bodies seen from an observer, before any pointing: their apparent
directions (:mod:`skynav.scenes.apparent`), magnitudes, phase and elongation angles and sizes,
for :func:`skynav.scenes.scene.build_scene` and the samplers that choose a pose by what it sees.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from skynav.infra.errors import ConfigValueError

from . import apparent, photometry
from .ephemeris_jpl import BODY_RADII_KM, default_ephemeris
from .errors import ObserverInsideBodyError
from .visibility import VisibilityCriteria

#: Bodies considered in every scene (the Sun is the illuminator, handled apart).
SCENE_BODIES = ("mercury", "venus", "earth", "moon", "mars", "jupiter", "saturn", "uranus", "neptune")

@dataclass(frozen=True, kw_only=True)
class SkyBody:
    """A body's apparent geometry and brightness from the observer, before any pointing.

    Attributes
    ----------
    name : str
        Body name.
    directions : BodyDirections
        Geometric, light-time and apparent directions and distances
        (:func:`~skynav.scenes.apparent.apparent_bodies`).
    radius_km : float
        Mean radius, km.
    v_mag : float
        Apparent V magnitude (NaN outside the phase law's range).
    phase_angle_rad : float
        Sun-body-observer angle, rad.
    elongation_rad : float
        Sun-spacecraft-body angle, rad.
    angular_diameter_rad : float
        Apparent diameter, rad.

    Examples
    --------
    See :func:`sky_bodies`.

    >>> from skynav.scenes import SkyBody, default_ephemeris, sky_bodies
    >>> r, v = default_ephemeris().position_velocity("earth", 0.0)
    >>> bodies, _ = sky_bodies(0.0, r + [0.0, 0.0, 1e6], v, names=("mars",))
    >>> isinstance(bodies[0], SkyBody), bodies[0].name
    (True, 'mars')
    """

    name: str
    directions: object  # apparent.BodyDirections
    radius_km: float
    v_mag: float
    phase_angle_rad: float
    elongation_rad: float    # angle Sun-spacecraft-body
    angular_diameter_rad: float


def sky_bodies(t_tdb_s: float, position_km, velocity_km_s, *, ephemeris=None, names=SCENE_BODIES, sun=None):
    """Apparent directions, magnitudes and angles of solar-system bodies seen from the observer.

    Parameters
    ----------
    t_tdb_s : float
        Epoch (reception), TDB seconds past J2000.
    position_km, velocity_km_s : array_like, shape (3,)
        Observer barycentric ICRS state, km and km/s.
    ephemeris : Ephemeris, optional
        Default: DE421 (:func:`~skynav.scenes.ephemeris_jpl.default_ephemeris`).
    names : sequence of str
        The bodies (default: the eight planets and the Moon).
    sun : BodyDirections, optional
        The Sun's directions for this epoch and observer when the caller has them
        (:func:`sky_bodies_and_sun`; a caller asking for the bodies in two parts), else
        computed with the bodies.

    Returns
    -------
    bodies : tuple of SkyBody
        One per name, in order.
    sun_u_icrs : numpy.ndarray, shape (3,)
        Apparent unit vector of the Sun, ICRS.

    Raises
    ------
    ObserverInsideBodyError
        When the observer is inside one of the bodies (geometric distance <= radius).

    References
    ----------
    Mallama & Hilton (2018) for the magnitudes (:func:`~skynav.scenes.photometry.planet_v_mag`);
    the apparent directions as :func:`~skynav.scenes.apparent.apparent_bodies`.

    Examples
    --------
    >>> from skynav.scenes import resolve_spec, default_scene_spec, sky_bodies
    >>> t, r, v, _, _ = resolve_spec(default_scene_spec())   # 2027-02-01, Earth-Mars cruise
    >>> bodies, sun_u = sky_bodies(t, r, v)
    >>> [(b.name, round(b.v_mag, 2)) for b in bodies[:3]], sun_u.shape
    ([('mercury', -0.29), ('venus', -3.74), ('earth', -2.34)], (3,))
    """
    bodies, sun = sky_bodies_and_sun(t_tdb_s, position_km, velocity_km_s, ephemeris=ephemeris, names=names, sun=sun)
    return bodies, np.asarray(sun.u_icrs, dtype=float)


def sky_bodies_and_sun(t_tdb_s: float, position_km, velocity_km_s, *, ephemeris=None, names=SCENE_BODIES, sun=None):
    """:func:`sky_bodies`, with the Sun's :class:`~skynav.scenes.apparent.BodyDirections` in
    place of its unit vector: ``(tuple of SkyBody, sun)``. Without ``sun``, the Sun is computed
    together with the bodies (one :func:`~skynav.scenes.apparent.apparent_bodies` call); with
    it, only the bodies (the second part of a caller asking for the bodies in two parts).

    Raises
    ------
    ObserverInsideBodyError
        When the observer is inside the Sun or one of the bodies (geometric distance <= radius).
    """
    eph = ephemeris or default_ephemeris()
    r = np.asarray(position_km, dtype=float)
    v = np.asarray(velocity_km_s, dtype=float)
    names = tuple(names)
    try:
        # at a body's centre the light-time step divides by zero before the error below names
        # the body: numpy's floating-point warnings are silenced here (a NaN still fails later)
        with np.errstate(divide="ignore", invalid="ignore"):
            if sun is None:
                sun, *dirs = apparent.apparent_bodies(eph, ("sun",) + names, r, v, t_tdb_s)
            else:
                dirs = apparent.apparent_bodies(eph, names, r, v, t_tdb_s) if names else ()
            if sun.geometric_distance_km <= BODY_RADII_KM["sun"]:
                raise ObserverInsideBodyError("sun", sun.geometric_distance_km, BODY_RADII_KM["sun"], r)
            return _sky_bodies(r, sun, names, dirs), sun
    except ObserverInsideBodyError:
        raise
    except Exception:
        _name_the_body(eph, t_tdb_s, r, ("sun",) + names)
        raise


def _name_the_body(eph, t_tdb_s, r, names) -> None:
    """Inside a body (at its centre, say) the light-time iteration has no solution and fails
    with a message that blames something else (the epoch): name the body instead (raises
    ObserverInsideBodyError; returns when the observer is inside none). Called only on failure,
    so a good frame pays no extra ephemeris look-ups."""
    for name in names:
        rb, _ = eph.position_velocity(name, t_tdb_s)
        dist = float(np.linalg.norm(np.asarray(rb, dtype=float) - r))
        if dist <= BODY_RADII_KM[name]:
            raise ObserverInsideBodyError(name, dist, BODY_RADII_KM[name], r) from None


def _sky_bodies(r, sun, names, dirs):
    """The :class:`SkyBody` of each body from its directions (its magnitude, phase, elongation
    and size), the bodies as rows of arrays."""
    if not names:
        return ()
    radii = np.array([BODY_RADII_KM[n] for n in names])
    for name, d, radius in zip(names, dirs, radii.tolist()):
        if d.geometric_distance_km <= radius:
            raise ObserverInsideBodyError(name, d.geometric_distance_km, radius, r)
    pos = np.array([d.position_km for d in dirs])
    sun_pos = np.array([d.sun_position_km for d in dirs])
    dist = np.array([d.distance_km for d in dirs])
    phase = photometry.phase_angle_rad(pos, sun_pos, r).tolist()
    sun_dist = np.linalg.norm(pos - sun_pos, axis=-1).tolist()
    u = np.array([d.u_icrs for d in dirs])
    elong = np.arccos(np.clip(u @ np.asarray(sun.u_icrs, dtype=float), -1.0, 1.0)).tolist()
    diam = photometry.angular_diameter_rad(radii, dist).tolist()
    return tuple(SkyBody(name=name, directions=d, radius_km=float(radius), phase_angle_rad=ph, elongation_rad=el,
                         v_mag=float(photometry.planet_v_mag(name, sd, d.distance_km, ph)), angular_diameter_rad=di)
                 for name, d, radius, ph, sd, el, di in zip(names, dirs, radii.tolist(), phase, sun_dist, elong, diam))


def brightest_visible_body(bodies, visibility: VisibilityCriteria) -> "SkyBody":
    """The brightest body outside the Sun exclusion angle of ``visibility``, whatever its
    magnitude (for ``point_at: auto``)."""
    candidates = [b for b in bodies if visibility.outside_sun_exclusion(b.elongation_rad) and np.isfinite(b.v_mag)]
    if not candidates:
        raise ConfigValueError("attitude.point_at", "auto", "a scene with at least one planet outside the Sun exclusion angle")
    return min(candidates, key=lambda b: b.v_mag)
