"""The camera: pinhole intrinsics, optics, sensor parameters, and the lens distortion it carries.

Optics and sensor only: what counts as *visible* (magnitude limit, Sun exclusion) is the
mission's :class:`~skynav.scenes.visibility.VisibilityCriteria`, and the cosmic-ray rate is a
render option (``RenderOptions.cosmic_rays_per_frame``). Pixels may be rectangular
(``pixel_pitch_y_um``): ``K = [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]`` with
``fx = focal_length_mm / pixel_pitch_mm`` and ``fy = focal_length_mm / pixel_pitch_y_mm``.
This module imports no reader: :meth:`Camera.from_dict` inverts :meth:`Camera.to_dict`, and the
YAML reader (:mod:`skynav.scenes.config`) builds on it, not the reverse.

Pixel convention (docs/conventions.md): ``(x, y)`` with x along columns and y along rows; the
CENTRE of the top-left pixel is ``(0.0, 0.0)``; a centred principal point is
``cx = (W - 1) / 2``, ``cy = (H - 1) / 2``. Projection ``[x, y, 1]^T ~ K v_cam``, with the lens
distortion (:class:`~skynav.scenes.distortion.BrownConrady`) applied to the normalised
coordinates between the pinhole and ``K``.

Everything here is a frozen, hashable value object (tuples, not lists) so cameras can be
dictionary keys, pickled to worker processes, and compared.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np

from skynav.infra.errors import ConfigValueError

from .distortion import BrownConrady
from .errors import MovedKeyError
from .psf import GaussianPSFModel
from .psf_measured import psf_from_dict


def _check(cond: bool, key: str, value, allowed: str) -> None:
    if not cond:
        raise ConfigValueError(key, value, allowed)


def default_response_curve():
    """A plausible CMOS QE x lens-transmission curve, 350-1050 nm every 10 nm.

    A front-illuminated CMOS shape (rise from the UV, peak near 550-600 nm, NIR tail) scaled so
    that its average over 400-900 nm equals the ``Qe x Tlens = 0.49`` of Andreis et al. (2024), Table 4.
    Returns (wavelengths_nm, qe_t) as tuples.
    """
    wl = np.arange(350.0, 1051.0, 10.0)
    rise = 1.0 / (1.0 + np.exp(-(wl - 420.0) / 22.0))
    fall = 1.0 / (1.0 + np.exp((wl - 800.0) / 70.0))
    shape = rise * fall
    band = (wl >= 400.0) & (wl <= 900.0)
    # mean over the band with the trapezoid rule on the uniform 10 nm grid
    mean = np.trapezoid(shape[band], wl[band]) / (900.0 - 400.0)
    qe_t = 0.49 * shape / mean
    return tuple(float(w) for w in wl), tuple(round(float(v), 6) for v in qe_t)


@dataclass(frozen=True, kw_only=True)
class SensorParams:
    """Detector parameters (EMVA 1288 linear model, extended). Units are in the names.

    ``gain_dn_per_e`` is the system gain K; ``offset_dn`` the dark offset; ``dsnu_e_per_s`` the
    pixel-to-pixel standard deviation of the dark current; ``prnu_fraction`` the relative
    standard deviation of pixel response; ``reset_noise_e`` the kTC noise; the fixed patterns
    are drawn from ``pattern_seed`` so that one sensor keeps its pattern across frames.

    Parameters
    ----------
    bit_depth : int
        Bits of a digital count, 1..16 (the largest DN is ``2**bit_depth - 1``).
    gain_dn_per_e : float
        System gain K, DN/e-.
    offset_dn : float
        Dark offset, DN.
    full_well_e : float
        Full-well capacity, e-.
    read_noise_e : float
        Read noise (standard deviation), e-.
    reset_noise_e : float
        Reset (kTC) noise (standard deviation), e-.
    dark_current_e_per_s : float
        Mean dark current, e-/s.
    dsnu_e_per_s : float
        Dark signal non-uniformity: pixel-to-pixel standard deviation of the dark current, e-/s.
    prnu_fraction : float
        Photo-response non-uniformity: relative standard deviation of the pixels' response.
    blooming : bool
        Spill the charge above the full well into neighbouring pixels.
    pattern_seed : int
        Seed of the fixed patterns (DSNU, PRNU), the same for every frame of this sensor.

    References
    ----------
    EMVA Standard 1288 (release 4.0, 2021), the linear camera model.

    Examples
    --------
    >>> from skynav.scenes import SensorParams
    >>> s = SensorParams(bit_depth=12, gain_dn_per_e=4095 / 20000)
    >>> s.max_dn
    4095
    """

    bit_depth: int = 8
    gain_dn_per_e: float = 255.0 / 20000.0
    offset_dn: float = 2.0
    full_well_e: float = 20000.0
    read_noise_e: float = 8.0
    reset_noise_e: float = 3.0
    dark_current_e_per_s: float = 5.0
    dsnu_e_per_s: float = 1.0
    prnu_fraction: float = 0.01
    blooming: bool = False
    pattern_seed: int = 20240515

    def __post_init__(self):
        _check(isinstance(self.bit_depth, int) and 1 <= self.bit_depth <= 16, "sensor.bit_depth", self.bit_depth, "an integer in 1..16")
        _check(self.gain_dn_per_e > 0, "sensor.gain_dn_per_e", self.gain_dn_per_e, "> 0")
        _check(self.full_well_e > 0, "sensor.full_well_e", self.full_well_e, "> 0")
        for name in ("offset_dn", "read_noise_e", "reset_noise_e", "dark_current_e_per_s", "dsnu_e_per_s", "prnu_fraction"):
            v = getattr(self, name)
            _check(math.isfinite(v) and v >= 0, f"sensor.{name}", v, ">= 0")

    @property
    def max_dn(self) -> int:
        """Largest digital count, DN: ``2**bit_depth - 1``."""
        return (1 << self.bit_depth) - 1


@dataclass(frozen=True, kw_only=True)
class Camera:
    """A pinhole camera with optional distortion, its optics and its sensor.

    Parameters
    ----------
    width, height : int
        Image size, px.
    focal_length_mm : float
        Focal length, mm (also sets the aperture with ``f_number``).
    pixel_pitch_um : float
        Pixel pitch along x (columns), um; ``fx_px = focal_length_mm / pixel_pitch_mm``.
    pixel_pitch_y_um : float or None
        Pixel pitch along y (rows), um, for rectangular pixels (``fy_px != fx_px``); None:
        square pixels, ``fy_px == fx_px`` exactly.
    cx, cy : float or None
        Principal point, px (None: centred, ``(W-1)/2``, ``(H-1)/2``).
    f_number : float
        Aperture diameter is ``focal_length_mm / f_number``.
    exposure_s : float
        Exposure time, s.
    defocus_sigma_px : float
        Gaussian defocus PSF standard deviation, px (Andreis et al. (2024), Table 4: 0.5 px): the shorthand
        of ``psf=GaussianPSFModel(defocus_sigma_px)``, kept equal to ``psf.sigma_px`` while the
        PSF is a Gaussian.
    psf : PSF model or mapping, optional
        The optics' point-spread function (:mod:`skynav.scenes.psf`: ``gaussian``, ``airy``,
        ``optical``, ``tabulated``); None: the Gaussian of ``defocus_sigma_px``.
    distortion : BrownConrady
        Lens distortion.
    response_wavelengths_nm, response_qe_t : tuple of float
        Quantum efficiency x lens transmission (no unit), tabulated at wavelengths in nm.
    sensor : SensorParams
        The detector (EMVA 1288 parameters).

    Raises
    ------
    ConfigValueError
        A parameter out of its range (one line naming the key and what is allowed).

    Examples
    --------
    >>> from skynav.scenes import Camera
    >>> cam = Camera(width=64, height=48, focal_length_mm=40.0, pixel_pitch_um=10.0)
    >>> cam.fx_px, cam.cx, cam.cy
    (4000.0, 31.5, 23.5)
    >>> cam.project(np.array([[0.0, 0.0, 1.0], [0.001, 0.0, 1.0]]))
    array([[31.5, 23.5],
           [35.5, 23.5]])
    >>> round(float(np.degrees(cam.fov_x_rad)), 4)
    0.9167
    """

    width: int
    height: int
    focal_length_mm: float
    pixel_pitch_um: float
    pixel_pitch_y_um: float | None = None
    cx: float | None = None
    cy: float | None = None
    f_number: float = 2.2
    exposure_s: float = 0.4
    defocus_sigma_px: float = 0.5
    psf: object = None
    distortion: BrownConrady = field(default_factory=BrownConrady)
    response_wavelengths_nm: tuple = field(default_factory=lambda: default_response_curve()[0])
    response_qe_t: tuple = field(default_factory=lambda: default_response_curve()[1])
    sensor: SensorParams = field(default_factory=SensorParams)

    def __post_init__(self):
        _check(isinstance(self.width, int) and self.width > 0, "camera.width", self.width, "a positive integer")
        _check(isinstance(self.height, int) and self.height > 0, "camera.height", self.height, "a positive integer")
        _check(self.focal_length_mm > 0, "camera.focal_length_mm", self.focal_length_mm, "> 0")
        _check(self.pixel_pitch_um > 0, "camera.pixel_pitch_um", self.pixel_pitch_um, "> 0")
        _check(self.f_number > 0, "camera.f_number", self.f_number, "> 0")
        _check(self.exposure_s > 0, "camera.exposure_s", self.exposure_s, "> 0 (seconds)")
        _check(self.defocus_sigma_px >= 0, "camera.defocus_sigma_px", self.defocus_sigma_px, ">= 0")
        if self.psf is None:
            object.__setattr__(self, "psf", GaussianPSFModel(self.defocus_sigma_px))
        else:
            object.__setattr__(self, "psf", psf_from_dict(self.psf, "camera.psf"))
            if isinstance(self.psf, GaussianPSFModel):
                object.__setattr__(self, "defocus_sigma_px", self.psf.sigma_px)
        if self.pixel_pitch_y_um is not None:
            _check(self.pixel_pitch_y_um > 0, "camera.pixel_pitch_y_um", self.pixel_pitch_y_um, "> 0 (or absent: square pixels)")
        _check(len(self.response_wavelengths_nm) == len(self.response_qe_t) >= 2, "camera.response", len(self.response_qe_t), "matching wavelength and QE*T tables of >= 2 samples")
        if self.cx is None:
            object.__setattr__(self, "cx", (self.width - 1) / 2.0)
        if self.cy is None:
            object.__setattr__(self, "cy", (self.height - 1) / 2.0)
        for name in ("response_wavelengths_nm", "response_qe_t"):
            object.__setattr__(self, name, tuple(float(v) for v in getattr(self, name)))
        # (fx, fy) and (cx, cy) as arrays for project / back_project (not fields: derived)
        object.__setattr__(self, "_f_xy", np.array([self.fx_px, self.fy_px], dtype=float))
        object.__setattr__(self, "_c_xy", np.array([self.cx, self.cy], dtype=float))

    # ----------------------------------------------------------------- constructors
    @classmethod
    def from_fov(cls, *, fov_rad: float, width: int, height: int, pixel_pitch_um: float, **kw) -> "Camera":
        """Camera whose horizontal field of view (edge to edge of the sensor) is ``fov_rad``.

        Parameters
        ----------
        fov_rad : float
            Horizontal field of view, rad, in (0, pi).
        width, height : int
            Image size, px.
        pixel_pitch_um : float
            Pixel pitch, um (the focal length follows).
        **kw
            Any other field of :class:`Camera`.

        Returns
        -------
        Camera
            ``focal_length_mm = width * pitch / (2 tan(fov / 2))``.

        Examples
        --------
        >>> import math
        >>> from skynav.scenes import Camera
        >>> cam = Camera.from_fov(fov_rad=math.radians(20.0), width=256, height=256, pixel_pitch_um=55.1)
        >>> round(cam.focal_length_mm, 2), round(math.degrees(cam.fov_x_rad), 6)
        (40.0, 20.0)
        """
        _check(0 < fov_rad < math.pi, "camera.fov_deg", math.degrees(fov_rad), "in (0, 180)")
        focal_mm = 0.5 * width * pixel_pitch_um * 1e-3 / math.tan(0.5 * fov_rad)
        return cls(width=width, height=height, focal_length_mm=focal_mm, pixel_pitch_um=pixel_pitch_um, **kw)

    def replace(self, **changes) -> "Camera":
        """A copy with fields changed (``dataclasses.replace``, checked again).

        A changed size recentres cx, cy unless they are given (and keeps the pixel pitch, so
        the field of view changes with the size); a changed ``defocus_sigma_px`` without
        ``psf`` makes the PSF that Gaussian.

        Parameters
        ----------
        **changes
            Fields of :class:`Camera` and their new values.

        Returns
        -------
        Camera
            The new camera.
        """
        if "defocus_sigma_px" in changes and "psf" not in changes:
            changes["psf"] = None  # the shorthand: a Gaussian of that sigma
        if ("width" in changes or "height" in changes) and "cx" not in changes and "cy" not in changes:
            changes.setdefault("cx", None)
            changes.setdefault("cy", None)
        return dataclasses.replace(self, **changes)

    # ----------------------------------------------------------------- derived values
    @property
    def fx_px(self) -> float:
        """Focal length in pixels along x (columns), ``K[0, 0]``."""
        return self.focal_length_mm / (self.pixel_pitch_um * 1e-3)

    @property
    def fy_px(self) -> float:
        """Focal length in pixels along y (rows), ``K[1, 1]``; equal to :attr:`fx_px` for square
        pixels."""
        if self.pixel_pitch_y_um is None:
            return self.fx_px
        return self.focal_length_mm / (self.pixel_pitch_y_um * 1e-3)

    @property
    def focal_length_px(self) -> float:
        """Mean focal length in pixels, ``sqrt(fx_px * fy_px)``, for isotropic uses (angular
        sizes, sweep lengths); exactly ``fx_px`` for square pixels."""
        if self.pixel_pitch_y_um is None:
            return self.fx_px
        return math.sqrt(self.fx_px * self.fy_px)

    @property
    def K(self) -> np.ndarray:
        """Intrinsic matrix ``[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]``, shape (3, 3), px."""
        return np.array([[self.fx_px, 0.0, self.cx], [0.0, self.fy_px, self.cy], [0.0, 0.0, 1.0]])

    @property
    def fov_x_rad(self) -> float:
        """Horizontal field of view, edge to edge of the sensor (ignoring distortion), rad."""
        return 2.0 * math.atan(0.5 * self.width / self.fx_px)

    @property
    def fov_y_rad(self) -> float:
        """Vertical field of view, edge to edge of the sensor (ignoring distortion), rad."""
        return 2.0 * math.atan(0.5 * self.height / self.fy_px)

    @property
    def half_diagonal_fov_rad(self) -> float:
        """Largest angle from the boresight to a sensor corner (ignoring distortion), rad."""
        fx, fy = self.fx_px, self.fy_px
        dx = max(self.cx + 0.5, self.width - 0.5 - self.cx)
        dy = max(self.cy + 0.5, self.height - 0.5 - self.cy)
        # dy in x-pixel units; the ratio is exactly 1.0 for square pixels (same bits as before)
        return math.atan(math.hypot(dx, dy * (fx / fy)) / fx)

    @property
    def aperture_diameter_m(self) -> float:
        """Entrance pupil diameter, m: ``focal_length_mm / f_number``."""
        return self.focal_length_mm * 1e-3 / self.f_number

    @property
    def aperture_area_m2(self) -> float:
        """Entrance pupil area, m^2 (an unobstructed circle)."""
        return math.pi * (0.5 * self.aperture_diameter_m) ** 2

    @property
    def ifov_rad(self) -> float:
        """Largest angle subtended by one pixel at the principal point (along x or y), rad."""
        return 1.0 / min(self.fx_px, self.fy_px)

    # ----------------------------------------------------------------- geometry
    def project(self, v_cam, *, distort: bool = True):
        """Pixel coordinates of camera-frame directions (pinhole, then the lens distortion).

        Parameters
        ----------
        v_cam : array_like, shape (..., 3)
            Directions in the camera frame (any length).
        distort : bool
            Apply the lens distortion.

        Returns
        -------
        numpy.ndarray, shape (..., 2)
            ``(x, y)``, px (centre of the top-left pixel at (0, 0)); NaN where ``z <= 0``.
        """
        v = np.asarray(v_cam, dtype=float)
        z = v[..., 2]
        # x / z and y / z where z > 0, NaN elsewhere (x / NaN: no division warning)
        n = v[..., :2] / np.where(z > 0, z, np.nan)[..., None]
        if distort and not self.distortion.is_identity:
            xn, yn = self.distortion.distort(n[..., 0], n[..., 1])
            return np.stack([self.fx_px * xn + self.cx, self.fy_px * yn + self.cy], -1)
        return n * self._f_xy + self._c_xy  # fx xn + cx, fy yn + cy (the same operations)

    def back_project(self, xy_px, *, distorted: bool = True):
        """Unit camera-frame directions of pixel coordinates.

        Parameters
        ----------
        xy_px : array_like, shape (..., 2)
            Pixel coordinates ``(x, y)``, px.
        distorted : bool
            The coordinates are distorted (as :meth:`project` gives them): undo the lens
            distortion first (Newton's method).

        Returns
        -------
        numpy.ndarray, shape (..., 3)
            Unit vectors in the camera frame.
        """
        xy = np.asarray(xy_px, dtype=float)
        v = np.empty(xy.shape[:-1] + (3,))
        v[..., :2] = (xy - self._c_xy) / self._f_xy  # (x - cx) / fx, (y - cy) / fy
        v[..., 2] = 1.0
        if distorted and not self.distortion.is_identity:
            v[..., 0], v[..., 1] = self.distortion.undistort(v[..., 0], v[..., 1])
        # numpy.linalg.norm's operations (sqrt of the sum of squares), without its wrapper
        return v / np.sqrt(np.add.reduce(v * v, axis=-1))[..., None]

    def line_of_sight(self, xy_px):
        """Unit camera-frame directions seen at pixel coordinates, through the lens distortion.

        The :class:`~skynav.scenes.projection.Projection` inverse of :meth:`project`.

        Parameters
        ----------
        xy_px : array_like, shape (..., 2)
            Pixel coordinates ``(x, y)``, px.

        Returns
        -------
        numpy.ndarray, shape (..., 3)
            Unit vectors in the camera frame.
        """
        return self.back_project(xy_px, distorted=True)

    def in_image(self, xy_px, margin_px: float = 0.0):
        """True where pixel coordinates fall on the sensor (pixel edges at -0.5 and W-0.5).

        Parameters
        ----------
        xy_px : array_like, shape (..., 2)
            Pixel coordinates ``(x, y)``, px.
        margin_px : float
            Widen the sensor by this much on every side, px.

        Returns
        -------
        numpy.ndarray of bool, shape (...)
            On the (widened) sensor.
        """
        xy = np.asarray(xy_px, dtype=float)
        x, y = xy[..., 0], xy[..., 1]
        return (x >= -0.5 - margin_px) & (x < self.width - 0.5 + margin_px) & (y >= -0.5 - margin_px) & (y < self.height - 0.5 + margin_px)

    # ----------------------------------------------------------------- I/O
    def to_dict(self) -> dict:
        """Plain dict for JSON/YAML (ground truth ``camera``); :meth:`from_dict` inverts it.

        ``K`` and ``bit_depth`` are derived copies (docs/conventions.md fixed truth keys);
        ``pixel_pitch_y_um`` appears only for rectangular pixels.

        Returns
        -------
        dict
            The camera's keys, units in their names (``K`` in px).
        """
        d = {
            "K": self.K.tolist(),
            "width": self.width,
            "height": self.height,
            "focal_length_mm": self.focal_length_mm,
            "pixel_pitch_um": self.pixel_pitch_um,
        }
        if self.pixel_pitch_y_um is not None:
            d["pixel_pitch_y_um"] = self.pixel_pitch_y_um
        d.update({
            "cx": self.cx,
            "cy": self.cy,
            "f_number": self.f_number,
            "exposure_s": self.exposure_s,
            "bit_depth": self.sensor.bit_depth,
            "defocus_sigma_px": self.defocus_sigma_px,
            "psf": self.psf.to_dict(),
            "distortion": dataclasses.asdict(self.distortion),
            "response": {"wavelengths_nm": list(self.response_wavelengths_nm), "qe_t": list(self.response_qe_t)},
            "sensor": dataclasses.asdict(self.sensor),
        })
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "Camera":
        """Inverse of :meth:`to_dict`: ``Camera.from_dict(cam.to_dict()) == cam``.

        Reads exactly the keys :meth:`to_dict` writes (``K`` and ``bit_depth`` are checked
        against the others, not used); for YAML camera sections with presets and ``fov_deg``
        see :func:`skynav.scenes.config.camera_from_mapping`. A key that has moved out of the
        camera (:data:`MOVED_CAMERA_KEYS`) raises :class:`~skynav.scenes.errors.MovedKeyError`.

        Parameters
        ----------
        d : dict
            A camera record (:meth:`to_dict`; a ground truth's ``camera``).

        Returns
        -------
        Camera
            The camera.

        Raises
        ------
        ConfigValueError
            An unknown or missing key, or a value out of its range.
        """
        if not isinstance(d, dict):
            raise ConfigValueError("camera", d, "a mapping (Camera.to_dict())")
        for k in d:
            if k in MOVED_CAMERA_KEYS:
                raise MovedKeyError(f"camera.{k}", d[k], MOVED_CAMERA_KEYS[k])
            if k not in _TO_DICT_KEYS:
                raise ConfigValueError(f"camera.{k}", d[k], "no such key; allowed keys: " + ", ".join(sorted(_TO_DICT_KEYS)))
        missing = [k for k in ("width", "height", "focal_length_mm", "pixel_pitch_um") if k not in d]
        if missing:
            raise ConfigValueError(f"camera.{missing[0]}", None, "a value")
        kw = {k: d[k] for k in ("width", "height", "focal_length_mm", "pixel_pitch_um", "pixel_pitch_y_um",
                                "cx", "cy", "f_number", "exposure_s", "defocus_sigma_px") if k in d}
        if "psf" in d:
            kw["psf"] = psf_from_dict(d["psf"], "camera.psf")
        if "distortion" in d:
            kw["distortion"] = BrownConrady(**_sub_mapping(d["distortion"], "camera.distortion", _DISTORTION_KEYS))
        if "response" in d:
            r = _sub_mapping(d["response"], "camera.response", {"wavelengths_nm", "qe_t"})
            kw["response_wavelengths_nm"] = tuple(r.get("wavelengths_nm", ()))
            kw["response_qe_t"] = tuple(r.get("qe_t", ()))
        if "sensor" in d:
            kw["sensor"] = SensorParams(**_sub_mapping(d["sensor"], "camera.sensor", _SENSOR_KEYS))
        cam = cls(**kw)
        if "bit_depth" in d and d["bit_depth"] != cam.sensor.bit_depth:
            raise ConfigValueError("camera.bit_depth", d["bit_depth"], f"equal to camera.sensor.bit_depth ({cam.sensor.bit_depth})")
        if "K" in d and not np.allclose(np.asarray(d["K"], dtype=float), cam.K, rtol=1e-12, atol=1e-9):
            raise ConfigValueError("camera.K", d["K"], "the K of focal_length_mm, pixel pitches, cx and cy")
        return cam


#: Keys that have left the camera: old key -> where it lives now (scene files and dicts).
MOVED_CAMERA_KEYS = {
    "limiting_v_mag": "visibility.limiting_v_mag",
    "sun_exclusion_deg": "visibility.sun_exclusion_deg",
    "cosmic_rays_per_frame": "render.cosmic_rays_per_frame",
}

_TO_DICT_KEYS = {
    "K", "width", "height", "focal_length_mm", "pixel_pitch_um", "pixel_pitch_y_um", "cx", "cy", "f_number",
    "exposure_s", "bit_depth", "defocus_sigma_px", "psf", "distortion", "response", "sensor",
}
_SENSOR_KEYS = {f.name for f in dataclasses.fields(SensorParams)}
_DISTORTION_KEYS = {f.name for f in dataclasses.fields(BrownConrady)}


def _sub_mapping(value, key: str, allowed) -> dict:
    if not isinstance(value, dict):
        raise ConfigValueError(key, value, "a mapping of keys to values")
    for k in value:
        if k not in allowed:
            raise ConfigValueError(f"{key}.{k}", value[k], "no such key; allowed keys: " + ", ".join(sorted(allowed)))
    return value


def paper_camera(**overrides) -> Camera:
    """The camera of Andreis et al. (2024), Table 4 (and Andreis et al. (2023a), Table 1).

    20 deg FOV, f/2.2, 400 ms, 1024 x 1024 px, f = 40 mm (so 13.78 um pixels), QE x T 0.49,
    defocus 0.5 px, 8-bit output (Andreis et al. (2023a) thresholds at "120 out of 255"). The paper's
    1 cosmic ray per frame is ``RenderOptions.cosmic_rays_per_frame`` and its 20 deg solar
    exclusion and V < 7 limit are :class:`~skynav.scenes.visibility.VisibilityCriteria`.

    Parameters
    ----------
    **overrides
        Fields of :class:`Camera` to change (:meth:`Camera.replace`: a changed size recentres
        the principal point and keeps the pixel pitch, so the field of view shrinks).

    Returns
    -------
    Camera
        The paper's camera, with the overrides applied.

    References
    ----------
    Andreis et al. (2024), Table 4; Andreis et al. (2023a), Table 1.

    Examples
    --------
    >>> from skynav.scenes import paper_camera
    >>> cam = paper_camera()
    >>> cam.width, cam.f_number, cam.exposure_s, round(cam.pixel_pitch_um, 2)
    (1024, 2.2, 0.4, 13.78)
    >>> round(float(np.degrees(cam.fov_x_rad)), 6)
    20.0
    >>> paper_camera(exposure_s=0.1).exposure_s
    0.1
    """
    width = height = 1024
    focal_mm = 40.0
    pitch_um = 2.0 * focal_mm * math.tan(math.radians(10.0)) / width * 1e3
    cam = Camera(width=width, height=height, focal_length_mm=focal_mm, pixel_pitch_um=pitch_um)
    return cam.replace(**overrides) if overrides else cam
