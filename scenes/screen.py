"""The screen of a hardware-in-the-loop facility and its geometry: screen pixel <-> camera line of sight.

Part of the facility model (:mod:`skynav.scenes.facility` holds the radiometry, the facility as a
whole, its file form and its presets): :class:`Screen` is the display; :class:`GeometricModel`
maps a screen pixel to a camera-frame tangent-plane direction through the collimator (screen
decentre, tilt and roll, collimator focal length and Brown-Conrady distortion, camera
misalignment) plus a smooth :class:`ResidualField`; :class:`ScreenProjection` is that mapping as a
:class:`~skynav.scenes.projection.Projection` at screen resolution, so the renderer draws straight
into screen pixels. Angles rad, lengths mm, pixel coordinates with the centre of the top-left
pixel at (0, 0).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
from scipy.interpolate import RectBivariateSpline

from skynav.infra.errors import ConfigValueError

__all__ = ["Screen", "ResidualField", "GeometricModel", "ScreenProjection", "rotation_from_vector"]


def _check(cond: bool, key: str, value, allowed: str) -> None:
    if not cond:
        raise ConfigValueError(key, value, allowed)


# ----------------------------------------------------------------------------- screen
@dataclass(frozen=True, kw_only=True)
class Screen:
    """The display: size, pixel pitch and bit depth (PNG: uint8 for 8 bits, uint16 above).

    Parameters
    ----------
    width_px, height_px : int
        Screen size, screen pixels (>= 16).
    pixel_pitch_um : float
        Screen pixel pitch, um.
    bit_depth : int
        Bits of a screen digital count, 1..16.

    Raises
    ------
    ConfigValueError
        A value out of its range.

    Examples
    --------
    >>> from skynav.scenes import Screen
    >>> Screen(width_px=640, height_px=640, pixel_pitch_um=32.0).max_dn
    1023
    """

    width_px: int
    height_px: int
    pixel_pitch_um: float
    bit_depth: int = 10

    def __post_init__(self):
        _check(isinstance(self.width_px, int) and self.width_px >= 16, "screen.width_px", self.width_px, "an integer >= 16")
        _check(isinstance(self.height_px, int) and self.height_px >= 16, "screen.height_px", self.height_px, "an integer >= 16")
        _check(math.isfinite(self.pixel_pitch_um) and self.pixel_pitch_um > 0, "screen.pixel_pitch_um", self.pixel_pitch_um, "> 0")
        _check(isinstance(self.bit_depth, int) and 1 <= self.bit_depth <= 16, "screen.bit_depth", self.bit_depth, "an integer in 1..16")

    @property
    def max_dn(self) -> int:
        """Largest screen digital count, DN: ``2**bit_depth - 1``."""
        return (1 << self.bit_depth) - 1


# ----------------------------------------------------------------------------- geometry
def rotation_from_vector(rvec) -> np.ndarray:
    """Rotation matrix of a rotation vector (axis * angle, rad), Rodrigues' formula; active."""
    r = np.asarray(rvec, dtype=float)
    th = float(np.linalg.norm(r))
    if th < 1e-300:
        return np.eye(3)
    k = r / th
    K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + math.sin(th) * K + (1.0 - math.cos(th)) * (K @ K)


@dataclass(frozen=True, kw_only=True)
class ResidualField:
    """A smooth correction of the line of sight over the screen: tangent-plane offsets (rad) on a
    regular grid of screen pixel coordinates, interpolated by a bicubic spline.

    ``x_px`` (nx,), ``y_px`` (ny,) grid nodes; ``dx_rad``, ``dy_rad`` tuples of rows (ny, nx).
    """

    x_px: tuple
    y_px: tuple
    dx_rad: tuple
    dy_rad: tuple

    def __post_init__(self):
        for name in ("x_px", "y_px"):
            object.__setattr__(self, name, tuple(float(v) for v in getattr(self, name)))
        ny, nx = len(self.y_px), len(self.x_px)
        _check(nx >= 4 and ny >= 4, "geometric.residual_field", (nx, ny), "a grid of at least 4 x 4 nodes")
        for name in ("dx_rad", "dy_rad"):
            a = np.asarray(getattr(self, name), dtype=float)
            _check(a.shape == (ny, nx) and np.all(np.isfinite(a)), f"geometric.residual_field.{name}", a.shape, f"finite values of shape ({ny}, {nx})")
            object.__setattr__(self, name, tuple(tuple(float(v) for v in row) for row in a))

    @functools.cached_property
    def _splines(self):
        x, y = np.array(self.x_px), np.array(self.y_px)
        return (RectBivariateSpline(y, x, np.array(self.dx_rad), kx=3, ky=3),
                RectBivariateSpline(y, x, np.array(self.dy_rad), kx=3, ky=3))

    def __call__(self, x, y):
        """Offsets at screen px ``(x, y)``; constant beyond the grid (clamped to its edge)."""
        sx, sy = self._splines
        shape = np.shape(x)
        xf = np.clip(np.ravel(x), self.x_px[0], self.x_px[-1])
        yf = np.clip(np.ravel(y), self.y_px[0], self.y_px[-1])
        return sx.ev(yf, xf).reshape(shape), sy.ev(yf, xf).reshape(shape)

    def __getstate__(self):
        d = dict(self.__dict__)
        d.pop("_splines", None)
        return d

    def __setstate__(self, d):
        self.__dict__.update(d)


@dataclass(frozen=True, kw_only=True)
class GeometricModel:
    """Physical model of the facility geometry (``model: physical/1``). Angles rad, lengths mm.

    Screen pixel ``(x, y)`` -> millimetres from the screen centre -> rolled by ``roll_rad`` ->
    tilted (``tilt_x_rad`` about x, then ``tilt_y_rad`` about y) and offset by the decentre, at
    ``focal_length_mm`` from the collimator -> chief-ray slope -> Brown-Conrady distortion of the
    collimator ``(k1, k2, p1, p2)`` -> rotated by the camera misalignment (rotation vector,
    rad) -> plus the residual field. Screen x right and y down map to camera +x and +y for a
    perfectly aligned facility (the image inversion of a real collimator is a 180 deg roll).
    """

    focal_length_mm: float
    decentre_x_mm: float = 0.0
    decentre_y_mm: float = 0.0
    tilt_x_rad: float = 0.0
    tilt_y_rad: float = 0.0
    roll_rad: float = 0.0
    k1: float = 0.0
    k2: float = 0.0
    p1: float = 0.0
    p2: float = 0.0
    misalignment_rad: tuple = (0.0, 0.0, 0.0)
    residual: ResidualField | None = None

    def __post_init__(self):
        _check(math.isfinite(self.focal_length_mm) and self.focal_length_mm > 0, "collimator.focal_length_mm", self.focal_length_mm, "> 0")
        object.__setattr__(self, "misalignment_rad", tuple(float(v) for v in self.misalignment_rad))
        _check(len(self.misalignment_rad) == 3, "geometric.misalignment_deg", self.misalignment_rad, "3 angles")

    #: names of the fitted parameters, in the order of :meth:`vector`
    PARAMS = ("focal_length_mm", "decentre_x_mm", "decentre_y_mm", "tilt_x_rad", "tilt_y_rad", "roll_rad",
              "k1", "k2", "p1", "p2", "mis_x_rad", "mis_y_rad", "mis_z_rad")

    def vector(self) -> np.ndarray:
        return np.array([self.focal_length_mm, self.decentre_x_mm, self.decentre_y_mm, self.tilt_x_rad, self.tilt_y_rad,
                         self.roll_rad, self.k1, self.k2, self.p1, self.p2, *self.misalignment_rad])

    @classmethod
    def from_vector(cls, p, residual=None) -> "GeometricModel":
        p = [float(v) for v in p]
        return cls(focal_length_mm=p[0], decentre_x_mm=p[1], decentre_y_mm=p[2], tilt_x_rad=p[3], tilt_y_rad=p[4],
                   roll_rad=p[5], k1=p[6], k2=p[7], p1=p[8], p2=p[9], misalignment_rad=tuple(p[10:13]), residual=residual)

    @functools.cached_property
    def _matrices(self):
        cx, sx = math.cos(self.tilt_x_rad), math.sin(self.tilt_x_rad)
        cy, sy = math.cos(self.tilt_y_rad), math.sin(self.tilt_y_rad)
        Rx = np.array([[1.0, 0.0, 0.0], [0.0, cx, -sx], [0.0, sx, cx]])
        Ry = np.array([[cy, 0.0, sy], [0.0, 1.0, 0.0], [-sy, 0.0, cy]])
        return Ry @ Rx, rotation_from_vector(self.misalignment_rad)

    def __getstate__(self):
        d = dict(self.__dict__)
        d.pop("_matrices", None)
        return d

    def __setstate__(self, d):
        self.__dict__.update(d)

    def tangent(self, screen: Screen, xy_px, *, residual: bool = True) -> np.ndarray:
        """Camera-frame tangent-plane coordinates ``(vx/vz, vy/vz)`` of screen pixels, shape (..., 2)."""
        xy = np.asarray(xy_px, dtype=float)
        p_mm = screen.pixel_pitch_um * 1e-3
        u = (xy[..., 0] - 0.5 * (screen.width_px - 1)) * p_mm
        v = (xy[..., 1] - 0.5 * (screen.height_px - 1)) * p_mm
        c, s = math.cos(self.roll_rad), math.sin(self.roll_rad)
        ur, vr = c * u - s * v, s * u + c * v
        Rt, Rm = self._matrices
        X = Rt[0, 0] * ur + Rt[0, 1] * vr + self.decentre_x_mm
        Y = Rt[1, 0] * ur + Rt[1, 1] * vr + self.decentre_y_mm
        Z = Rt[2, 0] * ur + Rt[2, 1] * vr + self.focal_length_mm
        xn, yn = X / Z, Y / Z
        r2 = xn * xn + yn * yn
        radial = 1.0 + self.k1 * r2 + self.k2 * r2 * r2
        xd = xn * radial + 2.0 * self.p1 * xn * yn + self.p2 * (r2 + 2.0 * xn * xn)
        yd = yn * radial + self.p1 * (r2 + 2.0 * yn * yn) + 2.0 * self.p2 * xn * yn
        vx = Rm[0, 0] * xd + Rm[0, 1] * yd + Rm[0, 2]
        vy = Rm[1, 0] * xd + Rm[1, 1] * yd + Rm[1, 2]
        vz = Rm[2, 0] * xd + Rm[2, 1] * yd + Rm[2, 2]
        tx, ty = vx / vz, vy / vz
        if residual and self.residual is not None:
            dx, dy = self.residual(xy[..., 0], xy[..., 1])
            tx, ty = tx + dx, ty + dy
        return np.stack([tx, ty], -1)


@dataclass(frozen=True, kw_only=True)
class ScreenProjection:
    """Screen pixel <-> camera-frame line of sight of a facility: a
    :class:`~skynav.scenes.projection.Projection` at screen resolution.

    :meth:`line_of_sight` is the model in closed form; :meth:`project` inverts it by Newton's
    method on the tangent-plane coordinates (converged to 1e-10 px, far below 0.01 arcsec).
    """

    screen: Screen
    model: GeometricModel

    @property
    def width(self) -> int:
        return self.screen.width_px

    @property
    def height(self) -> int:
        return self.screen.height_px

    def line_of_sight(self, xy_px) -> np.ndarray:
        t = self.model.tangent(self.screen, xy_px)
        v = np.concatenate([t, np.ones(t.shape[:-1] + (1,))], -1)
        return v / np.linalg.norm(v, axis=-1, keepdims=True)

    def _local(self, xy, h=1e-3):
        t0 = self.model.tangent(self.screen, xy)
        tx = self.model.tangent(self.screen, xy + np.array([h, 0.0]))
        ty = self.model.tangent(self.screen, xy + np.array([0.0, h]))
        J = np.stack([(tx - t0) / h, (ty - t0) / h], -1)  # (..., 2 [t], 2 [x, y])
        return t0, J

    def project(self, v_cam, *, iterations: int = 12, tol_px: float = 1e-10) -> np.ndarray:
        v = np.asarray(v_cam, dtype=float)
        z = v[..., 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            target = np.stack([np.where(z > 0, v[..., 0] / z, np.nan), np.where(z > 0, v[..., 1] / z, np.nan)], -1)
        centre = np.array([0.5 * (self.width - 1), 0.5 * (self.height - 1)])
        tc, Jc = self._local(centre)
        xy = centre + np.einsum("ij,...j->...i", np.linalg.inv(Jc), target - tc)
        for _ in range(iterations):
            t0, J = self._local(xy)
            det = J[..., 0, 0] * J[..., 1, 1] - J[..., 0, 1] * J[..., 1, 0]
            r = target - t0
            # a direction far outside the screen can meet a flat (singular) model: inf/nan there,
            # which in_screen rejects, without a warning per frame
            with np.errstate(divide="ignore", invalid="ignore"):
                dx = (J[..., 1, 1] * r[..., 0] - J[..., 0, 1] * r[..., 1]) / det
                dy = (-J[..., 1, 0] * r[..., 0] + J[..., 0, 0] * r[..., 1]) / det
            xy = xy + np.stack([dx, dy], -1)
            step = np.nanmax(np.abs(np.stack([dx, dy]))) if np.any(np.isfinite(dx)) else 0.0
            if step < tol_px:
                break
        return xy

    def in_screen(self, xy_px, margin_px: float = 0.0):
        xy = np.asarray(xy_px, dtype=float)
        x, y = xy[..., 0], xy[..., 1]
        return (x >= -0.5 + margin_px) & (x <= self.width - 0.5 - margin_px) & (y >= -0.5 + margin_px) & (y <= self.height - 0.5 - margin_px)
