"""Reading configuration mappings (parsed YAML) into scene-model objects, with clear errors.

Every error names the offending key with its dotted path and what is allowed, e.g.
``camera.exposure_s = -1 is not allowed; expected > 0 (seconds)``. Angles are degrees in files
(``*_deg`` keys) and radians in code.
"""

from __future__ import annotations

import dataclasses
import math
import os
import warnings
from dataclasses import dataclass, field

import numpy as np

from skynav.infra.errors import ConfigValueError, SkynavWarning

from .camera import MOVED_CAMERA_KEYS, Camera, SensorParams, paper_camera
from .constants import C_KM_S, SECONDS_PER_DAY
from .distortion import BrownConrady
from .ephemeris_jpl import BODIES
from .errors import MovedKeyError, SceneFileError, UnknownBodyError
from .psf import GaussianPSFModel
from .psf_measured import psf_from_dict
from .mission_files import resolve_mission_sources
from .scene import RESOLVED_THRESHOLD_PX
from .timescales import to_time
from .visibility import VisibilityCriteria

CAMERA_PRESETS = {"paper": paper_camera}

#: Longest wavelength of a camera's response table, nm (far infrared: no optical camera reaches it;
#: the radiometry integrates the band on a 0.25 nm grid, which a wider band would make unbounded).
MAX_WAVELENGTH_NM = 1e5
#: Largest Brown-Conrady coefficient in magnitude (real lenses stay below 1; a larger one is warned
#: of): beyond, the distorted coordinates of the frame's corners overflow.
MAX_DISTORTION = 1e3
#: Shortest, nm (far ultraviolet, the PSF models' own lower bound): a tinier positive wavelength
#: overflows the Planck spectra of the radiometry (exp(hc / lambda k T)).
MIN_WAVELENGTH_NM = 100.0


#: Smallest magnitude of a non-zero number in a configuration: no quantity of a scene is smaller
#: than this and not zero, and a smaller one (a subnormal such as 5e-324) overflows its reciprocal
#: downstream (a rate of 5e-324 e-/s made the sensor's sampler spin).
MIN_MAGNITUDE = 1e-300


def _number(value, key, *, allowed="a finite number", integer=False):
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ConfigValueError(key, value, allowed)
    if value != 0 and abs(value) < MIN_MAGNITUDE:
        raise ConfigValueError(key, value, f"{allowed}, 0 or of magnitude at least {MIN_MAGNITUDE:g}")
    if integer:
        if int(value) != value:
            raise ConfigValueError(key, value, "an integer")
        return int(value)
    return float(value)


def _vector(value, key, n=3):
    if not isinstance(value, (list, tuple)) or len(value) != n:
        raise ConfigValueError(key, value, f"a list of {n} numbers")
    return np.array([_number(v, f"{key}[{i}]") for i, v in enumerate(value)])


def _mapping(value, key):
    if not isinstance(value, dict):
        raise ConfigValueError(key, value, "a mapping of keys to values")
    return value


def _check_keys(d: dict, key: str, allowed):
    for k in d:
        if k not in allowed:
            where = f"{key}.{k}" if key else str(k)
            raise ConfigValueError(where, d[k], "no such key; allowed keys: " + ", ".join(sorted(allowed)))


_SENSOR_KEYS = {f.name for f in dataclasses.fields(SensorParams)}
_DIST_KEYS = {f.name for f in dataclasses.fields(BrownConrady)}
_CAMERA_KEYS = {
    "preset", "width", "height", "fov_deg", "focal_length_mm", "pixel_pitch_um", "pixel_pitch_y_um", "cx", "cy",
    "f_number", "exposure_s", "defocus_sigma_px", "psf", "distortion", "response", "sensor", "K", "bit_depth",
}


def camera_from_mapping(d: dict, key: str = "camera") -> Camera:
    """A :class:`Camera` from a mapping (a YAML ``camera:`` section or ``Camera.to_dict()``).

    ``preset: paper`` starts from :func:`paper_camera`; other keys override it. Either
    ``fov_deg`` (horizontal, edge to edge) or ``focal_length_mm`` sets the focal length;
    ``pixel_pitch_y_um`` makes the pixels rectangular (``fy != fx``). The keys that left the
    camera (``limiting_v_mag``, ``sun_exclusion_deg``, ``cosmic_rays_per_frame``) raise
    :class:`~skynav.scenes.errors.MovedKeyError` naming their new place.
    """
    d = _mapping(d if d is not None else {}, key)
    for k in d:
        if k in MOVED_CAMERA_KEYS:
            raise MovedKeyError(f"{key}.{k}", d[k], MOVED_CAMERA_KEYS[k])
    _check_keys(d, key, _CAMERA_KEYS)
    preset = d.get("preset", "paper" if "width" not in d else None)
    if preset is not None and (not isinstance(preset, str) or preset not in CAMERA_PRESETS):
        raise ConfigValueError(f"{key}.preset", preset, "one of: " + ", ".join(CAMERA_PRESETS))
    base = CAMERA_PRESETS[preset]() if preset else None
    kw = {}
    for name in ("width", "height"):
        if name in d:
            kw[name] = _number(d[name], f"{key}.{name}", allowed="a positive integer", integer=True)
    for name in ("focal_length_mm", "pixel_pitch_um", "f_number", "exposure_s", "defocus_sigma_px"):
        if name in d:
            kw[name] = _number(d[name], f"{key}.{name}")
    for name in ("cx", "cy", "pixel_pitch_y_um"):
        if name in d and d[name] is not None:
            kw[name] = _number(d[name], f"{key}.{name}")
    if "psf" in d:
        kw["psf"] = psf_from_dict(d["psf"], f"{key}.psf")
        if isinstance(kw["psf"], GaussianPSFModel) and "defocus_sigma_px" in kw and kw["defocus_sigma_px"] != kw["psf"].sigma_px:
            raise ConfigValueError(f"{key}.defocus_sigma_px", kw["defocus_sigma_px"],
                                   f"absent or equal to {key}.psf.sigma_px ({kw['psf'].sigma_px}): it is the same Gaussian")
    if "distortion" in d:
        dd = _mapping(d["distortion"], f"{key}.distortion")
        _check_keys(dd, f"{key}.distortion", _DIST_KEYS)
        coeffs = {k: _number(v, f"{key}.distortion.{k}") for k, v in dd.items()}
        for k, v in coeffs.items():   # |k| > 10 is warned of below; far beyond, the projection overflows
            if abs(v) > MAX_DISTORTION:
                raise ConfigValueError(f"{key}.distortion.{k}", v, f"a coefficient in [-{MAX_DISTORTION:g}, "
                                                                    f"{MAX_DISTORTION:g}] (real lenses: |{k}| < 1)")
        kw["distortion"] = BrownConrady(**coeffs)
    if "response" in d:
        kw["response_wavelengths_nm"], kw["response_qe_t"] = _response(d["response"], f"{key}.response")
    sensor = _sensor(d, key, base.sensor if base is not None else SensorParams())
    if sensor is not None:
        kw["sensor"] = sensor
    if "fov_deg" in d:
        fov = _number(d["fov_deg"], f"{key}.fov_deg")
        if not 0 < fov < 180:
            raise ConfigValueError(f"{key}.fov_deg", fov, "in (0, 180)")
        width = kw.get("width", base.width if base else None)
        pitch = kw.get("pixel_pitch_um", base.pixel_pitch_um if base else None)
        if width is None or pitch is None:
            raise ConfigValueError(f"{key}.fov_deg", fov, "together with width and pixel_pitch_um (or a preset)")
        kw["focal_length_mm"] = 0.5 * width * pitch * 1e-3 / math.tan(math.radians(fov) / 2)
    if base is None:
        missing = [k for k in ("width", "height", "focal_length_mm", "pixel_pitch_um") if k not in kw]
        if missing:
            raise ConfigValueError(f"{key}.{missing[0]}", None, "a value (or `preset: paper`)")
    _check_camera_limits(kw, key)
    camera = base.replace(**kw) if base is not None else Camera(**kw)
    if "K" in d:  # a derived copy (Camera.to_dict writes it): accepted only when it agrees
        _check_K(d["K"], camera, key)
    _warn_camera(camera, key)
    return camera


def _response(rd, key: str) -> tuple:
    """``(wavelengths_nm, qe_t)`` of a camera's ``response`` mapping (``key`` names it)."""
    rd = _mapping(rd, key)
    _check_keys(rd, key, {"wavelengths_nm", "qe_t"})
    wl = rd.get("wavelengths_nm")
    qe = rd.get("qe_t")
    if not isinstance(wl, list) or not isinstance(qe, list) or len(wl) != len(qe) or len(wl) < 2:
        raise ConfigValueError(key, "...", "wavelengths_nm and qe_t lists of equal length >= 2")
    wl = [_number(v, f"{key}.wavelengths_nm[{i}]") for i, v in enumerate(wl)]
    qe = [_number(v, f"{key}.qe_t[{i}]") for i, v in enumerate(qe)]
    if any(b <= a for a, b in zip(wl, wl[1:])):
        raise ConfigValueError(f"{key}.wavelengths_nm", wl[:3], "strictly increasing wavelengths")
    if not (MIN_WAVELENGTH_NM <= wl[0] and wl[-1] <= MAX_WAVELENGTH_NM):
        raise ConfigValueError(f"{key}.wavelengths_nm", [wl[0], wl[-1]],
                               f"wavelengths in [{MIN_WAVELENGTH_NM:g}, {MAX_WAVELENGTH_NM:g}] nm")
    if any(not 0 <= v <= 1 for v in qe):
        raise ConfigValueError(f"{key}.qe_t", qe[:3], "values in [0, 1]")
    return tuple(wl), tuple(qe)


def _sensor(d: dict, key: str, base_sensor: SensorParams):
    """The camera's :class:`SensorParams` from its ``sensor`` mapping (and the shorthand
    ``bit_depth``) over ``base_sensor``; None where neither is given."""
    sensor_d = dict(_mapping(d.get("sensor", {}), f"{key}.sensor"))
    if "bit_depth" in d:
        sensor_d.setdefault("bit_depth", d["bit_depth"])
    if not sensor_d:
        return None
    _check_keys(sensor_d, f"{key}.sensor", _SENSOR_KEYS)
    skw = {}
    for k, v in sensor_d.items():
        if k == "blooming":
            if not isinstance(v, bool):
                raise ConfigValueError(f"{key}.sensor.blooming", v, "true or false")
            skw[k] = v
        elif k in ("bit_depth", "pattern_seed"):
            skw[k] = _number(v, f"{key}.sensor.{k}", allowed="an integer", integer=True)
            if k == "bit_depth" and not 1 <= skw[k] <= 16:
                raise ConfigValueError(f"{key}.sensor.bit_depth", v, "an integer in 1..16")
            if k == "pattern_seed" and not 0 <= skw[k] <= 2**63 - 1:
                raise ConfigValueError(f"{key}.sensor.pattern_seed", v, "an integer in 0..2**63-1")
        else:
            skw[k] = _number(v, f"{key}.sensor.{k}")
    try:
        return dataclasses.replace(base_sensor, **skw)
    except ConfigValueError as exc:   # SensorParams names its own keys (sensor.*): the file's are under key
        raise ConfigValueError(f"{key}.{exc.key}", exc.value, exc.allowed) from None


def _check_K(K, camera: Camera, key: str) -> None:
    """Refuse a ``K`` that is not the one the other camera keys give (K is never read)."""
    allowed = (f"no K (it is derived: give fov_deg or focal_length_mm, pixel_pitch_um, cx and cy), or exactly "
               f"the derived {np.round(camera.K, 6).tolist()}")
    try:
        arr = np.asarray(K, dtype=float)
    except (TypeError, ValueError):
        raise ConfigValueError(f"{key}.K", K, allowed) from None
    if arr.shape != (3, 3) or not np.allclose(arr, camera.K, rtol=1e-9, atol=1e-9):
        raise ConfigValueError(f"{key}.K", K, allowed)


#: Bytes a rendered pixel needs at the peak of a render (float64 work arrays, EXR planes, DN).
BYTES_PER_PIXEL = 64


def _physical_memory_bytes() -> int:
    try:
        return int(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES"))
    except (ValueError, OSError, AttributeError):  # pragma: no cover - not POSIX
        return 16 << 30


def _check_camera_limits(kw: dict, key: str) -> None:
    """Refuse physically impossible camera values (one line naming the key the user wrote).

    The lower bounds of the lengths and the f-number are physical, not only positive: a tiny
    positive value (1e-308) passes ``> 0`` but overflows what is derived from it (the focal
    length in pixels, the aperture's area, the diffraction pattern's sampling), so it is refused
    here rather than failing downstream."""
    limits = {  # key: (low, high inclusive, what is allowed); the low bound of the first four included, of the rest excluded
        "focal_length_mm": (1e-3, 1e5, "in [0.001, 1e5] mm (a 100 m focal length is already beyond any camera; "
                                       "1 um is below any lens)"),
        "pixel_pitch_um": (1e-3, 1e3, "in [0.001, 1000] um"),
        "pixel_pitch_y_um": (1e-3, 1e3, "in [0.001, 1000] um"),
        "f_number": (0.1, 1e3, "in [0.1, 1000] (0.5 is the least a lens in air reaches)"),
        "exposure_s": (0.0, SECONDS_PER_DAY, "in (0, 86400] s (one day)"),
        "defocus_sigma_px": (-1e-300, 1e3, "in [0, 1000] px"),
    }
    closed = ("focal_length_mm", "pixel_pitch_um", "pixel_pitch_y_um", "f_number")
    for name, (lo, hi, allowed) in limits.items():
        v = kw.get(name)
        if v is not None and not ((lo <= v if name in closed else lo < v) and v <= hi):
            raise ConfigValueError(f"{key}.{name}", v, allowed)
    for name in ("width", "height"):
        if name in kw and not 1 <= kw[name] <= 100_000:
            raise ConfigValueError(f"{key}.{name}", kw[name], "an integer in 1..100000 px")
    w, h = kw.get("width"), kw.get("height")
    if w is not None and h is not None:
        need = w * h * BYTES_PER_PIXEL
        have = _physical_memory_bytes()
        if need > have // 2:
            raise ConfigValueError(f"{key}.width x {key}.height", f"{w} x {h}",
                                   f"a frame that fits in memory: about {need / 2**30:.0f} GiB needed, "
                                   f"{have / 2**30:.0f} GiB on this machine")
    sensor = kw.get("sensor")
    if sensor is not None:
        if sensor.full_well_e < 1.0:
            raise ConfigValueError(f"{key}.sensor.full_well_e", sensor.full_well_e, ">= 1 electron")
        for name in ("read_noise_e", "reset_noise_e", "dark_current_e_per_s", "dsnu_e_per_s", "gain_dn_per_e",
                     "full_well_e", "offset_dn"):
            v = getattr(sensor, name, None)
            if v is not None and v > 1e9:
                raise ConfigValueError(f"{key}.sensor.{name}", v, "<= 1e9")
        if sensor.prnu_fraction > 1.0:   # a fraction of the signal: beyond 1 the gain map goes negative
            raise ConfigValueError(f"{key}.sensor.prnu_fraction", sensor.prnu_fraction, "in [0, 1]")


def _warn_camera(camera: Camera, key: str) -> None:
    """One warning per absurd but possible camera value (the command line prints one line each)."""
    fov = math.degrees(camera.fov_x_rad)
    if fov > 120:
        warnings.warn(f"{key}: a {fov:.0f} deg horizontal field is far wider than a pinhole camera can image "
                      f"without severe stretching at the edges", SkynavWarning, stacklevel=3)
    for name in ("k1", "k2", "k3", "p1", "p2"):
        v = getattr(camera.distortion, name, 0.0) or 0.0
        if abs(v) > 10:
            warnings.warn(f"{key}.distortion.{name} = {v:g} is far outside real lenses (|{name}| < 1)",
                          SkynavWarning, stacklevel=3)


@dataclass(frozen=True, kw_only=True)
class AttitudeSpec:
    """How to point the camera: at a body, at RA/Dec/twist, or by a quaternion.

    ``point_at`` a body (or ``auto``: the brightest visible planet), else ``q_cam_icrs``, else
    ``ra_rad``/``dec_rad``/``twist_rad`` (:func:`skynav.scenes.scene.resolve_spec`). Scene files
    write the angles in degrees (``ra_deg``, ...; docs/conventions.md).

    Parameters
    ----------
    point_at : str or None
        A body name or ``auto``.
    ra_rad, dec_rad : float or None
        Boresight right ascension and declination, ICRS, rad.
    twist_rad : float
        Twist about the boresight, rad (:func:`~skynav.scenes.frames.radec_twist_to_dcm`).
    q_cam_icrs : tuple of float or None
        Scalar-first unit quaternion of ``R_cam_icrs`` (Andreis et al. (2023a), Eq. 14).
    angular_velocity_rad_s : tuple of float, shape (3,)
        Camera-frame angular velocity, rad/s (streaks over the exposure).

    Examples
    --------
    >>> from skynav.scenes import AttitudeSpec
    >>> AttitudeSpec(point_at="mars").twist_rad
    0.0
    """

    point_at: str | None = None
    ra_rad: float | None = None
    dec_rad: float | None = None
    twist_rad: float = 0.0
    q_cam_icrs: tuple | None = None
    angular_velocity_rad_s: tuple = (0.0, 0.0, 0.0)


@dataclass(frozen=True, kw_only=True)
class SceneSpec:
    """A scene as written in a file, before the sky is computed (see :func:`build_from_spec`).

    ``visibility`` is the file's ``visibility:`` section; ``catalog_limiting_v_mag`` (the star
    catalogue cut), ``resolved_threshold_px``, ``cosmic_rays_per_frame`` (mean hits per frame,
    for ``RenderOptions``), ``mitsuba_spp`` (for ``RenderOptions``) and ``seed`` come from its
    ``render:`` section (:data:`RENDER_KEYS`).

    Parameters
    ----------
    epoch_tdb_iso : str
        Mid-exposure epoch, ISO date in TDB.
    position_km, velocity_km_s : tuple of float, shape (3,), or None
        Observer state, barycentric ICRS (or relative to ``relative_to``), km and km/s.
    relative_to : str or None
        A body whose barycentric state is added to the observer's.
    attitude : AttitudeSpec
        How the camera points.
    camera : Camera
        The camera (default: :func:`~skynav.scenes.camera.paper_camera`).
    visibility : VisibilityCriteria
        The detection rule of the bodies' ``visible`` flag.
    catalog_limiting_v_mag : float
        Faintest catalogue star included, V mag.
    resolved_threshold_px : float
        Apparent diameter above which a body is ray-traced, px.
    cosmic_rays_per_frame : float
        Mean cosmic-ray hits per frame.
    mitsuba_spp : int
        Mitsuba samples per pixel of resolved bodies.
    seed : int
        Seed of the frame's noise and cosmic rays.
    data_files : tuple of dict
        The mission data files the scene read (``key``, ``name`` as given, ``sha256``), for the
        truth (:mod:`skynav.scenes.mission_files`).
    ephemeris : SpiceEphemeris or None
        The planets' ephemeris of ``ephemeris: {spk: FILE}``; None: DE421.

    Examples
    --------
    >>> from skynav.scenes import AttitudeSpec, SceneSpec, build_from_spec
    >>> spec = SceneSpec(epoch_tdb_iso="2027-02-01T00:00:00", position_km=(1.5e8, 0.0, 0.0),
    ...                  velocity_km_s=(0.0, 30.0, 0.0), attitude=AttitudeSpec(point_at="jupiter"))
    >>> scene = build_from_spec(spec)
    >>> next(b for b in scene.bodies if b.name == "jupiter").in_fov
    True
    """

    epoch_tdb_iso: str
    position_km: tuple | None = None
    velocity_km_s: tuple | None = None
    relative_to: str | None = None
    attitude: AttitudeSpec = field(default_factory=AttitudeSpec)
    camera: Camera = field(default_factory=paper_camera)
    visibility: VisibilityCriteria = field(default_factory=VisibilityCriteria)
    catalog_limiting_v_mag: float = 9.0
    resolved_threshold_px: float = RESOLVED_THRESHOLD_PX
    cosmic_rays_per_frame: float = 1.0
    mitsuba_spp: int = 16
    seed: int = 0
    data_files: tuple = ()
    ephemeris: object = None


_SCENE_KEYS = {"epoch", "observer", "attitude", "camera", "visibility", "render", "ephemeris"}

#: The ``render:`` keys of a scene file and of a dataset recipe (one table for both): key ->
#: (default, meaning with unit and allowed values). The defaults are the scene model's and the
#: renderer's (``RenderOptions``: 1 cosmic ray per frame as in Andreis et al. (2024), 16 Mitsuba samples).
RENDER_KEYS = {
    "catalog_limiting_v_mag": (9.0, "faintest catalogue star rendered, V mag, in [-2, 14] (Hipparcos is "
                                    "complete to about V = 8)"),
    "cosmic_rays_per_frame": (1.0, "mean cosmic-ray hits per frame (Poisson), >= 0 and <= 0.01 per pixel; "
                                   "0 turns them off"),
    "resolved_threshold_px": (RESOLVED_THRESHOLD_PX, "apparent diameter above which a body is ray-traced by "
                                                     "Mitsuba instead of drawn as a point, px, > 0"),
    "mitsuba_spp": (16, "Mitsuba samples per pixel for resolved bodies, an integer >= 1"),
    "seed": (0, "seed of the frame's noise and cosmic rays, a non-negative integer"),
}
_MOVED_RENDER_KEYS = {"star_mag_limit": "render.catalog_limiting_v_mag"}


def render_settings_from_mapping(d, camera: Camera, *, key: str = "render", fill: bool = True,
                                 keys=tuple(RENDER_KEYS)) -> dict:
    """Validate a ``render:`` mapping (scene files and dataset recipes share it, :data:`RENDER_KEYS`).

    Parameters
    ----------
    d : dict or None
        The mapping as written.
    camera : Camera
        The frame's camera (the cosmic-ray limit is per pixel).
    key : str
        Dotted prefix for messages (``render``, ``scenes[2].render``).
    fill : bool
        True: every key, defaults filled; False: only the keys given.
    keys : sequence of str
        The keys allowed in this context (a dataset recipe leaves out ``seed``).

    Returns
    -------
    dict
        ``{key: value}`` with floats, and ints for ``mitsuba_spp`` and ``seed``.

    Raises
    ------
    ConfigValueError
        An unknown key (naming the allowed ones), a value out of range; ``MovedKeyError`` for
        ``star_mag_limit``.
    """
    rd = _mapping(d if d is not None else {}, key)
    for k in rd:
        if k in _MOVED_RENDER_KEYS:
            raise MovedKeyError(f"{key}.{k}", rd[k], _MOVED_RENDER_KEYS[k])
    _check_keys(rd, key, keys)
    out = {}
    for name, (default, _) in RENDER_KEYS.items():
        if name not in keys or (name not in rd and not fill):
            continue
        where = f"{key}.{name}"
        value = rd.get(name, default)
        if name == "catalog_limiting_v_mag":
            value = _number(value, where)
            if not -2 <= value <= 14:
                raise ConfigValueError(where, value, "in [-2, 14] (Hipparcos is complete to about V = 8)")
        elif name == "cosmic_rays_per_frame":
            value = check_cosmic_rays(_number(value, where), camera, where)
        elif name == "resolved_threshold_px":
            value = _number(value, where)
            if value <= 0:
                raise ConfigValueError(where, value, "> 0")
        elif name == "mitsuba_spp":
            value = _number(value, where, allowed="an integer >= 1", integer=True)
            if not 1 <= value <= 65536:
                raise ConfigValueError(where, value, "an integer in 1..65536")
        else:  # seed
            value = _number(value, where, allowed="a non-negative integer", integer=True)
            if value < 0:
                raise ConfigValueError(where, value, "a non-negative integer")
        out[name] = value
    return out


#: Farthest observer from the barycentre (or its ``relative_to`` body), km: ~200 AU (Voyager 1 is at
#: ~165 AU). Beyond ~1e11 km the light-time iteration (1e-10 s tolerance) meets float64 resolution.
MAX_DISTANCE_KM = 3e10


def check_cosmic_rays(rays: float, camera: Camera, key: str) -> float:
    """Refuse a cosmic-ray rate the frame cannot hold (``<= 0.01`` hits per pixel).

    Each hit deposits a track of several pixels; beyond one hit per 100 pixels the frame is
    noise and the rasteriser's time grows without bound (1e7 hits never finished).

    Raises
    ------
    ConfigValueError
    """
    limit = 0.01 * camera.width * camera.height
    if not 0 <= rays <= limit:
        raise ConfigValueError(key, rays, f"in [0, {limit:g}] (0.01 per pixel of the {camera.width} x "
                                          f"{camera.height} frame)")
    return rays


def visibility_from_mapping(d, key: str = "visibility") -> VisibilityCriteria:
    """A :class:`~skynav.scenes.visibility.VisibilityCriteria` from a ``visibility:`` mapping
    (``limiting_v_mag``, ``sun_exclusion_deg``; missing keys take the defaults, V 7 and 20 deg)."""
    d = _mapping(d if d is not None else {}, key)
    _check_keys(d, key, {"limiting_v_mag", "sun_exclusion_deg"})
    kw = {}
    if "limiting_v_mag" in d:
        kw["limiting_v_mag"] = _number(d["limiting_v_mag"], f"{key}.limiting_v_mag")
    if "sun_exclusion_deg" in d:
        deg = _number(d["sun_exclusion_deg"], f"{key}.sun_exclusion_deg")
        if not 0 <= deg < 180:
            raise ConfigValueError(f"{key}.sun_exclusion_deg", deg, "in [0, 180)")
        kw["sun_exclusion_rad"] = math.radians(deg)
    return VisibilityCriteria(**kw)


def scene_spec_from_mapping(d) -> SceneSpec:
    """Validate a scene mapping (parsed YAML) into a :class:`SceneSpec`."""
    if not isinstance(d, dict):
        raise SceneFileError("a scene file must be a mapping with keys: " + ", ".join(sorted(_SCENE_KEYS)))
    _check_keys(d, "", _SCENE_KEYS)
    d, mission = resolve_mission_sources(d)  # oem/aem, spice kernels, ephemeris: {spk}, UTC epochs
    if "epoch" not in d:
        raise ConfigValueError("epoch", None, "an ISO date in TDB, e.g. 2027-03-15T00:00:00")
    try:
        epoch = to_time(str(d["epoch"])).tdb
        epoch.precision = 9  # the date as given, to the ns: milliseconds at least, trailing zeros cut
        head, _, frac = epoch.isot.partition(".")
        iso = f"{head}.{frac.rstrip('0').ljust(3, '0')}"
    except Exception:
        raise ConfigValueError("epoch", d["epoch"], "an ISO date in TDB, e.g. 2027-03-15T00:00:00") from None
    obs = _mapping(d.get("observer", {}), "observer")
    _check_keys(obs, "observer", {"position_km", "velocity_km_s", "relative_to"})
    if "position_km" not in obs or "velocity_km_s" not in obs:
        raise ConfigValueError("observer", obs, "position_km and velocity_km_s (barycentric ICRS, or relative_to a body)")
    rel = obs.get("relative_to")
    if rel is not None and rel not in BODIES:
        raise UnknownBodyError(str(rel), BODIES)
    att = _mapping(d.get("attitude", {"point_at": "auto"}), "attitude")
    _check_keys(att, "attitude", {"point_at", "ra_deg", "dec_deg", "twist_deg", "q_cam_icrs", "angular_velocity_deg_s"})
    modes = [k for k in ("point_at", "ra_deg", "q_cam_icrs") if k in att]
    if len(modes) != 1:
        raise ConfigValueError("attitude", sorted(att), "exactly one of point_at, ra_deg+dec_deg, q_cam_icrs")
    point_at = att.get("point_at")
    if "point_at" in att and not isinstance(point_at, str):
        raise ConfigValueError("attitude.point_at", point_at, "a body name or auto")
    if point_at == "sun":
        raise ConfigValueError("attitude.point_at", point_at, "a planet, the Moon or auto; a navigation camera "
                               "is never pointed at the Sun (it is outside every scene's sun exclusion)")
    if point_at is not None and point_at != "auto" and point_at not in BODIES:
        raise UnknownBodyError(str(point_at), ("auto",) + BODIES)
    ra = dec = None
    if "ra_deg" in att:
        ra = math.radians(_number(att["ra_deg"], "attitude.ra_deg"))
        decd = _number(att.get("dec_deg"), "attitude.dec_deg")
        if not -90 <= decd <= 90:
            raise ConfigValueError("attitude.dec_deg", decd, "in [-90, 90]")
        dec = math.radians(decd)
    q = None
    if "q_cam_icrs" in att:
        qv = _vector(att["q_cam_icrs"], "attitude.q_cam_icrs", 4)
        if np.linalg.norm(qv) < 1e-12:
            raise ConfigValueError("attitude.q_cam_icrs", att["q_cam_icrs"], "a non-zero quaternion (scalar first)")
        q = tuple(qv / np.linalg.norm(qv))
    w_deg = _vector(att.get("angular_velocity_deg_s", [0, 0, 0]), "attitude.angular_velocity_deg_s")
    if np.linalg.norm(w_deg) > 1e7:
        raise ConfigValueError("attitude.angular_velocity_deg_s", att["angular_velocity_deg_s"], "a rate below 1e7 deg/s")
    if np.linalg.norm(w_deg) > 360:
        warnings.warn(f"attitude.angular_velocity_deg_s: {np.linalg.norm(w_deg):g} deg/s is more than one turn per "
                      f"second; the stars are long streaks", SkynavWarning, stacklevel=2)
    w = np.radians(w_deg)
    attitude = AttitudeSpec(point_at=point_at, ra_rad=ra, dec_rad=dec, q_cam_icrs=q,
                            twist_rad=math.radians(_number(att.get("twist_deg", 0.0), "attitude.twist_deg")),
                            angular_velocity_rad_s=tuple(float(x) for x in w))
    camera = camera_from_mapping(d.get("camera", {"preset": "paper"}))
    visibility = visibility_from_mapping(d.get("visibility", {}))
    render = render_settings_from_mapping(d.get("render", {}), camera)
    pos = _vector(obs["position_km"], "observer.position_km")
    if np.linalg.norm(pos) > MAX_DISTANCE_KM:
        raise ConfigValueError("observer.position_km", obs["position_km"],
                               f"within {MAX_DISTANCE_KM:.0e} km (about 200 AU) of the "
                               f"{'barycentre' if rel is None else rel}")
    vel = _vector(obs["velocity_km_s"], "observer.velocity_km_s")
    if np.linalg.norm(vel) >= 0.1 * C_KM_S:
        raise ConfigValueError("observer.velocity_km_s", obs["velocity_km_s"],
                               f"a speed below {0.1 * C_KM_S:.0f} km/s (0.1 c; light is {C_KM_S:.0f} km/s)")
    return SceneSpec(
        epoch_tdb_iso=iso,
        position_km=tuple(pos),
        velocity_km_s=tuple(vel),
        relative_to=rel,
        attitude=attitude,
        camera=camera,
        visibility=visibility,
        data_files=mission.records,
        ephemeris=mission.ephemeris,
        **render,
    )
