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
from skynav.scenes.constants import AU_KM
from skynav.scenes.constants import C_M_S as _C_M_S
from skynav.scenes.constants import PLANCK_J_S as _H_J_S
from skynav.scenes.frames import propagate_attitude
from skynav.scenes.scene import RESOLVED_THRESHOLD_PX  # the default diameter (px) above which a body is ray-traced

from . import jit_backend, spectra
from .brdf import BRDF, default_brdf
from .errors import ProjectionCropError
from .crop_geometry import (CROP_MARGIN_PX, SENSORS, _frame_z, _sensor_kind, _to_world, crop_lines_of_sight,
                            crop_window, limb_radius_px, plain_pinhole)
from .mitsuba_plugins import register_plugins
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


LAMBDA_REF_NM = 550.0

#: Near and far clip of the ``perspective`` sensor, world units (the observer-body distance is
#: 1; the body's surface is at >= 1 - r, its far side at <= 1 + r < 2).
_NEAR_CLIP = 1e-5
_FAR_CLIP = 4.0


_lock = threading.RLock()
_cache: "OrderedDict[tuple, _Entry]" = OrderedDict()
_CACHE_SIZE = 8


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

    register_plugins(variant)
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
    _check_render_arguments(body, normalize, spp, time_samples)
    if brdf is None or isinstance(brdf, str):
        brdf = default_brdf(body.name, brdf)
    rng = np.random.default_rng(0 if rng is None else rng)

    cam = scene.camera
    proj = cam if projection is None else projection
    kind = _sensor_kind(proj, sensor)
    variant = current_variant(variant)
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
    if kind == "projection":
        entry.scene.sensors()[0].set_table(ab)
    inv_r2 = _place_body_and_sun(entry.params, body, sin_r)
    acc, seeds = _render_exposure(entry, kind, proj, R_t, basis, u, (x0, y0, w, h), rng)
    value = acc * (inv_r2 / len(dt))  # time-averaged film value at r_sun, W m^-2 sr^-1 (SRF-weighted)

    electrons, raw_total = _electrons(value, omega_sr, cam, body, normalize)
    total = float(electrons.sum())
    centre = proj.project(R_mid @ u)
    photocentre = _photocentre(electrons, total, x0, y0, centre)
    return ResolvedBodyImage(
        x0=x0, y0=y0, electrons=electrons, photocentre_xy=photocentre,
        centre_of_figure_xy=(float(centre[0]), float(centre[1])), radius_px=float(radius_px),
        electrons_total=total, electrons_raw_total=raw_total, variant=variant, spp=entry.spp,
        time_samples=int(time_samples), brdf=brdf, normalize=normalize, seeds=tuple(seeds),
        sensor=kind,
    )


def _check_render_arguments(body, normalize, spp, time_samples) -> None:
    """One line naming a bad argument of :func:`render_resolved_body`."""
    if normalize not in ("phase_law", "none"):
        raise ConfigValueError("mitsuba.normalize", normalize, "one of: phase_law, none")
    if not (isinstance(spp, (int, np.integer)) and spp >= 1):
        raise ConfigValueError("mitsuba.spp", spp, "an integer >= 1")
    if not (isinstance(time_samples, (int, np.integer)) and time_samples >= 1):
        raise ConfigValueError("mitsuba.time_samples", time_samples, "an integer >= 1")
    if not (body.distance_km > body.radius_km > 0):
        raise ConfigValueError("body.distance_km", body.distance_km, f"> radius_km = {body.radius_km}")


def _place_body_and_sun(params, body, sin_r: float) -> float:
    """Set the body (a sphere of radius ``sin_r`` at the origin: the world unit is the
    observer-body distance) and the Sun's direction in the scene; returns the 1/r^2 factor of
    the Sun's irradiance from 1 AU. The emitter keeps its 1 AU spectrum (no per-frame spectral
    update, no recompilation); the rendering is linear in the irradiance, so the factor is
    applied to the film values."""
    _set(params, "body.to_world", np.diag([sin_r, sin_r, sin_r, 1.0]))
    # Sun: light travels from the Sun to the body; 1/r^2 from 1 AU
    body_pos = np.asarray(body.position_km, dtype=float)
    sun_vec = body_pos - np.asarray(body.sun_position_km, dtype=float)
    r_sun_km = float(np.linalg.norm(sun_vec))
    _set(params, "sun.to_world", _frame_z(sun_vec))
    params.update()
    return (AU_KM / r_sun_km) ** 2


def _render_exposure(entry, kind: str, proj, R_t, basis, u, window, rng):
    """Mitsuba's film of the crop ``window`` = (x0, y0, w, h) summed over the exposure's
    attitudes ``R_t`` (one render per instant, each with a seed drawn from ``rng``); returns
    (sum, shape (h, w); the seeds)."""
    # Mitsuba only when a body is ray-traced: import skynav.renderer loads neither Mitsuba nor Dr.Jit
    import mitsuba as mi

    x0, y0, w, h = window
    params = entry.params
    mi_sensor = entry.scene.sensors()[0]
    acc = np.zeros((h, w))
    seeds = []
    for k in range(len(R_t)):
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
    return acc, seeds


def _photocentre(electrons, total: float, x0: int, y0: int, centre) -> tuple:
    """The first moment of a crop's electrons in image px (the centre of figure when it is dark)."""
    if total > 0:
        h, w = electrons.shape
        ys = np.arange(y0, y0 + h, dtype=float)
        xs = np.arange(x0, x0 + w, dtype=float)
        return (float(electrons.sum(0) @ xs / total), float(electrons.sum(1) @ ys / total))
    return (float(centre[0]), float(centre[1]))


def _electrons(value, omega_sr, cam, body, normalize: str):
    """Electrons over the exposure of the crop's film values ``value`` (W m^-2 sr^-1, weighted
    by the camera's response) through pixels of solid angle ``omega_sr``, counted as photons at
    :data:`LAMBDA_REF_NM`; with ``normalize="phase_law"`` scaled to the body's phase-law
    electrons. Returns (electrons, their total before the scaling)."""
    e_per_s = value * omega_sr * (cam.aperture_area_m2 * LAMBDA_REF_NM * 1e-9 / (_H_J_S * _C_M_S))
    electrons = e_per_s * cam.exposure_s
    raw_total = float(electrons.sum())
    if normalize == "phase_law":
        target = float(Radiometry.for_camera(cam).body_electrons_per_s(body.name, body.v_mag)) * cam.exposure_s
        if raw_total > 0 and math.isfinite(target):
            electrons = electrons * (target / raw_total)
        else:
            electrons = np.zeros_like(electrons)
    return electrons, raw_total
