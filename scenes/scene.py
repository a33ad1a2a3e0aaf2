"""A Scene: what the camera sees at an epoch, from where, pointing where, before any pixel.

The renderer consumes a :class:`Scene`; the ground truth is written from it. Directions are kept
in three flavours because the pipeline and the ground truth need all of them:

- ``geometric``: from the observer to the body's position at the observation epoch;
- ``light_time``: to the body's position at the emission epoch (iterated light-time);
- ``apparent``: light-time + Sun light deflection + relativistic aberration (the truth).
"""

from __future__ import annotations

import dataclasses

from dataclasses import dataclass, field

import numpy as np

from . import apparent, frames
from .camera import Camera
from .catalog_hipparcos import load_catalog
from .constants import ARCSEC_RAD
from .ephemeris_jpl import default_ephemeris
from .sky import brightest_visible_body, sky_bodies
from .timescales import tdb_seconds
from .visibility import VisibilityCriteria


@dataclass(frozen=True, kw_only=True, eq=False)
class StarsInView:
    """Catalog stars near the field of view, arrays of length N.

    Attributes
    ----------
    hip : ndarray of int, shape (N,)
        Hipparcos numbers.
    v_mag, b_v : ndarray, shape (N,)
        Johnson V and B-V, mag.
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

    Examples
    --------
    >>> from skynav.scenes import build_from_spec, default_scene_spec
    >>> stars = build_from_spec(default_scene_spec()).stars
    >>> n_near, n_in = len(stars), int(stars.in_fov.sum())   # near the field (the PSF's reach), in it
    >>> n_near >= n_in > 500, stars.xy.shape == (n_near, 2)
    (True, True)
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
    """One solar-system body as seen from the spacecraft (units in the names).

    Attributes
    ----------
    name : str
        Body name.
    u_icrs, u_geometric, u_light_time : tuple of float, shape (3,)
        Apparent (light-time, Sun deflection, aberration), geometric and light-time-only unit
        vectors, ICRS axes (``u_apparent`` is an alias of ``u_icrs``).
    xy, xy_geometric, xy_light_time : tuple of float, shape (2,)
        Pixel positions of those directions at mid-exposure, px.
    xy_start, xy_end : tuple of float, shape (2,)
        Apparent pixel positions at the start and the end of the exposure, px.
    light_time_s : float
        Light travel time, s.
    distance_km : float
        Observer to body at emission (light-time distance), km.
    position_km : tuple of float, shape (3,)
        The body's barycentric ICRS position at light emission, km.
    sun_position_km : tuple of float, shape (3,)
        The Sun's barycentric ICRS position at the same emission epoch (illumination), km.
    radius_km : float
        Mean radius, km.
    v_mag : float
        Apparent V magnitude (NaN outside the phase law's range).
    phase_angle_rad : float
        Sun-body-observer angle, rad.
    elongation_rad : float
        Sun-spacecraft-body angle, rad.
    angular_diameter_px : float
        Apparent diameter, px.
    aberration_arcsec : float
        Angle between the light-time-only and the apparent directions, arcsec.
    in_fov, visible, resolved : bool
        On the sensor; visible by the scene's :class:`VisibilityCriteria`; wider than the
        resolved threshold (ray-traced).

    Examples
    --------
    >>> from skynav.scenes import build_from_spec, default_scene_spec
    >>> scene = build_from_spec(default_scene_spec())   # pointing at Mars
    >>> mars = next(b for b in scene.bodies if b.name == "mars")
    >>> [round(c, 6) for c in mars.xy], round(mars.v_mag, 2), mars.visible, mars.resolved
    ([511.5, 511.5], -1.72, True, False)
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
        The camera (optics, sensor, exposure).
    stars : StarsInView
        Catalogue stars near the field.
    bodies : tuple of BodyInView
        Every body considered (Sun excluded), in or out of the field.
    sun_u_icrs : ndarray, shape (3,)
        Apparent direction of the Sun.
    catalog_limiting_v_mag : float
        Faintest catalogue V magnitude included (the star catalogue cut).
    visibility : VisibilityCriteria
        The detection rule that set each body's ``visible`` flag.
    data_files : tuple of dict
        The mission files the scene was made from (SPICE kernels, CCSDS messages, a planetary
        SPK), each as its name was given and its SHA-256: the truth's ``data_files``.

    Examples
    --------
    >>> from skynav.scenes import build_from_spec, default_scene_spec
    >>> scene = build_from_spec(default_scene_spec())
    >>> scene.epoch_tdb_s, scene.camera.width, [b.name for b in scene.bodies_in_fov()]
    (854712000.0, 1024, ['mars'])
    >>> round(float(np.degrees(scene.boresight_sun_angle_rad)), 1)
    157.3
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
    data_files: tuple = ()

    @property
    def boresight_sun_angle_rad(self) -> float:
        """Angle between the boresight and the Sun, rad."""
        return float(np.arccos(np.clip(self.R_cam_icrs[2] @ self.sun_u_icrs, -1.0, 1.0)))

    def bodies_in_fov(self):
        """The bodies whose apparent position is on the sensor (tuple of :class:`BodyInView`)."""
        return tuple(b for b in self.bodies if b.in_fov)


# --------------------------------------------------------------------------------------------
# Building a scene
# --------------------------------------------------------------------------------------------

#: Default angular diameter above which a body is ray-traced rather than drawn as a point, px.
RESOLVED_THRESHOLD_PX = 2.0


def _tup(a):
    return tuple(np.asarray(a, dtype=float).ravel().tolist())


def _stars_in_view(cat, camera: Camera, t: float, r, v, attitudes: tuple, w, limiting_v_mag: float, sun_pos) -> StarsInView:
    """The catalogue's stars near the image (within the PSF's reach of it at mid-exposure, its
    start or its end), their apparent directions and pixel positions: ``attitudes`` is ``(R,
    R_start, R_end)``, ``w`` the body rate (rad/s), ``sun_pos`` the Sun's barycentric position
    (km) at ``t``."""
    R, R_start, R_end = attitudes
    still = not w.any()  # no rate: R_start and R_end are R
    # a cone around the boresight wide enough for the whole exposure's sweep
    sweep = float(np.linalg.norm(w)) * (0.5 * camera.exposure_s)
    margin = sweep + np.radians(0.2) + 8.0 * camera.ifov_rad
    idx = cat.cone(R[2], camera.half_diagonal_fov_rad + margin, limiting_v_mag=limiting_v_mag)
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
    return StarsInView(
        hip=np.asarray(cat.hip)[idx][keep], v_mag=np.asarray(cat.v_mag)[idx][keep],
        b_v=np.asarray(cat.b_v)[idx][keep], teff_k=np.asarray(cat.teff_k)[idx][keep],
        u_icrs=u_star[keep], xy=xy[keep], xy_start=xy0[keep], xy_end=xy1[keep],
        in_fov=camera.in_image(xy[keep]),
    )


def _bodies_in_view(sky_list, camera: Camera, attitudes: tuple, vis: VisibilityCriteria,
                    resolved_threshold_px: float) -> list:
    """A :class:`BodyInView` of each body of ``sky_list`` (``sky_bodies``'s), ``attitudes``
    ``(R, R_start, R_end)``: its directions, pixel positions, size and flags."""
    R, R_start, R_end = attitudes
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
    return bodies


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
        The camera (projection, field, PSF reach).
    angular_velocity_rad_s : array_like, shape (3,)
        Camera-frame body rate, rad/s; sources move along paths during the exposure.
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

    Returns
    -------
    Scene
        Stars near the field and every body, with their pixel positions through ``camera``.

    Examples
    --------
    The paper camera looking at the north celestial pole:

    >>> from skynav.scenes import build_scene, paper_camera, point_boresight
    >>> scene = build_scene("2027-02-01T00:00:00", position_km=[1.5e8, 0.0, 0.0],
    ...                     velocity_km_s=[0.0, 30.0, 0.0], R_cam_icrs=point_boresight([0.0, 0.0, 1.0]),
    ...                     camera=paper_camera())
    >>> scene.epoch_tdb_s, bool(scene.stars.in_fov.sum() > 500)
    (854712000.0, True)
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

    stars = _stars_in_view(cat, camera, t, r, v, (R, R_start, R_end), w, catalog_limiting_v_mag, eph.position("sun", t))
    if sky is None:
        sky = sky_bodies(t, r, v, ephemeris=eph)
    sky_list, sun_u = sky
    bodies = _bodies_in_view(sky_list, camera, (R, R_start, R_end), vis, resolved_threshold_px)
    return Scene(epoch_tdb_s=t, position_km=r, velocity_km_s=v, R_cam_icrs=R, angular_velocity_rad_s=w,
                 camera=camera, stars=stars, bodies=tuple(bodies), sun_u_icrs=np.asarray(sun_u),
                 catalog_limiting_v_mag=float(catalog_limiting_v_mag), visibility=vis)


def resolve_spec(spec, *, ephemeris=None):
    """Observer state, attitude and sky of a :class:`skynav.scenes.config.SceneSpec`.

    Parameters
    ----------
    spec : SceneSpec
        The scene description (a scene file, parsed).
    ephemeris : Ephemeris, optional
        Default: DE421.

    Returns
    -------
    tuple
        ``(t_tdb_s, position_km, velocity_km_s, R_cam_icrs, sky)``: the epoch (TDB s past
        J2000), the barycentric ICRS state (km, km/s; ``relative_to`` resolved), the attitude
        (3, 3) and the :func:`sky_bodies` result (reused by :func:`build_scene`).

    Examples
    --------
    >>> from skynav.scenes import default_scene_spec, resolve_spec
    >>> t, r, v, R, (bodies, sun_u) = resolve_spec(default_scene_spec())
    >>> t, R.shape, len(bodies)
    (854712000.0, (3, 3), 9)
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
    """Build the :class:`Scene` a :class:`skynav.scenes.config.SceneSpec` describes.

    Parameters
    ----------
    spec : SceneSpec
        The scene description (:func:`~skynav.scenes.scene_files.load_scene_file`,
        :func:`~skynav.scenes.presets.default_scene_spec`).
    ephemeris : Ephemeris, optional
        Default: the spec's (``ephemeris: {spk: FILE}``), else DE421.
    catalog : StarCatalog, optional
        Default: Hipparcos (:func:`~skynav.scenes.catalog_hipparcos.load_catalog`).

    Returns
    -------
    Scene
        Everything the renderer needs for the frame (``data_files``: the spec's records of the
        mission files it read).

    Examples
    --------
    >>> from skynav.scenes import build_from_spec, default_scene_spec
    >>> scene = build_from_spec(default_scene_spec())
    >>> scene.camera.width, [b.name for b in scene.bodies_in_fov()]
    (1024, ['mars'])
    >>> int(scene.stars.in_fov.sum()) > 500   # stars to V = 9 in the 20 deg field
    True
    """
    eph = ephemeris or getattr(spec, "ephemeris", None) or default_ephemeris()
    t, r, v, R, sky = resolve_spec(spec, ephemeris=eph)
    a = spec.attitude
    scene = build_scene(t, position_km=r, velocity_km_s=v, R_cam_icrs=R, camera=spec.camera,
                        angular_velocity_rad_s=a.angular_velocity_rad_s, catalog_limiting_v_mag=spec.catalog_limiting_v_mag,
                        visibility=spec.visibility,
                        resolved_threshold_px=spec.resolved_threshold_px, ephemeris=eph, catalog=catalog, sky=sky)
    records = tuple(getattr(spec, "data_files", ()))
    return dataclasses.replace(scene, data_files=records) if records else scene
