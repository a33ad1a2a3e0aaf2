"""A virtual bench: what a real screen + collimator + camera would capture, for tests and rehearsals.

The *true* bench parameters live here only (:data:`SCENARIOS`); the fitting modules never import
this module and see only the files it writes (captures PNG, ``power_meter.csv``). The physics:

- screen: each pixel emits ``black + (peak - black) * (DN / max)**gamma`` (per lit pixel, at the
  power meter) times its fill factor, a fixed per-pixel non-uniformity (0.5 % rms) and a
  large-scale non-uniformity (a few-percent gradient);
- collimator: the true geometric model (distortion, misalignments, and in the stress case an
  unmodelled few-arcsec ripple) and vignetting (``1 - v * r**2`` of the field radius);
- camera: the screen's radiance is blurred in screen space by the camera's defocus and pixel
  footprint (a band-limited image), sampled at the screen point of each camera pixel's true line
  of sight, scaled by the solid-angle ratio (screen px per camera px), and read out through the
  renderer's own :class:`~skynav.renderer.detector.Sensor` (shot, read and dark noise, PRNU,
  quantisation). ``frames`` exposures are averaged, as a lab averages captures.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from skynav.renderer.detector import Sensor
from skynav.scenes.constants import ARCSEC_RAD
from skynav.scenes.facility import Facility, GeometricModel, RadiometricModel, ResidualField

from .patterns import design

#: most exposures a capture averages (each is a full camera frame of noise: 256 on the paper
#: camera's 1024 x 1024 sensor is about a minute per pattern)
MAX_FRAMES = 256


@dataclass(frozen=True, kw_only=True)
class TrueBench:
    geometric: GeometricModel
    radiometric_scale: float = 1.0      # true peak / nominal peak
    gamma: float = 2.35
    black_fraction: float = 3e-5
    fill_factor: float = 0.85
    vignetting: float = 0.25            # relative loss at the screen corner radius
    gradient: float = 0.04              # large-scale screen non-uniformity, peak-to-peak
    pixel_nonuniformity: float = 0.005
    meter_noise: float = 0.002          # relative, per reading
    seed: int = 12


def _ripple(screen, amplitude_arcsec: float, n: int = 33) -> ResidualField:
    x = np.linspace(-0.5, screen.width_px - 0.5, n)
    y = np.linspace(-0.5, screen.height_px - 0.5, n)
    X, Y = np.meshgrid(x / screen.width_px, y / screen.height_px)
    a = amplitude_arcsec * ARCSEC_RAD
    return ResidualField(x_px=x, y_px=y, dx_rad=a * np.sin(2 * np.pi * (2.0 * X + 0.7 * Y) + 0.3),
                         dy_rad=a * np.cos(2 * np.pi * (1.3 * X - 1.8 * Y) + 1.1))


def scenario(name: str, facility: Facility) -> TrueBench:
    """The true bench of a named scenario: ``realistic`` (>= 500 arcsec uncalibrated),
    ``stress`` (4x the distortion plus a 3 arcsec unmodelled ripple), ``shifted`` (screen
    displaced by one grid step), ``roll90`` (screen rolled by 90 deg), ``ideal``."""
    g = facility.geometric
    f = g.focal_length_mm
    base = dict(focal_length_mm=f * 1.006, decentre_x_mm=0.12, decentre_y_mm=-0.08, tilt_x_rad=math.radians(0.8),
                tilt_y_rad=math.radians(-0.6), roll_rad=math.radians(0.35), k1=0.012, k2=-0.004, p1=2e-4, p2=-1.5e-4,
                misalignment_rad=(math.radians(0.05), math.radians(-0.04), 0.0))
    if name == "ideal":
        return TrueBench(geometric=g, gamma=2.2, black_fraction=2e-5, vignetting=0.0, gradient=0.0, pixel_nonuniformity=0.0,
                         fill_factor=1.0)
    if name == "realistic":
        return TrueBench(geometric=GeometricModel(**base), radiometric_scale=0.8)
    if name == "stress":
        b = dict(base, k1=4 * base["k1"], k2=4 * base["k2"], p1=4 * base["p1"], p2=4 * base["p2"])
        return TrueBench(geometric=GeometricModel(**b, residual=_ripple(facility.screen, 3.0)), radiometric_scale=1.3,
                         vignetting=0.35)
    if name == "shifted":
        step_mm = design(facility, phases=1)[0].grid_step_px * facility.screen.pixel_pitch_um * 1e-3
        return TrueBench(geometric=GeometricModel(**dict(base, decentre_x_mm=base["decentre_x_mm"] - step_mm)))
    if name == "roll90":
        return TrueBench(geometric=GeometricModel(**dict(base, roll_rad=math.radians(90.2))))
    raise ValueError(f"unknown virtual-bench scenario {name!r}; known: ideal, realistic, stress, shifted, roll90")


SCENARIO_NAMES = ("realistic", "stress", "shifted", "roll90", "ideal")


class VirtualBench:
    """A simulated bench for one facility file (the lab's nominal description) and a true bench."""

    def __init__(self, facility: Facility, truth: TrueBench):
        self.facility = facility
        self.truth = truth
        sc = facility.screen
        nominal = facility.radiometric
        peak = nominal.peak_w_m2 * truth.radiometric_scale
        self.curve = RadiometricModel(black_w_m2=peak * truth.black_fraction, peak_w_m2=peak, gamma=truth.gamma, max_dn=sc.max_dn)
        self.projection = dataclasses.replace(facility.projection, model=truth.geometric)
        rng = np.random.default_rng(truth.seed)
        H, W = sc.height_px, sc.width_px
        yy, xx = np.mgrid[0:H, 0:W].astype(float)
        u, v = (xx - (W - 1) / 2) / (W / 2), (yy - (H - 1) / 2) / (H / 2)
        large = (1.0 - truth.vignetting * (u * u + v * v) / 2.0) * (1.0 + 0.5 * truth.gradient * (0.8 * u - 0.6 * v))
        self.screen_gain = (large * (1.0 + truth.pixel_nonuniformity * rng.standard_normal((H, W))) * truth.fill_factor)
        self._map = None

    # ------------------------------------------------------------------ radiometry
    def emission_w_m2(self, dn: np.ndarray) -> np.ndarray:
        """Pupil irradiance (meter units) of each screen pixel showing ``dn``."""
        return self.curve.irradiance_w_m2(dn) * self.screen_gain

    def power_meter(self, levels=None, lit_pixels: int = 10000, rng=None) -> list[tuple[int, int, float]]:
        """Power-meter readings of a centred square of ``lit_pixels`` at each digital count (dense
        at low counts); rows ``(digital_count, lit_pixels, irradiance_w_m2)``."""
        rng = np.random.default_rng(self.truth.seed + 1 if rng is None else rng)
        m = self.facility.screen.max_dn
        if levels is None:
            levels = np.unique(np.round(m * np.linspace(0.0, 1.0, 40) ** 2.5).astype(int))
        sc = self.facility.screen
        n = int(math.isqrt(lit_pixels))
        y0, x0 = (sc.height_px - n) // 2, (sc.width_px - n) // 2
        gain = self.screen_gain[y0:y0 + n, x0:x0 + n].sum()
        rows = []
        for d in levels:
            e = float(self.curve.irradiance_w_m2(d)) * gain * (1.0 + self.truth.meter_noise * rng.standard_normal())
            rows.append((int(d), n * n, e))
        return rows

    # ------------------------------------------------------------------ geometry
    def camera_map(self):
        """Screen xy (H, W, 2) of each camera pixel's true line of sight and the screen px per
        camera px area there (cached)."""
        if self._map is None:
            cam = self.facility.camera
            yy, xx = np.mgrid[0:cam.height, 0:cam.width].astype(float)
            xy = self.projection.project(cam.line_of_sight(np.stack([xx, yy], -1)))
            gx = np.gradient(xy, axis=1)
            gy = np.gradient(xy, axis=0)
            area = np.abs(gx[..., 0] * gy[..., 1] - gx[..., 1] * gy[..., 0])
            self._map = (xy, area)
        return self._map

    def expected_electrons(self, screen_dn: np.ndarray) -> np.ndarray:
        """Noise-free camera electrons of a screen image, shape (H, W) of the camera."""
        cam = self.facility.camera
        xy, area = self.camera_map()
        k = self.facility.electrons_per_s_per_w_m2() * cam.exposure_s
        rate = self.emission_w_m2(screen_dn) * k  # e- per screen pixel
        scale = float(np.sqrt(np.median(area)))
        sigma = math.hypot(cam.defocus_sigma_px * scale, scale / math.sqrt(12.0))
        blurred = ndimage.gaussian_filter(rate, sigma, mode="nearest")
        vals = ndimage.map_coordinates(blurred, [xy[..., 1].ravel(), xy[..., 0].ravel()], order=3, mode="constant", cval=0.0)
        return np.maximum(vals.reshape(xy.shape[:2]), 0.0) * area

    def capture(self, screen_dn: np.ndarray, rng: np.random.Generator, frames: int = 16, exposure_scale: float = 1.0) -> np.ndarray:
        """The camera's (averaged) capture of a screen image, DN at the camera's bit depth;
        ``exposure_scale`` lengthens the camera's exposure (the lab's exposure setting)."""
        cam = self.facility.camera
        e = self.expected_electrons(screen_dn) * exposure_scale
        sensor = Sensor(cam.sensor, e.shape)
        acc = np.zeros(e.shape)
        for _ in range(frames):
            acc += sensor.expose(e, cam.exposure_s * exposure_scale, rng, backend="numpy")
        dtype = np.uint8 if cam.sensor.bit_depth <= 8 else np.uint16
        return np.clip(np.round(acc / frames), 0, cam.sensor.max_dn).astype(dtype)


def uncalibrated_error_arcsec(facility: Facility, truth: TrueBench, n: int = 41) -> float:
    """Largest angle over the camera's field between the facility's nominal line of sight of a
    screen point and its true one (the error of an uncalibrated bench), arcsec."""
    cam = facility.camera
    g = np.stack(np.meshgrid(np.linspace(0, cam.width - 1, n), np.linspace(0, cam.height - 1, n)), -1).reshape(-1, 2)
    xy = facility.projection.project(cam.line_of_sight(g))
    true = dataclasses.replace(facility.projection, model=truth.geometric).line_of_sight(xy)
    nom = facility.projection.line_of_sight(xy)
    return float(np.max(np.linalg.norm(np.cross(true, nom), axis=-1)) / ARCSEC_RAD)
