"""Resolved bodies ray-traced by Mitsuba 3 (spectral) in a crop window of the frame.

The one module that holds Mitsuba's global state (``mi.set_variant``); the variant comes from
:func:`skynav.renderer.jit_backend.select_mitsuba_variant` (CUDA, else LLVM with a libLLVM that
a subprocess probe proved safe, else scalar), so a bad libLLVM can never abort the process.

Geometry (skynav's float64 projection is the master)
----------------------------------------------------
Mitsuba works in float32, so the scene is BODY-CENTRED and scaled: one world unit is the
observer-body distance ``body.distance_km``; the body is a sphere of radius
``radius_km / distance_km`` at the origin; the observer sits at ``-u_icrs`` (the apparent,
light-time corrected and aberrated direction); world axes are ICRS axes. A 1e8 km position in
float32 would carry 10 km of rounding; here every coordinate is O(1).

Rays come from the :class:`~skynav.scenes.projection.Projection` (the camera by default, or a
bench's per-pixel table), not from a built-in pinhole: a Python sensor plugin
(``skynav_projection``) whose ``sample_ray`` interpolates a table of lines of sight. The table is
computed in float64 with ``projection.line_of_sight`` at the ``(w + 1) x (h + 1)`` pixel CORNERS
of the crop, ``x = x0 - 0.5 + i``, ``y = y0 - 0.5 + j``, and stored as coordinates ``(a, b)`` on
the plane tangent to the crop's central line of sight ``c`` (``v ~ a e1 + b e2 + c``: small
numbers, so float32 keeps them to ~1e-9 rad). A film sample at ``(u, v)`` (Mitsuba film units,
0 at the crop's left/top edge, so ``x = x0 - 0.5 + u``) takes the bilinear interpolation of its
pixel's four corners; for a pinhole the tangent-plane coordinates are a homography of the
pixel coordinates and the interpolation is exact to ~1e-5 px. The ray leaves the observer along
``R_cam_icrs^T [e1 e2 c] (a, b, 1)``. The Mitsuba film IS the crop (``w x h`` pixels, box
filter), so lens distortion, fx != fy or a bench's table need nothing else.

A plain pinhole (a :class:`~skynav.scenes.camera.Camera` without distortion, with square pixels)
needs no table: its rays come from Mitsuba's built-in ``perspective`` sensor, in C++, which in
the scalar variant is faster than a Python ``sample_ray`` called once per ray
(``benchmarks/mitsuba_bench.py``). That sensor looks along local +z with +x to the LEFT and +y UP
of the image, and the skynav camera frame has +x right, +y down, so its ``to_world`` has the
columns ``(-x_cam, -y_cam, +z_cam)`` (ICRS components, the rows of ``R_cam_icrs``) and the
observer's position; its horizontal field of view is ``2 atan(w / (2 f))``. It maps the film
sample ``u`` (0 at the film's left edge) to the ray through the point ``u + ppo_x w`` of a
centred pinhole film (``principal_point_offset_x`` in units of the film width,
``perspective.cpp``); a skynav pixel coordinate is ``x = x0 - 0.5 + u``, and the principal point
``cx`` must sit at ``u = cx - x0 + 0.5 = w / 2 - ppo_x w``, hence
``ppo_x = ((w - 1) / 2 - (cx - x0)) / w`` and ``ppo_y = ((h - 1) / 2 - (cy - y0)) / h``. Both
sensors draw the same samples from the same seed (a 2-D film position and a wavelength, no
aperture sample), so for a pinhole they trace the same rays up to float32 rounding and the
corner table's interpolation error (~1e-5 px): ``tests/renderer/test_mitsuba_projection.py``
holds their photocentres within 0.001 px. ``render_resolved_body(sensor=...)`` forces either.

Each pixel's solid angle ``Omega`` is that of the spherical quadrilateral of its four corner
lines of sight (two triangles, Van Oosterom & Strackee 1983, IEEE Trans. Biomed. Eng. 30, 125);
for a pinhole it equals ``cos^3(theta) / f^2`` at the pixel centre to < 1e-7.

Radiometry
----------
Sun: ``directional`` emitter, EXPLICIT ``irregular`` spectrum on
:data:`skynav.renderer.spectra.WAVELENGTHS_NM`: ``E(lambda) = E_1AU(lambda) (1 AU / r)^2``
(W m^-2 nm^-1) with ``r`` the body-Sun distance at emission; travelling from
``sun_position_km`` to ``position_km``. (A plain number would silently become a D65 shape.)
The node values are the CALSPEC solar spectrum AVERAGED over each node's 5 nm cell
(:func:`solar_irradiance_nodes_w_m2_nm`): point samples of a spectrum full of Fraunhofer lines
put the in-band integral 1.2-1.5e-3 off the full-resolution one; cell averages, 5-8e-5.

BSDF: reflectance ``k(lambda) = reflectance_550 * reflectance_shape(body, lambda)``.

Film: ``specfilm`` with ONE sensor response ``s(lambda) = QE T(lambda) lambda / lambda_ref``
(``lambda_ref = 550 nm``), box filter, float32. Mitsuba samples wavelengths from ``s`` and the
film stores the unnormalised integral (``specfilm.cpp`` ``prepare_sample``: the sample weight is
``integral s``, divided by the sampling density): pixel value

    V = < integral L(lambda) s(lambda) dlambda >_pixel     (W m^-2 sr^-1, pixel-area average).

Photo-electrons per second in a pixel of solid angle ``Omega`` through an aperture ``A``:

    e-/s = A Omega integral L QE T lambda / (h c) dlambda = V * A * Omega * lambda_ref / (h c)

the same kernel as :meth:`Radiometry.electrons_per_s_from_spectral_irradiance` (photon counting,
aperture area, no cosine at the pupil), because ``sum_pixels L Omega = integral L dOmega`` is the
irradiance the point-source path uses (``Omega`` from the corner lines of sight, see Geometry).

``normalize="phase_law"`` (default) rescales the crop so its total equals the point-source
electrons of the body at its catalogued V (``Radiometry.body_electrons_per_s``): the BRDF gives
the shape and the photocentre, the Mallama & Hilton phase law the brightness, and the
resolved/unresolved switch at :data:`RESOLVED_THRESHOLD_PX` is continuous in flux.

Sampling and noise
------------------
``stratified`` sampler (jittered strata per pixel in every dimension, including the wavelength
sample), ``direct`` integrator with one emitter sample and no BSDF sample (the Sun is a delta
light: emitter sampling is exact, BSDF sampling can never hit it). The Mitsuba seed of each
sub-frame is drawn from the caller's generator (the renderer passes a child of the frame's
stream, so every frame samples its disks differently); the seeds are returned.

Kernel reuse
------------
One Mitsuba scene per (variant, crop size, BRDF, body reflectance, spectral response, spp); a
frame only updates parameters: the sensor's line-of-sight table (a Dr.Jit array, never a
literal), its opaque crop-to-world rotation and origin, and, through ``mi.traverse``, the
sphere's and the Sun's ``to_world``. The Sun's spectrum stays at 1 AU in the scene and the
``(1 AU / r)^2`` factor multiplies the film values (the rendering is linear in it): updating a
141-node spectrum every frame would launch (and, at first, compile) extra kernels. Crop sizes are rounded up to multiples of
:data:`CROP_QUANTUM_PX` so a moving, slowly growing body keeps hitting the same scene, and the
compiled kernels are reused (``benchmarks/mitsuba_bench.py`` counts them). Mitsuba 3.9 has no
animated transforms: ``time_samples`` sub-frames each update the sensor rotation from
:func:`skynav.scenes.frames.propagate_attitude` (the camera-frame table stays) and are averaged.
"""

from __future__ import annotations

import functools
import math
import threading
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np

from skynav.infra.errors import ConfigValueError
from skynav.scenes.camera import Camera
from skynav.scenes.constants import AU_KM
from skynav.scenes.constants import C_M_S as _C_M_S
from skynav.scenes.constants import PLANCK_J_S as _H_J_S
from skynav.scenes.frames import propagate_attitude
from skynav.scenes.scene import RESOLVED_THRESHOLD_PX  # the default diameter (px) above which a body is ray-traced

from . import jit_backend, spectra
from .brdf import BRDF, default_brdf
from .errors import ProjectionCropError
from .radiometry import Radiometry

__all__ = [
    "RESOLVED_THRESHOLD_PX",
    "ResolvedBodyImage",
    "render_resolved_body",
    "crop_window",
    "crop_lines_of_sight",
    "current_variant",
    "clear_cache",
    "solar_irradiance_nodes_w_m2_nm",
    "plain_pinhole",
]


#: Margin around the body's disk (and its streak) in the crop, px.
CROP_MARGIN_PX = 2.0

#: Crop sizes are rounded up to a multiple of this, px (kernel reuse across frames).
CROP_QUANTUM_PX = 8

#: Largest crop side, px (a body larger than this is clipped to a window around the frame).
MAX_CROP_PX = 4096

LAMBDA_REF_NM = 550.0

#: Near and far clip of the ``perspective`` sensor, world units (the observer-body distance is
#: 1; the body's surface is at >= 1 - r, its far side at <= 1 + r < 2).
_NEAR_CLIP = 1e-5
_FAR_CLIP = 4.0

#: ``render_resolved_body(sensor=...)`` values.
SENSORS = ("auto", "perspective", "projection")

_lock = threading.RLock()
_cache: "OrderedDict[tuple, _Entry]" = OrderedDict()
_CACHE_SIZE = 8
_registered: set = set()


@dataclass(frozen=True, kw_only=True, eq=False)
class ResolvedBodyImage:
    """A resolved body rendered in a crop of the frame.

    Attributes
    ----------
    x0, y0 : int
        Column and row (in the full image) of the crop's top-left pixel; may be negative or
        extend past the image (callers clip).
    electrons : ndarray, shape (h, w), float64
        Expected electrons over the exposure (no PSF, no noise).
    photocentre_xy : tuple of float
        Electron-weighted centroid, full-image pixel coordinates (pixel centres at integers).
    centre_of_figure_xy : tuple of float
        Projection of the body's apparent centre at mid-exposure, px (``body.xy`` for the
        scene's camera).
    radius_px : float
        Apparent radius: the largest distance from the projected centre to the projected limb
        at mid-exposure, px (``f tan(asin(R / d))`` on the axis of a pinhole).
    electrons_total, electrons_raw_total : float
        Sum of ``electrons``; and the physical BRDF rendering's sum before normalisation, e-.
    variant : str
        Mitsuba variant used.
    spp, time_samples : int
    brdf : BRDF
    normalize : str
    seeds : tuple of int
        Mitsuba seed of each sub-frame.
    sensor : str
        Mitsuba sensor that traced the rays: ``"perspective"`` (a plain pinhole) or
        ``"projection"`` (the line-of-sight table).
    """

    x0: int
    y0: int
    electrons: np.ndarray
    photocentre_xy: tuple
    centre_of_figure_xy: tuple
    radius_px: float
    electrons_total: float
    electrons_raw_total: float
    variant: str
    spp: int
    time_samples: int
    brdf: BRDF
    normalize: str
    seeds: tuple = ()
    sensor: str = "projection"


# ------------------------------------------------------------------------------ variant
def current_variant(variant: str | None = None) -> str:
    """Set (if needed) and return the Mitsuba variant: ``variant`` or the probed choice."""
    if variant is None:
        variant, _ = jit_backend.select_mitsuba_variant()
    elif variant.startswith("llvm"):
        if not jit_backend.configure_llvm().available:
            raise ConfigValueError("mitsuba.variant", variant, "a variant whose backend works here (LLVM probe failed)")
    # Mitsuba only when a body is ray-traced: import skynav.renderer loads neither Mitsuba nor Dr.Jit
    import mitsuba as mi

    if mi.variant() != variant:
        mi.set_variant(variant)
    return variant


def clear_cache() -> None:
    """Forget the cached Mitsuba scenes."""
    with _lock:
        _cache.clear()


# ------------------------------------------------------------------------------ geometry
def _sample_times(exposure_s: float, n: int) -> np.ndarray:
    """Sub-frame instants relative to mid-exposure: midpoints of n equal sub-intervals, s."""
    return ((np.arange(n) + 0.5) / n - 0.5) * exposure_s


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


# ------------------------------------------------------------------------------ Mitsuba scene
@functools.lru_cache(maxsize=4)
def _solar_cells_1au(wl_key: tuple) -> np.ndarray:
    wl = np.asarray(wl_key)
    edges = np.concatenate([[wl[0]], 0.5 * (wl[1:] + wl[:-1]), [wl[-1]]])
    out = np.empty_like(wl)
    for i in range(wl.size):
        lo, hi = edges[i], edges[i + 1]
        # cells are half-open at the ends of the grid; widen them symmetrically there
        half = max(wl[i] - lo, hi - wl[i])
        x = np.linspace(wl[i] - half, wl[i] + half, 401)
        out[i] = np.trapezoid(spectra.solar_irradiance_1au_w_m2_nm(x), x) / (2.0 * half)
    return out


def solar_irradiance_nodes_w_m2_nm(r_sun_km: float) -> np.ndarray:
    """The Sun's spectral irradiance at ``r_sun_km`` on :data:`spectra.WAVELENGTHS_NM`, each node
    the average over its cell (half-way to the neighbours), W m^-2 nm^-1; shape (M,)."""
    return _solar_cells_1au(tuple(float(x) for x in spectra.WAVELENGTHS_NM)) * (AU_KM / float(r_sun_km)) ** 2


def _spectrum_dict(wl, values) -> dict:
    return {
        "type": "irregular",
        "wavelengths": ",".join(repr(float(x)) for x in wl),
        "values": ",".join(repr(float(x)) for x in values),
    }


def _register_plugins(variant: str) -> None:
    """Register the Python plugins for the current variant: the BSDFs (Lommel-Seeliger,
    Oren-Nayar) and the ``skynav_projection`` sensor."""
    if variant in _registered:
        return
    # Mitsuba only when a body is ray-traced: import skynav.renderer loads neither Mitsuba nor Dr.Jit
    import drjit as dr
    import mitsuba as mi

    class _PyDiffuseBase(mi.BSDF):
        def __init__(self, props):
            mi.BSDF.__init__(self, props)
            self.reflectance = props["reflectance"]
            flags = mi.BSDFFlags.DiffuseReflection | mi.BSDFFlags.FrontSide
            self.m_components = [flags]
            self.m_flags = flags

        def _f_cos(self, si, wo, active):  # BRDF x cos(wo), Spectrum
            raise NotImplementedError

        def sample(self, ctx, si, sample1, sample2, active):
            cos_i = mi.Frame3f.cos_theta(si.wi)
            bs = dr.zeros(mi.BSDFSample3f)
            bs.wo = mi.warp.square_to_cosine_hemisphere(sample2)
            bs.pdf = mi.warp.square_to_cosine_hemisphere_pdf(bs.wo)
            bs.eta = 1.0
            bs.sampled_type = mi.UInt32(+mi.BSDFFlags.DiffuseReflection)
            bs.sampled_component = mi.UInt32(0)
            ok = active & (cos_i > 0) & (bs.pdf > 0)
            value = self._f_cos(si, bs.wo, ok) / dr.select(ok, bs.pdf, 1.0)
            return bs, dr.select(ok, value, 0.0)

        def eval(self, ctx, si, wo, active):
            ok = active & (mi.Frame3f.cos_theta(si.wi) > 0) & (mi.Frame3f.cos_theta(wo) > 0)
            return dr.select(ok, self._f_cos(si, wo, ok), 0.0)

        def pdf(self, ctx, si, wo, active):
            ok = active & (mi.Frame3f.cos_theta(si.wi) > 0) & (mi.Frame3f.cos_theta(wo) > 0)
            return dr.select(ok, mi.warp.square_to_cosine_hemisphere_pdf(wo), 0.0)

        def eval_pdf(self, ctx, si, wo, active):
            return self.eval(ctx, si, wo, active), self.pdf(ctx, si, wo, active)

        def traverse(self, callback):
            callback.put("reflectance", self.reflectance, mi.ParamFlags.Differentiable)

        def parameters_changed(self, keys):
            pass

    class LommelSeeliger(_PyDiffuseBase):
        """f = w / (4 pi (mu0 + mu)); eval returns f mu0 (mu0 = cos of the light direction)."""

        def _f_cos(self, si, wo, active):
            mu = dr.maximum(mi.Frame3f.cos_theta(si.wi), 0.0)
            mu0 = dr.maximum(mi.Frame3f.cos_theta(wo), 0.0)
            k = self.reflectance.eval(si, active)
            return k * (dr.inv_four_pi * mu0 / dr.maximum(mu0 + mu, 1e-12))

    class OrenNayar(_PyDiffuseBase):
        """Qualitative Oren-Nayar (1994, eq. 30); ``roughness`` is the slope deviation, rad."""

        def __init__(self, props):
            super().__init__(props)
            s2 = float(props["roughness"]) ** 2
            self.a = 1.0 - 0.5 * s2 / (s2 + 0.33)
            self.b = 0.45 * s2 / (s2 + 0.09)

        def _f_cos(self, si, wo, active):
            wi = si.wi
            c0 = dr.clip(mi.Frame3f.cos_theta(wo), 0.0, 1.0)
            c1 = dr.clip(mi.Frame3f.cos_theta(wi), 0.0, 1.0)
            s0 = dr.safe_sqrt(1.0 - c0 * c0)
            s1 = dr.safe_sqrt(1.0 - c1 * c1)
            pw = dr.safe_sqrt((wo.x * wo.x + wo.y * wo.y) * (wi.x * wi.x + wi.y * wi.y))
            cos_psi = dr.select(pw > 1e-12, (wo.x * wi.x + wo.y * wi.y) / dr.maximum(pw, 1e-12), 1.0)
            sin_a = dr.maximum(s0, s1)
            tan_b = dr.select(c0 > c1, s0 / dr.maximum(c0, 1e-12), s1 / dr.maximum(c1, 1e-12))
            k = self.reflectance.eval(si, active)
            return k * (dr.inv_pi * (self.a + self.b * dr.maximum(cos_psi, 0.0) * sin_a * tan_b) * c0)

    class ProjectionSensor(mi.Sensor):
        """Rays along a table of lines of sight at the film's pixel corners (module notes).

        Parameters (set per frame, never literals in a kernel): ``a``, ``b``, the ``(h+1) x (w+1)``
        corner table of tangent-plane coordinates, each flattened row-major; ``basis``, the
        crop-to-world rotation (columns ``R^T e1, R^T e2, R^T c``); ``origin``, the observer.
        """

        def __init__(self, props):
            mi.Sensor.__init__(self, props)
            w, h = self.film().crop_size()
            self.w, self.h = int(w), int(h)
            self.m_needs_sample_3 = False  # a pinhole-like sensor: no aperture sample
            # a Dr.Jit array in the JIT variants; in the scalar ones (one ray per call, mi.Float is
            # a float) a NumPy array read by index
            self._jit = dr.is_jit_v(mi.Float)
            self.set_table(np.zeros((self.h + 1, self.w + 1, 2)))
            self.basis = mi.Matrix3f(mi.ScalarMatrix3f(np.eye(3)))
            self.origin = mi.Point3f(0.0, 0.0, -1.0)
            dr.make_opaque(self.basis, self.origin)

        def set_table(self, ab) -> None:
            """Corner table, ndarray (h + 1, w + 1, 2)."""
            # two flat arrays gathered with the pixel index itself (a gather of (a, b) pairs from
            # one interleaved array let Dr.Jit emit two forms of the index arithmetic, i.e. two
            # kernels, from one frame to the next)
            a = np.ascontiguousarray(np.asarray(ab)[..., 0], dtype=np.float32).ravel()
            b = np.ascontiguousarray(np.asarray(ab)[..., 1], dtype=np.float32).ravel()
            self.a, self.b = (mi.Float(a), mi.Float(b)) if self._jit else (a, b)

        def _corner(self, k, active):
            if self._jit:
                return mi.Point2f(dr.gather(mi.Float, self.a, k, active), dr.gather(mi.Float, self.b, k, active))
            return mi.Point2f(float(self.a[k]), float(self.b[k]))

        def set_view(self, basis, origin) -> None:
            """Crop-to-world rotation (3, 3) and observer position (3,), world units."""
            self.basis = mi.Matrix3f(mi.ScalarMatrix3f(np.asarray(basis, dtype=np.float64)))
            self.origin = mi.Point3f(*(float(v) for v in origin))
            dr.make_opaque(self.basis, self.origin)

        def sample_ray(self, time, wavelength_sample, position_sample, aperture_sample, active=True):
            wavelengths, weight = self.sample_wavelengths(dr.zeros(mi.SurfaceInteraction3f), wavelength_sample, active)
            u = position_sample.x * self.w
            v = position_sample.y * self.h
            i = dr.clip(mi.Int32(dr.floor(u)), 0, self.w - 1)
            j = dr.clip(mi.Int32(dr.floor(v)), 0, self.h - 1)
            fu = u - mi.Float(i)
            fv = v - mi.Float(j)
            k = mi.UInt32(j * (self.w + 1) + i)
            c00 = self._corner(k, active)
            c10 = self._corner(k + 1, active)
            c01 = self._corner(k + (self.w + 1), active)
            c11 = self._corner(k + (self.w + 2), active)
            p = dr.lerp(dr.lerp(c00, c10, fu), dr.lerp(c01, c11, fu), fv)
            d = dr.normalize(self.basis @ mi.Vector3f(p.x, p.y, 1.0))
            return mi.Ray3f(self.origin, d, time, wavelengths), weight

        def sample_ray_differential(self, time, wavelength_sample, position_sample, aperture_sample, active=True):
            ray, weight = self.sample_ray(time, wavelength_sample, position_sample, aperture_sample, active)
            return mi.RayDifferential3f(ray), weight

        def traverse(self, callback):
            super().traverse(callback)
            if self._jit:
                callback.put("table_a", self.a, mi.ParamFlags.NonDifferentiable)
                callback.put("table_b", self.b, mi.ParamFlags.NonDifferentiable)

        def parameters_changed(self, keys):
            pass

        def to_string(self):
            return f"ProjectionSensor[{self.w} x {self.h}]"

    mi.register_bsdf("skynav_lommel_seeliger", lambda props: LommelSeeliger(props))
    mi.register_bsdf("skynav_oren_nayar", lambda props: OrenNayar(props))
    mi.register_sensor("skynav_projection", lambda props: ProjectionSensor(props))
    _registered.add(variant)


def _bsdf_dict(brdf: BRDF, reflectance_values) -> dict:
    refl = _spectrum_dict(spectra.WAVELENGTHS_NM, reflectance_values)
    if brdf.kind == "lambert":
        return {"type": "diffuse", "reflectance": refl}
    if brdf.kind == "lommel_seeliger":
        return {"type": "skynav_lommel_seeliger", "reflectance": refl}
    return {"type": "skynav_oren_nayar", "reflectance": refl, "roughness": float(brdf.roughness_rad)}


class _Entry:
    """A loaded Mitsuba scene and its traversed parameters."""

    def __init__(self, scene, params, spp: int):
        self.scene = scene
        self.params = params
        self.spp = spp


def _sensor_dict(kind: str, camera, w: int, h: int) -> dict:
    """The sensor of a crop's scene, without its film and sampler (see the module notes)."""
    if kind == "projection":
        return {"type": "skynav_projection"}
    # Mitsuba only when a body is ray-traced: import skynav.renderer loads neither Mitsuba nor Dr.Jit
    import mitsuba as mi

    return {
        "type": "perspective",
        "fov_axis": "x",
        "fov": math.degrees(2.0 * math.atan(0.5 * w / camera.focal_length_px)),
        "near_clip": _NEAR_CLIP,
        "far_clip": _FAR_CLIP,
        "to_world": mi.ScalarTransform4f(_to_world(np.eye(3), [0.0, 0.0, -1.0])),
    }


def _scene_for(variant: str, camera, w: int, h: int, brdf: BRDF, body_name: str, spp: int,
               sensor: str = "projection") -> _Entry:
    wl = spectra.WAVELENGTHS_NM
    refl = brdf.reflectance_550 * spectra.reflectance_shape(body_name, wl)
    srf = spectra.response_on_grid(camera, wl) * wl / LAMBDA_REF_NM
    # the perspective sensor's field of view is a property of the scene: it keys the cache
    fov_key = float(camera.focal_length_px) if sensor == "perspective" else None
    key = (variant, sensor, fov_key, w, h, brdf, tuple(np.round(refl, 12)), tuple(np.round(srf, 12)), int(spp))
    with _lock:
        hit = _cache.get(key)
        if hit is not None:
            _cache.move_to_end(key)
            return hit
    # Mitsuba only when a body is ray-traced: import skynav.renderer loads neither Mitsuba nor Dr.Jit
    import mitsuba as mi

    _register_plugins(variant)
    sun = solar_irradiance_nodes_w_m2_nm(AU_KM)
    scene = mi.load_dict({
        "type": "scene",
        "integrator": {"type": "direct", "emitter_samples": 1, "bsdf_samples": 0},
        "sensor": {
            **_sensor_dict(sensor, camera, w, h),
            "film": {
                "type": "specfilm",
                "width": int(w),
                "height": int(h),
                "component_format": "float32",
                "rfilter": {"type": "box"},
                "qe_t_photons": _spectrum_dict(wl, srf),
            },
            "sampler": {"type": "stratified", "sample_count": int(spp), "jitter": True},
        },
        "body": {
            "type": "sphere",
            "center": [0.0, 0.0, 0.0],
            "radius": 1.0,
            "to_world": mi.ScalarTransform4f().scale(1e-3),
            "bsdf": _bsdf_dict(brdf, refl),
        },
        "sun": {
            "type": "directional",
            "to_world": mi.ScalarTransform4f(_frame_z([0.0, 0.0, 1.0])),
            "irradiance": _spectrum_dict(wl, sun),
        },
    })
    params = mi.traverse(scene)
    actual_spp = int(scene.sensors()[0].sampler().sample_count())
    entry = _Entry(scene, params, actual_spp)
    with _lock:
        _cache[key] = entry
        while len(_cache) > _CACHE_SIZE:
            _cache.popitem(last=False)
    return entry


def _set(params, key: str, value) -> None:
    """Assign a NumPy value to a traversed parameter, in the parameter's own (variant) type."""
    params[key] = type(params[key])(value)


# ------------------------------------------------------------------------------ public API
def render_resolved_body(
    scene,
    body,
    *,
    spp: int = 16,
    time_samples: int = 1,
    brdf: BRDF | str | None = None,
    normalize: str = "phase_law",
    rng: np.random.Generator | int | None = None,
    variant: str | None = None,
    margin_px: float = CROP_MARGIN_PX,
    projection=None,
    sensor: str = "auto",
) -> ResolvedBodyImage:
    """Ray-trace one resolved body with Mitsuba 3 in a crop window around it.

    Parameters
    ----------
    scene : skynav.scenes.scene.Scene
        Attitude, body rate and the camera's optics (aperture, spectral response, exposure).
    body : skynav.scenes.scene.BodyInView
    spp : int
        Samples per pixel (the stratified sampler rounds up to a square).
    time_samples : int
        Sub-frame instants spread over the exposure (streaks from the camera rotation).
    brdf : BRDF, str or None
        A :class:`~skynav.renderer.brdf.BRDF`, a law name (``"lambert"``,
        ``"lommel_seeliger"``, ``"oren_nayar"``) scaled to the body's geometric albedo, or None
        for the body's default law (:func:`~skynav.renderer.brdf.default_brdf`).
    normalize : {"phase_law", "none"}
        ``"phase_law"``: total = point-source electrons of the body's V magnitude;
        ``"none"``: the physical rendering of the BRDF and albedo.
    rng : numpy.random.Generator, int or None
        Draws the Mitsuba seed of each sub-frame (None: ``default_rng(0)``, the same seeds on
        every call; :func:`~skynav.renderer.render.render` passes a child of the frame's stream).
    variant : str or None
        Mitsuba variant (None: :func:`jit_backend.select_mitsuba_variant`).
    margin_px : float
        Extra pixels around the disk in the crop.
    projection : Projection, optional
        Where the rays come from: ``projection.line_of_sight`` at the crop's pixel corners
        (default ``scene.camera``: its pinhole and lens distortion).
    sensor : {"auto", "perspective", "projection"}
        Mitsuba's sensor: ``"auto"`` takes the built-in ``perspective`` sensor for a plain
        pinhole (:func:`plain_pinhole`) and the ``skynav_projection`` table otherwise;
        ``"perspective"`` is refused for any other projection.

    Returns
    -------
    ResolvedBodyImage
    """
    if normalize not in ("phase_law", "none"):
        raise ConfigValueError("mitsuba.normalize", normalize, "one of: phase_law, none")
    if not (isinstance(spp, (int, np.integer)) and spp >= 1):
        raise ConfigValueError("mitsuba.spp", spp, "an integer >= 1")
    if not (isinstance(time_samples, (int, np.integer)) and time_samples >= 1):
        raise ConfigValueError("mitsuba.time_samples", time_samples, "an integer >= 1")
    if brdf is None or isinstance(brdf, str):
        brdf = default_brdf(body.name, brdf)
    if not (body.distance_km > body.radius_km > 0):
        raise ConfigValueError("body.distance_km", body.distance_km, f"> radius_km = {body.radius_km}")
    rng = np.random.default_rng(0 if rng is None else rng)

    cam = scene.camera
    proj = cam if projection is None else projection
    kind = _sensor_kind(proj, sensor)
    variant = current_variant(variant)
    # Mitsuba only when a body is ray-traced: import skynav.renderer loads neither Mitsuba nor Dr.Jit
    import mitsuba as mi

    u = np.asarray(body.u_icrs, dtype=float)
    u = u / np.linalg.norm(u)
    sin_r = body.radius_km / body.distance_km

    dt = _sample_times(cam.exposure_s, int(time_samples))
    R_mid = np.asarray(scene.R_cam_icrs, dtype=float)
    R_t = propagate_attitude(R_mid, scene.angular_velocity_rad_s, dt)
    centres = proj.project(np.einsum("tij,j->ti", R_t, u))
    radius_px = limb_radius_px(proj, R_mid, u, sin_r)
    if not (np.all(np.isfinite(centres)) and math.isfinite(radius_px)):
        raise ProjectionCropError(body.name, (0, 0, 0, 0), "cannot be placed: its centre or limb does not project")
    x0, y0, w, h = crop_window(centres, radius_px, margin_px=margin_px)
    basis, ab, omega_sr = crop_lines_of_sight(proj, x0, y0, w, h, body=body.name)

    entry = _scene_for(variant, proj if kind == "perspective" else cam, w, h, brdf, body.name, int(spp), kind)
    params = entry.params
    mi_sensor = entry.scene.sensors()[0]
    if kind == "projection":
        mi_sensor.set_table(ab)

    # body: sphere radius sin_r at the origin (world unit = observer-body distance)
    _set(params, "body.to_world", np.diag([sin_r, sin_r, sin_r, 1.0]))
    # Sun: light travels from the Sun to the body; 1/r^2 from 1 AU
    body_pos = np.asarray(body.position_km, dtype=float)
    sun_vec = body_pos - np.asarray(body.sun_position_km, dtype=float)
    r_sun_km = float(np.linalg.norm(sun_vec))
    _set(params, "sun.to_world", _frame_z(sun_vec))
    params.update()
    # The emitter keeps its 1 AU spectrum (no per-frame spectral update, no recompilation); the
    # rendering is linear in the irradiance, so the 1/r^2 factor is applied to the film values.
    inv_r2 = (AU_KM / r_sun_km) ** 2

    acc = np.zeros((h, w))
    seeds = []
    for k in range(len(dt)):
        if kind == "projection":
            mi_sensor.set_view(R_t[k].T @ basis, -u)  # crop frame -> camera frame -> ICRS
        else:
            _set(params, "sensor.to_world", _to_world(R_t[k], -u))
            _set(params, "sensor.principal_point_offset_x", float(((w - 1) / 2.0 - (proj.cx - x0)) / w))
            _set(params, "sensor.principal_point_offset_y", float(((h - 1) / 2.0 - (proj.cy - y0)) / h))
            params.update()
        seed = int(rng.integers(0, 2**31 - 1))
        seeds.append(seed)
        img = mi.render(entry.scene, spp=entry.spp, seed=seed)
        acc += np.asarray(img, dtype=np.float64).reshape(h, w)
    value = acc * (inv_r2 / len(dt))  # time-averaged film value at r_sun, W m^-2 sr^-1 (SRF-weighted)

    e_per_s = value * omega_sr * (cam.aperture_area_m2 * LAMBDA_REF_NM * 1e-9 / (_H_J_S * _C_M_S))
    electrons = e_per_s * cam.exposure_s
    raw_total = float(electrons.sum())
    if normalize == "phase_law":
        target = float(Radiometry.for_camera(cam).body_electrons_per_s(body.name, body.v_mag)) * cam.exposure_s
        if raw_total > 0 and math.isfinite(target):
            electrons = electrons * (target / raw_total)
        else:
            electrons = np.zeros_like(electrons)
    total = float(electrons.sum())
    centre = proj.project(R_mid @ u)
    if total > 0:
        ys = np.arange(y0, y0 + h, dtype=float)
        xs = np.arange(x0, x0 + w, dtype=float)
        photocentre = (float(electrons.sum(0) @ xs / total), float(electrons.sum(1) @ ys / total))
    else:
        photocentre = (float(centre[0]), float(centre[1]))
    return ResolvedBodyImage(
        x0=x0, y0=y0, electrons=electrons, photocentre_xy=photocentre,
        centre_of_figure_xy=(float(centre[0]), float(centre[1])), radius_px=float(radius_px),
        electrons_total=total, electrons_raw_total=raw_total, variant=variant, spp=entry.spp,
        time_samples=int(time_samples), brdf=brdf, normalize=normalize, seeds=tuple(seeds),
        sensor=kind,
    )
