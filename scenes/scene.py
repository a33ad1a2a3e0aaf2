"""A Scene: what the camera sees at an epoch, from where, pointing where, before any pixel.

The renderer consumes a :class:`Scene`; the ground truth is written from it. Directions are kept
in three flavours because the pipeline and the ground truth need all of them:

- ``geometric``: from the observer to the body's position at the observation epoch;
- ``light_time``: to the body's position at the emission epoch (iterated light-time);
- ``apparent``: light-time + Sun light deflection + relativistic aberration (the truth).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from skynav.infra.errors import ConfigValueError

from . import apparent, frames, photometry
from .camera import Camera
from .catalog_hipparcos import load_catalog
from .constants import ARCSEC_RAD
from .ephemeris_jpl import BODY_RADII_KM, default_ephemeris
from .errors import ObserverInsideBodyError
from .timescales import tdb_seconds
from .visibility import VisibilityCriteria


@dataclass(frozen=True, kw_only=True, eq=False)
class StarsInView:
    """Catalog stars near the field of view, arrays of length N.

    Attributes
    ----------
    hip : ndarray of int, shape (N,)
    v_mag, b_v : ndarray, shape (N,)
    teff_k : ndarray, shape (N,)
        Effective temperature, K.
    u_icrs : ndarray, shape (N, 3)
        Apparent unit vectors (ICRS axes) at mid-exposure (alias ``u_apparent``).
    xy : ndarray, shape (N, 2)
        Apparent pixel positions at mid-exposure (distortion applied), px.
    xy_start, xy_end : ndarray, shape (N, 2)
        Apparent pixel positions at the start and the end of the exposure (equal to ``xy``
        when the camera does not rotate).
    in_fov : ndarray of bool, shape (N,)
        ``xy`` on the sensor.
    """

    hip: np.ndarray
    v_mag: np.ndarray
    b_v: np.ndarray
    teff_k: np.ndarray
    u_icrs: np.ndarray
    xy: np.ndarray
    xy_start: np.ndarray
    xy_end: np.ndarray
    in_fov: np.ndarray

    def __len__(self) -> int:
        return len(self.hip)

    @property
    def u_apparent(self):
        """Alias of ``u_icrs``, the apparent direction (docs/conventions.md "One name per quantity")."""
        return self.u_icrs


@dataclass(frozen=True, kw_only=True)
class BodyInView:
    """One solar-system body as seen from the spacecraft (floats in SI-ish units, see names).

    ``xy`` is apparent (mid-exposure), ``xy_geometric`` uses the geometric direction;
    ``position_km`` is the body's barycentric position at light emission; ``sun_position_km`` the
    Sun's at the same emission epoch (for illumination); ``radius_km`` the mean radius.
    """

    name: str
    u_icrs: tuple            # apparent unit vector (3,)
    u_geometric: tuple       # geometric unit vector (3,)
    u_light_time: tuple      # light-time-only unit vector (3,)
    xy: tuple                # apparent pixel position at mid-exposure (2,)
    xy_geometric: tuple
    xy_light_time: tuple
    xy_start: tuple
    xy_end: tuple
    light_time_s: float
    distance_km: float       # observer to body at emission (light-time distance)
    position_km: tuple       # barycentric ICRS at emission
    sun_position_km: tuple   # barycentric ICRS of the Sun at emission
    radius_km: float
    v_mag: float
    phase_angle_rad: float
    elongation_rad: float    # angle Sun-spacecraft-body
    angular_diameter_px: float
    aberration_arcsec: float  # separation between light-time-only and apparent directions
    in_fov: bool
    visible: bool
    resolved: bool

    @property
    def u_apparent(self):
        """Alias of ``u_icrs``, the apparent direction (docs/conventions.md "One name per quantity")."""
        return self.u_icrs


@dataclass(frozen=True, kw_only=True, eq=False)
class Scene:
    """Everything the renderer needs for one frame.

    Attributes
    ----------
    epoch_tdb_s : float
        Mid-exposure epoch, TDB seconds past J2000.
    position_km, velocity_km_s : ndarray, shape (3,)
        Observer barycentric ICRS state.
    R_cam_icrs : ndarray, shape (3, 3)
        Attitude at mid-exposure (passive, ``v_cam = R @ v_icrs``).
    angular_velocity_rad_s : ndarray, shape (3,)
        Camera frame.
    camera : Camera
    stars : StarsInView
    bodies : tuple of BodyInView
        Every body considered (Sun excluded), in or out of the field.
    sun_u_icrs : ndarray, shape (3,)
        Apparent direction of the Sun.
    catalog_limiting_v_mag : float
        Faintest catalogue V magnitude included (the star catalogue cut).
    visibility : VisibilityCriteria
        The detection rule that set each body's ``visible`` flag.
    """

    epoch_tdb_s: float
    position_km: np.ndarray
    velocity_km_s: np.ndarray
    R_cam_icrs: np.ndarray
    angular_velocity_rad_s: np.ndarray
    camera: Camera
    stars: StarsInView
    bodies: tuple = field(default_factory=tuple)
    sun_u_icrs: np.ndarray = field(default_factory=lambda: np.zeros(3))
    catalog_limiting_v_mag: float = 9.0
    visibility: VisibilityCriteria = field(default_factory=VisibilityCriteria)

    @property
    def boresight_sun_angle_rad(self) -> float:
        """Angle between the boresight and the Sun, rad."""
        return float(np.arccos(np.clip(self.R_cam_icrs[2] @ self.sun_u_icrs, -1.0, 1.0)))

    def bodies_in_fov(self):
        return tuple(b for b in self.bodies if b.in_fov)


# --------------------------------------------------------------------------------------------
# Building a scene
# --------------------------------------------------------------------------------------------

#: Bodies considered in every scene (the Sun is the illuminator, handled apart).
SCENE_BODIES = ("mercury", "venus", "earth", "moon", "mars", "jupiter", "saturn", "uranus", "neptune")

#: Default angular diameter above which a body is ray-traced rather than drawn as a point, px.
RESOLVED_THRESHOLD_PX = 2.0


@dataclass(frozen=True, kw_only=True)
class SkyBody:
    """A body's apparent geometry and brightness from the observer, before any pointing."""

    name: str
    directions: object  # apparent.BodyDirections
    radius_km: float
    v_mag: float
    phase_angle_rad: float
    elongation_rad: float    # angle Sun-spacecraft-body
    angular_diameter_rad: float


def sky_bodies(t_tdb_s: float, position_km, velocity_km_s, *, ephemeris=None, names=SCENE_BODIES, sun=None):
    """Apparent directions, magnitudes and angles of solar-system bodies seen from the observer.

    Returns a tuple of :class:`SkyBody` and the apparent unit vector of the Sun. ``sun``: the
    Sun's :class:`~skynav.scenes.apparent.BodyDirections` for this epoch and observer when the
    caller has it (:func:`sky_bodies_and_sun`; a caller asking for the bodies in two parts), else
    computed with the bodies.

    Raises
    ------
    ObserverInsideBodyError
        When the observer is inside one of the bodies (geometric distance <= radius).
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


def _tup(a):
    return tuple(np.asarray(a, dtype=float).ravel().tolist())


def build_scene(
    epoch,
    *,
    position_km,
    velocity_km_s,
    R_cam_icrs,
    camera: Camera,
    angular_velocity_rad_s=(0.0, 0.0, 0.0),
    catalog_limiting_v_mag: float = 9.0,
    visibility: VisibilityCriteria | None = None,
    resolved_threshold_px: float = RESOLVED_THRESHOLD_PX,
    ephemeris=None,
    catalog=None,
    sky=None,
) -> Scene:
    """Compute everything the camera sees at mid-exposure ``epoch``.

    Parameters
    ----------
    epoch : astropy.time.Time, str (ISO, TDB) or float
        A float is TDB seconds past J2000 (the one meaning of a float epoch in skynav).
    position_km, velocity_km_s : array_like, shape (3,)
        Observer barycentric ICRS state.
    R_cam_icrs : array_like, shape (3, 3)
        Attitude at mid-exposure.
    camera : Camera
    angular_velocity_rad_s : array_like, shape (3,)
        Camera-frame body rate; sources move along paths during the exposure.
    catalog_limiting_v_mag : float
        Faintest catalogue V included (the star catalogue cut).
    visibility : VisibilityCriteria, optional
        The detection rule of the bodies' ``visible`` flag (default: V <= 7, 20 deg from the Sun).
    resolved_threshold_px : float
        Bodies whose angular diameter exceeds this are flagged ``resolved``.
    ephemeris, catalog : optional
        Injected adapters (defaults: DE421, Hipparcos).
    sky : optional
        Precomputed ``sky_bodies(...)`` result for this epoch and observer.
    """
    vis = VisibilityCriteria() if visibility is None else visibility
    t = float(epoch) if isinstance(epoch, (int, float, np.floating)) else float(tdb_seconds(epoch))
    eph = ephemeris or default_ephemeris()
    cat = catalog or load_catalog()
    r = np.asarray(position_km, dtype=float).reshape(3)
    v = np.asarray(velocity_km_s, dtype=float).reshape(3)
    R = np.asarray(R_cam_icrs, dtype=float).reshape(3, 3)
    w = np.asarray(angular_velocity_rad_s, dtype=float).reshape(3)
    half = 0.5 * camera.exposure_s
    still = not w.any()  # no rate: the attitude at the exposure's start and end is R itself
    R_start = R if still else frames.propagate_attitude(R, w, -half)
    R_end = R if still else frames.propagate_attitude(R, w, half)

    # --- stars: cone around the boresight wide enough for the whole exposure's sweep
    sweep = float(np.linalg.norm(w)) * half
    margin = sweep + np.radians(0.2) + 8.0 * camera.ifov_rad
    idx = cat.cone(R[2], camera.half_diagonal_fov_rad + margin, limiting_v_mag=catalog_limiting_v_mag)
    sun_pos = eph.position("sun", t)
    u_astro = cat.directions(idx, t, r)
    u_star = apparent.apparent_star_directions(u_astro, r, v, sun_pos)
    xy = camera.project(u_star @ R.T)
    pad = 8.0 + camera.psf.reach_px(camera)  # the PSF's reach (6 sigma for a Gaussian)
    if still:
        xy0 = xy1 = xy
        near = camera.in_image(xy, pad)
    else:
        xy0 = camera.project(u_star @ R_start.T)
        xy1 = camera.project(u_star @ R_end.T)
        near = camera.in_image(xy, pad) | camera.in_image(xy0, pad) | camera.in_image(xy1, pad)
    keep = np.flatnonzero(near)
    stars = StarsInView(
        hip=np.asarray(cat.hip)[idx][keep], v_mag=np.asarray(cat.v_mag)[idx][keep],
        b_v=np.asarray(cat.b_v)[idx][keep], teff_k=np.asarray(cat.teff_k)[idx][keep],
        u_icrs=u_star[keep], xy=xy[keep], xy_start=xy0[keep], xy_end=xy1[keep],
        in_fov=camera.in_image(xy[keep]),
    )

    # --- bodies
    if sky is None:
        sky = sky_bodies(t, r, v, ephemeris=eph)
    sky_list, sun_u = sky
    # each body's five camera-frame directions (apparent, geometric, light-time; apparent at the
    # exposure's start and end), projected in one call (project is elementwise)
    xys = camera.project(np.array([[R @ b.directions.u_icrs, R @ b.directions.u_geometric,
                                    R @ b.directions.u_light_time, R_start @ b.directions.u_icrs,
                                    R_end @ b.directions.u_icrs] for b in sky_list]).reshape(-1, 3)).reshape(-1, 5, 2)
    bodies = []
    for b, (p, p_geo, p_lt, p_start, p_end) in zip(sky_list, xys):
        d = b.directions
        in_fov = bool(camera.in_image(p[None])[0])
        diam_px = b.angular_diameter_rad * camera.focal_length_px
        bodies.append(BodyInView(
            name=b.name,
            u_icrs=_tup(d.u_icrs), u_geometric=_tup(d.u_geometric), u_light_time=_tup(d.u_light_time),
            xy=_tup(p), xy_geometric=_tup(p_geo), xy_light_time=_tup(p_lt), xy_start=_tup(p_start), xy_end=_tup(p_end),
            light_time_s=float(d.light_time_s), distance_km=float(d.distance_km),
            position_km=_tup(d.position_km), sun_position_km=_tup(d.sun_position_km),
            radius_km=float(b.radius_km), v_mag=float(b.v_mag), phase_angle_rad=float(b.phase_angle_rad),
            elongation_rad=float(b.elongation_rad), angular_diameter_px=float(diam_px),
            aberration_arcsec=float(np.arccos(np.clip(np.dot(d.u_light_time, d.u_icrs), -1, 1)) / ARCSEC_RAD),
            in_fov=in_fov,
            visible=bool(in_fov and vis.body_visible(v_mag=b.v_mag, elongation_rad=b.elongation_rad)),
            resolved=bool(diam_px > resolved_threshold_px),
        ))
    return Scene(epoch_tdb_s=t, position_km=r, velocity_km_s=v, R_cam_icrs=R, angular_velocity_rad_s=w,
                 camera=camera, stars=stars, bodies=tuple(bodies), sun_u_icrs=np.asarray(sun_u),
                 catalog_limiting_v_mag=float(catalog_limiting_v_mag), visibility=vis)


def resolve_spec(spec, *, ephemeris=None):
    """Observer state, attitude and sky of a :class:`skynav.scenes.config.SceneSpec`.

    Returns ``(t_tdb_s, position_km, velocity_km_s, R_cam_icrs, sky)`` where ``sky`` is the
    :func:`sky_bodies` result (reused by :func:`build_scene`).
    """
    eph = ephemeris or default_ephemeris()
    t = float(tdb_seconds(spec.epoch_tdb_iso))
    r = np.asarray(spec.position_km, dtype=float)
    v = np.asarray(spec.velocity_km_s, dtype=float)
    if spec.relative_to:
        rb, vb = eph.position_velocity(spec.relative_to, t)
        r, v = r + rb, v + vb
    sky = sky_bodies(t, r, v, ephemeris=eph)
    a = spec.attitude
    if a.point_at is not None:
        if a.point_at == "auto":
            target = brightest_visible_body(sky[0], spec.visibility)
        else:
            target = next(b for b in sky[0] if b.name == a.point_at)
        R = frames.point_boresight(target.directions.u_icrs, a.twist_rad)
    elif a.q_cam_icrs is not None:
        R = frames.quat_to_dcm(np.asarray(a.q_cam_icrs))
    else:
        R = frames.radec_twist_to_dcm(a.ra_rad, a.dec_rad, a.twist_rad)
    return t, r, v, R, sky


def build_from_spec(spec, *, ephemeris=None, catalog=None) -> Scene:
    """Build the :class:`Scene` a :class:`skynav.scenes.config.SceneSpec` describes."""
    eph = ephemeris or default_ephemeris()
    t, r, v, R, sky = resolve_spec(spec, ephemeris=eph)
    a = spec.attitude
    return build_scene(t, position_km=r, velocity_km_s=v, R_cam_icrs=R, camera=spec.camera,
                       angular_velocity_rad_s=a.angular_velocity_rad_s, catalog_limiting_v_mag=spec.catalog_limiting_v_mag,
                       visibility=spec.visibility,
                       resolved_threshold_px=spec.resolved_threshold_px, ephemeris=eph, catalog=catalog, sky=sky)
