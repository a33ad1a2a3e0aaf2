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

from .camera import Camera


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
        Apparent unit vectors (ICRS axes) at mid-exposure.
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
    sun_angle_rad: float     # elongation from the Sun seen from the spacecraft
    angular_diameter_px: float
    aberration_arcsec: float  # separation between light-time-only and apparent directions
    in_fov: bool
    visible: bool
    resolved: bool


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
    star_mag_limit : float
        Faintest catalog V magnitude included.
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
    star_mag_limit: float = 9.0

    @property
    def sun_angle_rad(self) -> float:
        """Angle between the boresight and the Sun, rad."""
        return float(np.arccos(np.clip(self.R_cam_icrs[2] @ self.sun_u_icrs, -1.0, 1.0)))

    def bodies_in_fov(self):
        return tuple(b for b in self.bodies if b.in_fov)
