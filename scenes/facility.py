"""A hardware-in-the-loop facility: a screen seen by the camera through a collimator.

Andreis et al. (2023b), Sec. 3 (RETINA): a microdisplay sits in the focal plane of a collimator; the flight
camera looks into the collimator, so every screen pixel becomes a direction in the camera frame.
This module is the model of such a facility (an optical bench; skynav calls it a *facility*
and keeps "bench" for its benchmark commands), pure computation:

- the screen and its geometry (:mod:`skynav.scenes.screen`): :class:`~skynav.scenes.screen.Screen`,
  and :class:`~skynav.scenes.screen.GeometricModel` / :class:`~skynav.scenes.screen.ScreenProjection`,
  screen pixel <-> camera-frame line of sight, both directions, a physical model (screen decentre,
  tilt and roll, collimator focal length and Brown-Conrady distortion, camera misalignment) plus a
  smooth residual field (a bicubic spline over a coarse grid of the screen). ``ScreenProjection``
  implements the :class:`~skynav.scenes.projection.Projection` protocol at screen resolution, so
  the renderer draws straight into screen pixels.
- :class:`RadiometricModel`: screen digital count -> irradiance at the camera pupil per lit pixel
  (as the power meter reads it), monotone, with its inverse; :meth:`Facility.electrons_per_s_per_w_m2`
  turns the meter's reading into camera electrons through the screen's relative emission
  spectrum, the meter's spectral responsivity and the camera's QE x T, so a screen frame targets
  the same *electrons* as the rendered source, not the same broadband watts.
- :class:`FlatField`: the relative transmission screen -> camera across the field (collimator
  vignetting, screen non-uniformity), 1 where the radiometric curve was measured (screen centre).

File form (YAML, ``schema: skynav.facility/1``) is read and written by :func:`facility_from_mapping`
and :meth:`Facility.to_mapping`; angles are degrees (or arcsec) in files, radians in code.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from dataclasses import dataclass, field

import numpy as np
from scipy.interpolate import RectBivariateSpline

from skynav.infra.errors import ConfigValueError

from .camera import Camera, paper_camera
from .config import camera_from_mapping
from .constants import ARCSEC_RAD, C_M_S, PLANCK_J_S
from .facility_schema import validate_facility_mapping
from .screen import GeometricModel, ResidualField, Screen, ScreenProjection

SCHEMA = "skynav.facility/1"


def _check(cond: bool, key: str, value, allowed: str) -> None:
    if not cond:
        raise ConfigValueError(key, value, allowed)


# ----------------------------------------------------------------------------- radiometry
@dataclass(frozen=True, kw_only=True)
class RadiometricModel:
    """Screen digital count -> irradiance at the camera pupil per lit pixel, W/m^2 as the power
    meter reads it (``model: gamma/1``): ``E(d) = black + (peak - black) * (d / max_dn)**gamma``.

    Monotone for ``gamma > 0`` and ``peak > black``; :meth:`digital_count` is its inverse.
    """

    black_w_m2: float
    peak_w_m2: float
    gamma: float
    max_dn: int

    def __post_init__(self):
        _check(math.isfinite(self.black_w_m2) and self.black_w_m2 >= 0, "radiometric.black_w_m2", self.black_w_m2, ">= 0")
        _check(math.isfinite(self.peak_w_m2) and self.peak_w_m2 > self.black_w_m2, "radiometric.peak_w_m2", self.peak_w_m2, "> black_w_m2")
        _check(math.isfinite(self.gamma) and 0.2 < self.gamma < 10, "radiometric.gamma", self.gamma, "in (0.2, 10)")

    def irradiance_w_m2(self, dn) -> np.ndarray:
        d = np.clip(np.asarray(dn, dtype=float), 0, self.max_dn) / self.max_dn
        return self.black_w_m2 + (self.peak_w_m2 - self.black_w_m2) * d ** self.gamma

    def digital_count(self, irradiance_w_m2) -> np.ndarray:
        """Real-valued digital count giving ``irradiance_w_m2`` (clipped to 0..max_dn)."""
        e = (np.asarray(irradiance_w_m2, dtype=float) - self.black_w_m2) / (self.peak_w_m2 - self.black_w_m2)
        return self.max_dn * np.clip(e, 0.0, 1.0) ** (1.0 / self.gamma)


@dataclass(frozen=True, kw_only=True)
class FlatField:
    """Relative transmission screen -> camera over the screen (bicubic spline over a grid);
    1 at the screen centre, where the radiometric curve is measured."""

    x_px: tuple
    y_px: tuple
    relative: tuple

    def __post_init__(self):
        object.__setattr__(self, "x_px", tuple(float(v) for v in self.x_px))
        object.__setattr__(self, "y_px", tuple(float(v) for v in self.y_px))
        a = np.asarray(self.relative, dtype=float)
        _check(a.shape == (len(self.y_px), len(self.x_px)) and a.shape[0] >= 2 and a.shape[1] >= 2 and np.all(a > 0),
               "radiometric.flat_field.relative", a.shape, "positive values on the (ny, nx) grid")
        object.__setattr__(self, "relative", tuple(tuple(float(v) for v in row) for row in a))

    @functools.cached_property
    def _spline(self):
        k = min(3, len(self.x_px) - 1, len(self.y_px) - 1)
        return RectBivariateSpline(np.array(self.y_px), np.array(self.x_px), np.array(self.relative), kx=k, ky=k)

    def __call__(self, xy_px) -> np.ndarray:
        xy = np.asarray(xy_px, dtype=float)
        x = np.clip(xy[..., 0], self.x_px[0], self.x_px[-1])
        y = np.clip(xy[..., 1], self.y_px[0], self.y_px[-1])
        return self._spline.ev(np.ravel(y), np.ravel(x)).reshape(np.shape(x))

    def __getstate__(self):
        d = dict(self.__dict__)
        d.pop("_spline", None)
        return d

    def __setstate__(self, d):
        self.__dict__.update(d)


def default_screen_spectrum():
    """Documented default relative emission of a colour OLED microdisplay showing grey: three
    Gaussian primaries (B 460 nm, G 530 nm, R 620 nm; sigma 12, 18, 14 nm; weights 1, 0.8, 0.7),
    380-780 nm every 5 nm. Returns (wavelengths_nm, relative) tuples."""
    wl = np.arange(380.0, 781.0, 5.0)
    s = (1.0 * np.exp(-0.5 * ((wl - 460) / 12) ** 2) + 0.8 * np.exp(-0.5 * ((wl - 530) / 18) ** 2)
         + 0.7 * np.exp(-0.5 * ((wl - 620) / 14) ** 2))
    return tuple(float(v) for v in wl), tuple(round(float(v / s.max()), 6) for v in s)


FLAT_RESPONSIVITY = ((300.0, 1200.0), (1.0, 1.0))


# ----------------------------------------------------------------------------- the facility
@dataclass(frozen=True, kw_only=True)
class Facility:
    """A facility: screen, collimator, camera, geometric and radiometric models.

    Parameters
    ----------
    name : str
        The facility's name (file key ``name``).
    screen : Screen
        The display.
    camera : Camera
        The flight camera looking into the collimator.
    geometric : GeometricModel
        Screen pixel <-> camera line of sight (angles rad, lengths mm).
    radiometric : RadiometricModel
        Screen DN -> irradiance at the camera pupil per lit pixel, W/m^2.
    flat_field : FlatField or None
        Relative transmission across the screen (None: uniform).
    screen_spectrum : tuple
        ``(wavelengths_nm, relative)``: the screen's relative emission spectrum.
    meter_responsivity : tuple
        ``(wavelengths_nm, relative)``: the power meter's relative spectral responsivity.
    calibrated_geometric, calibrated_radiometric : dict or None
        Fit reports and provenance kept from the file (not used to compute).

    References
    ----------
    Andreis et al. (2023b), Sec. 3 (the RETINA bench); the file form is ``skynav.facility/1``
    (docs/hil.md).

    Examples
    --------
    >>> from skynav.scenes import facility_from_mapping, screen_small_preset
    >>> fac = screen_small_preset()
    >>> fac.screen.width_px, fac.camera.width
    (640, 256)
    >>> fac.projection.project(np.array([0.0, 0.0, 1.0]))   # the boresight, screen px
    array([319.5, 319.5])
    >>> facility_from_mapping(fac.to_mapping()) == fac
    True
    """

    name: str = "screen"
    screen: Screen
    camera: Camera
    geometric: GeometricModel
    radiometric: RadiometricModel
    flat_field: FlatField | None = None
    screen_spectrum: tuple = field(default_factory=default_screen_spectrum)
    meter_responsivity: tuple = FLAT_RESPONSIVITY
    calibrated_geometric: dict | None = None  # fit report + provenance (file only)
    calibrated_radiometric: dict | None = None

    def __post_init__(self):
        for key in ("screen_spectrum", "meter_responsivity"):
            wl, rel = (tuple(float(v) for v in a) for a in getattr(self, key))
            _check(len(wl) == len(rel) >= 2 and all(b > a for a, b in zip(wl, wl[1:])) and min(rel) >= 0 and max(rel) > 0,
                   f"spectra.{key}", len(wl), "increasing wavelengths_nm and non-negative relative values, >= 2 samples")
            object.__setattr__(self, key, (wl, rel))
        _check(self.radiometric.max_dn == self.screen.max_dn, "radiometric.max_dn", self.radiometric.max_dn,
               f"the screen's 2**bit_depth - 1 = {self.screen.max_dn}")

    def __hash__(self):
        return hash((self.name, self.screen, self.camera, self.geometric.vector().tobytes()))

    @property
    def projection(self) -> ScreenProjection:
        """Camera line of sight <-> screen pixel (a :class:`~skynav.scenes.projection.Projection`)."""
        return ScreenProjection(screen=self.screen, model=self.geometric)

    def flat(self, xy_px) -> np.ndarray:
        """Relative transmission at screen pixels ``xy_px`` (shape (..., 2)), shape (...)."""
        if self.flat_field is None:
            return np.ones(np.shape(xy_px)[:-1])
        return self.flat_field(xy_px)

    def electrons_per_s_per_w_m2(self) -> float:
        """Camera electrons per second per W/m^2 of power-meter reading of the screen's light.

        ``A_pupil * int S(l) QE(l) l/(h c) dl / int S(l) R(l) dl`` with S the screen's relative
        emission, R the meter's relative responsivity, QE the camera's QE x T (1 nm grid).

        Returns
        -------
        float
            e-/s per W/m^2.
        """
        wl = np.arange(300.0, 1200.0, 1.0)
        S = np.interp(wl, *self.screen_spectrum, left=0.0, right=0.0)
        R = np.interp(wl, *self.meter_responsivity, left=0.0, right=0.0)
        Q = np.interp(wl, self.camera.response_wavelengths_nm, self.camera.response_qe_t, left=0.0, right=0.0)
        photons_per_j = wl * 1e-9 / (PLANCK_J_S * C_M_S)
        den = np.trapezoid(S * R, wl)
        _check(den > 0, "spectra", "screen spectrum x meter responsivity", "overlapping spectra")
        return float(self.camera.aperture_area_m2 * np.trapezoid(S * Q * photons_per_j, wl) / den)

    def check_spectra(self) -> None:
        """Raise :class:`ConfigValueError` unless the screen's emission overlaps both the power meter's
        responsivity and the camera's QE x T (else no reading or no electron relates to a DN)."""
        wl = np.arange(300.0, 1200.0, 1.0)
        S = np.interp(wl, *self.screen_spectrum, left=0.0, right=0.0)
        R = np.interp(wl, *self.meter_responsivity, left=0.0, right=0.0)
        Q = np.interp(wl, self.camera.response_wavelengths_nm, self.camera.response_qe_t, left=0.0, right=0.0)
        lo, hi = self.camera.response_wavelengths_nm[0], self.camera.response_wavelengths_nm[-1]
        _check(np.trapezoid(S * Q, wl) > 0, "spectra.screen_emission", f"{self.screen_spectrum[0][0]:g}..{self.screen_spectrum[0][-1]:g} nm",
               f"a spectrum with light where the camera responds ({lo:g}..{hi:g} nm, between 300 and 1200 nm)")
        _check(np.trapezoid(S * R, wl) > 0, "spectra.power_meter_responsivity",
               f"{self.meter_responsivity[0][0]:g}..{self.meter_responsivity[0][-1]:g} nm",
               "a responsivity overlapping the screen's emission (between 300 and 1200 nm)")

    def coverage(self, n: int = 64) -> float:
        """Smallest distance from the camera's image border, seen through the collimator, to the screen's edge.

        Parameters
        ----------
        n : int
            Points sampled along each side of the camera's image.

        Returns
        -------
        float
            Screen px; negative where the camera sees beyond the screen.
        """
        W, H = self.camera.width, self.camera.height
        s = np.linspace(-0.5, 1.0, n)
        xs = np.linspace(-0.5, W - 0.5, n)
        ys = np.linspace(-0.5, H - 0.5, n)
        border = np.concatenate([np.stack([xs, np.full(n, -0.5)], -1), np.stack([xs, np.full(n, H - 0.5)], -1),
                                 np.stack([np.full(n, -0.5), ys], -1), np.stack([np.full(n, W - 0.5), ys], -1)])
        del s
        xy = self.projection.project(self.camera.line_of_sight(border))
        if not np.all(np.isfinite(xy)):
            return -math.inf
        d = np.minimum.reduce([xy[:, 0] + 0.5, self.screen.width_px - 0.5 - xy[:, 0], xy[:, 1] + 0.5, self.screen.height_px - 0.5 - xy[:, 1]])
        return float(d.min())

    def check_coverage(self) -> None:
        """Raise :class:`ConfigValueError` if the screen does not cover the camera's field."""
        d = self.coverage()
        if not d >= 0:
            raise ConfigValueError("screen", f"{self.screen.width_px}x{self.screen.height_px} px of {self.screen.pixel_pitch_um:g} um "
                                   f"behind a {self.geometric.focal_length_mm:g} mm collimator",
                                   f"a screen that covers the camera's {math.degrees(self.camera.fov_x_rad):.1f} deg field "
                                   f"(its edge falls {-d:.0f} screen px inside the camera's image)")

    def replace(self, **changes) -> "Facility":
        """A copy with fields changed (``dataclasses.replace``, checked again)."""
        return dataclasses.replace(self, **changes)

    # ------------------------------------------------------------------ file form
    def to_mapping(self) -> dict:
        """The file form (``skynav.facility/1``, degrees and arcsec); :func:`facility_from_mapping` inverts it."""
        g = self.geometric
        geo = {
            "model": "physical/1",
            "parameters": {
                "focal_length_mm": g.focal_length_mm,
                "decentre_x_mm": g.decentre_x_mm, "decentre_y_mm": g.decentre_y_mm,
                "tilt_x_deg": math.degrees(g.tilt_x_rad), "tilt_y_deg": math.degrees(g.tilt_y_rad),
                "roll_deg": math.degrees(g.roll_rad),
                "k1": g.k1, "k2": g.k2, "p1": g.p1, "p2": g.p2,
                "misalignment_deg": [math.degrees(a) for a in g.misalignment_rad],
            },
        }
        if g.residual is not None:
            r = g.residual
            geo["residual_field"] = {"x_px": list(r.x_px), "y_px": list(r.y_px),
                                     "dx_arcsec": [[v / ARCSEC_RAD for v in row] for row in r.dx_rad],
                                     "dy_arcsec": [[v / ARCSEC_RAD for v in row] for row in r.dy_rad]}
        geo.update(self.calibrated_geometric or {"status": "nominal (not calibrated)"})
        rm = self.radiometric
        rad = {"model": "gamma/1", "parameters": {"black_w_m2": rm.black_w_m2, "peak_w_m2": rm.peak_w_m2, "gamma": rm.gamma}}
        if self.flat_field is not None:
            f = self.flat_field
            rad["flat_field"] = {"x_px": list(f.x_px), "y_px": list(f.y_px), "relative": [list(row) for row in f.relative]}
        rad.update(self.calibrated_radiometric or {"status": "nominal (not calibrated)"})
        return {
            "schema": SCHEMA,
            "name": self.name,
            "screen": dataclasses.asdict(self.screen),
            "collimator": {"focal_length_mm": g.focal_length_mm},
            "camera": self.camera.to_dict(),
            "spectra": {
                "screen_emission": {"wavelengths_nm": list(self.screen_spectrum[0]), "relative": list(self.screen_spectrum[1])},
                "power_meter_responsivity": {"wavelengths_nm": list(self.meter_responsivity[0]), "relative": list(self.meter_responsivity[1])},
            },
            "geometric": geo,
            "radiometric": rad,
        }


def facility_from_mapping(d) -> Facility:
    """A :class:`Facility` from its file form (:meth:`Facility.to_mapping`).

    The mapping is checked first against the facility schema
    (:func:`skynav.scenes.facility_schema.validate_facility_mapping`: every key, type, unit and
    range, unknown keys refused naming the closest valid one), then the camera (the scene files'
    camera keys) and the spectra's overlap with the camera's band.

    Parameters
    ----------
    d : dict
        The parsed YAML of a facility file (``schema: skynav.facility/1``; keys in docs/hil.md):
        angles in degrees or arcsec, lengths in mm and um, irradiance in W/m^2.

    Returns
    -------
    Facility
        The facility, angles converted to radians.

    Raises
    ------
    ConfigValueError
        One line naming the dotted key, the value and what is allowed.

    Examples
    --------
    >>> from skynav.scenes import ConfigValueError, screen_small_preset, facility_from_mapping
    >>> mapping = screen_small_preset().to_mapping()
    >>> facility_from_mapping(mapping).name
    'screen_small'
    >>> mapping["screen"]["pixel_pitch_um"] = -1
    >>> try:
    ...     facility_from_mapping(mapping)
    ... except ConfigValueError as exc:
    ...     print(exc)   # doctest: +ELLIPSIS
    screen.pixel_pitch_um = -1 ...
    """
    validate_facility_mapping(d)
    s = d["screen"]
    screen = Screen(width_px=int(s["width_px"]), height_px=int(s["height_px"]), pixel_pitch_um=float(s["pixel_pitch_um"]),
                    bit_depth=int(s.get("bit_depth", 10)))
    focal = float(d["collimator"]["focal_length_mm"])
    camera = camera_from_mapping(d["camera"])
    geo = d.get("geometric") or {}
    p = geo.get("parameters") or {}
    residual = None
    if geo.get("residual_field"):
        rf = geo["residual_field"]
        residual = ResidualField(x_px=rf["x_px"], y_px=rf["y_px"],
                                 dx_rad=(np.asarray(rf["dx_arcsec"], dtype=float) * ARCSEC_RAD).tolist(),
                                 dy_rad=(np.asarray(rf["dy_arcsec"], dtype=float) * ARCSEC_RAD).tolist())
    g = GeometricModel(
        focal_length_mm=float(p.get("focal_length_mm", focal)),
        decentre_x_mm=float(p.get("decentre_x_mm", 0.0)), decentre_y_mm=float(p.get("decentre_y_mm", 0.0)),
        tilt_x_rad=math.radians(p.get("tilt_x_deg", 0.0)), tilt_y_rad=math.radians(p.get("tilt_y_deg", 0.0)),
        roll_rad=math.radians(p.get("roll_deg", 0.0)),
        k1=float(p.get("k1", 0.0)), k2=float(p.get("k2", 0.0)), p1=float(p.get("p1", 0.0)), p2=float(p.get("p2", 0.0)),
        misalignment_rad=tuple(math.radians(a) for a in p.get("misalignment_deg", (0, 0, 0))),
        residual=residual)
    cal_geo = {k: v for k, v in geo.items() if k not in ("model", "parameters", "residual_field", "status")} or None
    rad = d.get("radiometric") or {}
    rp = rad.get("parameters") or {}
    nominal = nominal_radiometric(screen, camera)
    black = float(rp.get("black_w_m2", nominal.black_w_m2))
    peak = float(rp.get("peak_w_m2", nominal.peak_w_m2))
    _check(peak > black, "radiometric.parameters.peak_w_m2" if "peak_w_m2" in rp else "radiometric.parameters.black_w_m2",
           peak if "peak_w_m2" in rp else black, f"peak_w_m2 > black_w_m2 (now {peak:g} and {black:g})")
    rm = RadiometricModel(black_w_m2=black, peak_w_m2=peak, gamma=float(rp.get("gamma", nominal.gamma)), max_dn=screen.max_dn)
    flat = None
    if rad.get("flat_field"):
        ff = rad["flat_field"]
        flat = FlatField(x_px=ff["x_px"], y_px=ff["y_px"], relative=ff["relative"])
    cal_rad = {k: v for k, v in rad.items() if k not in ("model", "parameters", "flat_field", "status")} or None
    spectra = d.get("spectra") or {}
    kw = {}
    if "screen_emission" in spectra:
        kw["screen_spectrum"] = (spectra["screen_emission"]["wavelengths_nm"], spectra["screen_emission"]["relative"])
    if "power_meter_responsivity" in spectra:
        kw["meter_responsivity"] = (spectra["power_meter_responsivity"]["wavelengths_nm"], spectra["power_meter_responsivity"]["relative"])
    fac = Facility(name=str(d.get("name", "screen")), screen=screen, camera=camera, geometric=g, radiometric=rm,
                   flat_field=flat, calibrated_geometric=cal_geo, calibrated_radiometric=cal_rad, **kw)
    fac.check_spectra()
    return fac


# ----------------------------------------------------------------------------- presets
def nominal_radiometric(screen: Screen, camera: Camera) -> RadiometricModel:
    """A plausible uncalibrated curve: gamma 2.2, contrast 50 000:1, and a peak of 1e-8 W/m^2
    per lit pixel (scaled by the camera's aperture to the paper camera's), which puts a V = -1.5
    star's core near full scale through the preset collimator."""
    peak = 1.0e-8 * (paper_camera().aperture_area_m2 / camera.aperture_area_m2)
    return RadiometricModel(black_w_m2=peak / 5.0e4, peak_w_m2=peak, gamma=2.2, max_dn=screen.max_dn)


def _facility(camera: Camera, screen_px: int, pitch_um: float, focal_mm: float, name: str) -> Facility:
    screen = Screen(width_px=screen_px, height_px=screen_px, pixel_pitch_um=pitch_um, bit_depth=10)
    return Facility(name=name, screen=screen, camera=camera, geometric=GeometricModel(focal_length_mm=focal_mm),
                    radiometric=nominal_radiometric(screen, camera))


def screen_preset() -> Facility:
    """The ``screen`` preset: the paper camera behind a 50 mm collimator and a 2560 px microdisplay.

    The paper camera (20 deg, 1024 px) looks at a square 2560 x 2560 px, 8 um, 10-bit
    microdisplay: the screen spans +/-11.6 deg (a 1.6 deg margin for misalignment) at 2.15
    screen px per camera px. Its radiometric curve is nominal (uncalibrated).

    Returns
    -------
    Facility
        A new facility, perfectly aligned (no residual field, no flat field).

    References
    ----------
    Andreis et al. (2023b), Sec. 3 (RETINA); the camera of Andreis et al. (2024), Table 4.

    Examples
    --------
    >>> from skynav.scenes import screen_preset
    >>> fac = screen_preset()
    >>> fac.screen.width_px, fac.screen.pixel_pitch_um, fac.geometric.focal_length_mm
    (2560, 8.0, 50.0)
    """
    return _facility(paper_camera(), 2560, 8.0, 50.0, "screen")


def screen_small_preset() -> Facility:
    """The ``screen_small`` preset: the ``screen`` optics scaled down for quick rehearsals and tests.

    A 256 x 256 px camera with the paper camera's 20 deg field, a 640 x 640 px, 32 um screen
    (2.15 screen px per camera px), the 50 mm collimator.

    Returns
    -------
    Facility
        A new facility, perfectly aligned, with a nominal radiometric curve.

    Examples
    --------
    >>> from skynav.scenes import screen_small_preset
    >>> fac = screen_small_preset()
    >>> fac.camera.width, round(float(np.degrees(fac.camera.fov_x_rad)), 6)
    (256, 20.0)
    """
    cam = paper_camera()
    cam = cam.replace(width=256, height=256, pixel_pitch_um=cam.pixel_pitch_um * 4)
    return _facility(cam, 640, 32.0, 50.0, "screen_small")


PRESETS = {"screen": screen_preset, "screen_small": screen_small_preset}

#: Former preset names, refused naming the new one: "bench" is the benchmark command group
#: (``skynav bench ip|nav|loop``); the facility presets are named after what the camera looks at.
RENAMED_PRESETS = {"bench": "screen", "bench_small": "screen_small"}


def renamed_preset_line(name: str) -> str | None:
    """The one-line refusal of a former preset name (None for any other name).

    >>> renamed_preset_line("bench_small")
    "bench_small: the facility preset is now named screen_small ('bench' means only the benchmark commands); give screen_small"
    """
    new = RENAMED_PRESETS.get(str(name))
    if new is None:
        return None
    return f"{name}: the facility preset is now named {new} ('bench' means only the benchmark commands); give {new}"
