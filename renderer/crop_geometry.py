"""Where a resolved body is ray-traced: its crop window on the image, the limb's radius in pixels,
and the lines of sight of the crop's pixel corners through any projection (a distorted camera or a
bench's collimator), which the ``skynav_projection`` sensor follows
(:mod:`skynav.renderer.mitsuba_plugins`); and which sensor a projection needs (a plain pinhole
takes Mitsuba's own perspective sensor).
"""

from __future__ import annotations

import math

import numpy as np

from skynav.infra.errors import ConfigValueError
from skynav.scenes.camera import Camera

from .errors import ProjectionCropError

__all__ = ["crop_window", "crop_lines_of_sight", "limb_radius_px", "plain_pinhole", "CROP_MARGIN_PX",
           "CROP_QUANTUM_PX", "MAX_CROP_PX", "SENSORS"]

#: ``render_resolved_body(sensor=...)`` values.
SENSORS = ("auto", "perspective", "projection")

#: Margin around the body's disk (and its streak) in the crop, px.
CROP_MARGIN_PX = 2.0

#: Crop sizes are rounded up to a multiple of this, px (kernel reuse across frames).
CROP_QUANTUM_PX = 8

#: Largest crop side, px (a body larger than this is clipped to a window around the frame).
MAX_CROP_PX = 4096


def crop_window(centres_xy, radius_px: float, *, margin_px: float = CROP_MARGIN_PX, quantum_px: int = CROP_QUANTUM_PX):
    """Integer crop ``(x0, y0, w, h)`` holding disks of ``radius_px`` at ``centres_xy``.

    Parameters
    ----------
    centres_xy : ndarray, shape (T, 2), px
    radius_px : float

    Returns
    -------
    x0, y0, w, h : int (w, h multiples of ``quantum_px``, centred on the bounding box)
    """
    c = np.asarray(centres_xy, dtype=float).reshape(-1, 2)
    r = float(radius_px) + float(margin_px)
    lo = np.floor(c.min(0) - r + 0.5).astype(int)
    hi = np.floor(c.max(0) + r + 0.5).astype(int)
    size = hi - lo + 1
    q = int(quantum_px)
    qsize = np.minimum(((size + q - 1) // q) * q, MAX_CROP_PX)
    lo = lo - (qsize - size) // 2
    return int(lo[0]), int(lo[1]), int(qsize[0]), int(qsize[1])


def _frame_z(direction) -> np.ndarray:
    """A rotation 4x4 whose +z column is ``direction`` (unit)."""
    z = np.asarray(direction, dtype=float)
    z = z / np.linalg.norm(z)
    a = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(a, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    M = np.eye(4)
    M[:3, 0], M[:3, 1], M[:3, 2] = x, y, z
    return M


def _to_world(R_cam_icrs: np.ndarray, position) -> np.ndarray:
    """The ``perspective`` sensor's camera-to-world 4x4: columns ``(-x_cam, -y_cam, z_cam)`` in
    ICRS (Mitsuba's film has +x left and +y up) and the observer's position."""
    M = np.eye(4)
    M[:3, 0] = -R_cam_icrs[0]
    M[:3, 1] = -R_cam_icrs[1]
    M[:3, 2] = R_cam_icrs[2]
    M[:3, 3] = position
    return M


def plain_pinhole(projection) -> bool:
    """True if ``projection`` is a :class:`~skynav.scenes.camera.Camera` whose rays Mitsuba's
    ``perspective`` sensor traces exactly: no lens distortion and square pixels (fx == fy)."""
    return isinstance(projection, Camera) and projection.distortion.is_identity and projection.pixel_pitch_y_um is None


def _sensor_kind(projection, sensor: str) -> str:
    """``"perspective"`` or ``"projection"`` for a ``render_resolved_body(sensor=...)`` request."""
    if sensor not in SENSORS:
        raise ConfigValueError("mitsuba.sensor", sensor, "one of: " + ", ".join(SENSORS))
    if sensor == "auto":
        return "perspective" if plain_pinhole(projection) else "projection"
    if sensor == "perspective" and not plain_pinhole(projection):
        raise ConfigValueError("mitsuba.sensor", sensor, "'projection' or 'auto' for this projection "
                               "(the perspective sensor is a pinhole: a Camera without distortion, with square pixels)")
    return sensor


def _perpendicular_basis(c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit vectors e1, e2 with (e1, e2, c) right-handed; e1 near the camera's +x."""
    a = np.array([1.0, 0.0, 0.0]) if abs(c[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = a - (a @ c) * c
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(c, e1)


def limb_radius_px(projection, R_cam_icrs, u_icrs, sin_r: float, *, n: int = 64) -> float:
    """Largest distance from a body's projected centre to its projected limb, px.

    Parameters
    ----------
    projection : Projection
    R_cam_icrs : ndarray, shape (3, 3)
    u_icrs : ndarray, shape (3,)
        Unit vector to the body's centre.
    sin_r : float
        ``radius_km / distance_km``: the limb is the cone of half-angle ``asin(sin_r)``.
    n : int
        Limb points.

    Returns
    -------
    float, px (NaN where the limb does not project)
    """
    u = np.asarray(u_icrs, dtype=float)
    p, q = _perpendicular_basis(u)
    rho = math.asin(sin_r)
    phi = np.linspace(0.0, 2.0 * math.pi, n, endpoint=False)
    limb = math.cos(rho) * u + math.sin(rho) * (np.cos(phi)[:, None] * p + np.sin(phi)[:, None] * q)
    R = np.asarray(R_cam_icrs, dtype=float)
    xy = projection.project(np.concatenate([(R @ u)[None], limb @ R.T]))
    return float(np.max(np.hypot(*(xy[1:] - xy[0]).T)))


def _triangle_solid_angle(a, b, c) -> np.ndarray:
    """Solid angle of spherical triangles of unit vectors (..., 3), sr (Van Oosterom & Strackee
    1983); the triple product from differences, so tiny triangles keep their precision."""
    num = np.abs(np.einsum("...i,...i->...", a, np.cross(b - a, c - a)))
    den = 1.0 + np.einsum("...i,...i->...", a, b) + np.einsum("...i,...i->...", b, c) + np.einsum("...i,...i->...", c, a)
    return 2.0 * np.arctan2(num, den)


def crop_lines_of_sight(projection, x0: int, y0: int, w: int, h: int, *, body: str = "body"):
    """The line-of-sight table of a crop, as the ``skynav_projection`` sensor takes it.

    Parameters
    ----------
    projection : Projection
    x0, y0, w, h : int
        Crop: top-left pixel (column, row) and size, px.
    body : str
        Named in the error.

    Returns
    -------
    basis : ndarray, shape (3, 3)
        Columns ``e1, e2, c`` in the camera frame; ``c`` is the line of sight at the crop centre.
    ab : ndarray, shape (h + 1, w + 1, 2)
        Tangent-plane coordinates of the pixel-corner lines of sight: ``v ~ a e1 + b e2 + c``.
    omega_sr : ndarray, shape (h, w)
        Solid angle of each pixel, sr.

    Raises
    ------
    ProjectionCropError
        A line of sight is not finite, or 89.9 deg or more from the crop centre's.
    """
    xs = x0 - 0.5 + np.arange(w + 1, dtype=float)
    ys = y0 - 0.5 + np.arange(h + 1, dtype=float)
    corners = np.stack(np.meshgrid(xs, ys), axis=-1)
    los = np.asarray(projection.line_of_sight(corners), dtype=float)
    c = np.asarray(projection.line_of_sight(np.array([x0 + 0.5 * (w - 1), y0 + 0.5 * (h - 1)])), dtype=float)
    if not (np.all(np.isfinite(los)) and np.all(np.isfinite(c))):
        raise ProjectionCropError(body, (x0, y0, w, h), "has pixels without a finite line of sight")
    los = los / np.linalg.norm(los, axis=-1, keepdims=True)
    c = c / np.linalg.norm(c)
    e1, e2 = _perpendicular_basis(c)
    dots = los @ c
    if float(dots.min()) < 1.7e-3:  # cos(89.9 deg)
        raise ProjectionCropError(body, (x0, y0, w, h), "spans 90 deg or more from its central line of sight")
    ab = np.stack([(los @ e1) / dots, (los @ e2) / dots], axis=-1)
    c00, c10, c01, c11 = los[:-1, :-1], los[:-1, 1:], los[1:, :-1], los[1:, 1:]
    omega = _triangle_solid_angle(c00, c10, c11) + _triangle_solid_angle(c00, c11, c01)
    return np.column_stack([e1, e2, c]), ab, omega
