"""A virtual bench: what a real screen + collimator + camera would capture, for tests and rehearsals.

The *true* bench parameters live here only (:data:`SCENARIOS`); the fitting modules never import
this module and see only the files it writes (captures PNG, ``power_meter.csv``). The physics:

- screen: each pixel emits ``black + (peak - black) * (DN / max)**gamma`` (per lit pixel, at the
  power meter) times its fill factor, a fixed per-pixel non-uniformity (0.5 % rms) and a
  large-scale non-uniformity (a few-percent gradient);
- collimator: the true geometric model (distortion, misalignments, and in the stress case an
  unmodelled few-arcsec ripple) and vignetting (``1 - v * r**2`` of the field radius);
- camera: the screen's radiance is blurred in screen space by the camera's PSF and pixel
  footprint (a band-limited image), sampled at the screen point of each camera pixel's true line
  of sight, scaled by the solid-angle ratio (screen px per camera px), and read out through the
  renderer's own :class:`~skynav.renderer.detector.Sensor` (shot, read and dark noise, PRNU,
  quantisation). ``frames`` exposures are averaged, as a lab averages captures. The PSF is the
  camera's ``psf``: the default Gaussian (``defocus_sigma_px``) blurs by a Gaussian of the
  defocus and the pixel footprint combined (``hypot(sigma, 1/sqrt 12)`` camera px, the model the
  bench's calibration accuracy was measured with); any other model by the renderer's own kernel
  (:func:`skynav.renderer.optics.kernel_for`: its pixel-integrated table, resampled onto the
  screen through the collimator's local Jacobian by
  :meth:`~skynav.renderer.table_kernels.TableKernel.on_grid`; a field grid blended per camera pixel as the
  renderer blends it; a polychromatic Airy with the table of the screen's own spectrum).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage
from scipy.signal import fftconvolve

from skynav.renderer.detector import Sensor
from skynav.renderer.optics import is_polychromatic, kernel_for
from skynav.scenes.constants import ARCSEC_RAD
from skynav.scenes.facility import Facility, RadiometricModel
from skynav.scenes.screen import GeometricModel, ResidualField

from .patterns import design

#: Samples per camera pixel, at least, of the grid a non-Gaussian camera PSF is applied on. A
#: diffraction kernel sharper than a screen pixel (lambda F = 0.4 camera px = 0.9 screen px on
#: the bench presets) aliases on the screen's own grid (a dot's flux off by up to 1.4e-3); the
#: screen is cut into squares (each screen pixel a uniform emitter) until this holds: 5 x 5 per
#: screen pixel on the presets (2.2 screen px per camera px), a dot's flux then within 4.1e-5
#: (tests/calibration/test_virtual_bench_psf.py; 3 x 3 and 4 x 4 left 1e-4 for a polychromatic
#: Airy, 6 x 6 leaves 7e-6 at a higher cost).
PSF_SAMPLES_PER_CAMERA_PX = 10.0

#: Camera pixels per side of the tiles a non-Gaussian PSF is applied in (bounds the memory of
#: the upsampled screen crop to a few MB).
PSF_TILE_PX = 128

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
        self._kernels = None

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

    def psf_kernels(self):
        """The camera PSF on the (upsampled) screen grid: ``(kernels, weights, up)``: kernels a
        list of 2-D arrays (each summing to 1, odd sides, centred) on the screen grid cut
        ``up`` x ``up`` per screen pixel (:data:`PSF_SAMPLES_PER_CAMERA_PX`), weights (H * W, K)
        the share of each in every camera pixel (one kernel: all ones); None for the Gaussian,
        which blurs by :func:`scipy.ndimage.gaussian_filter`. Built once per bench."""
        cam = self.facility.camera
        if cam.psf.model == "gaussian":
            return None
        if self._kernels is None:
            xy, _ = self.camera_map()
            gx, gy = np.gradient(xy, axis=1), np.gradient(xy, axis=0)
            # screen offset per camera px (columns: per x step, per y step), the field's median
            J = np.array([[np.median(gx[..., 0]), np.median(gy[..., 0])], [np.median(gx[..., 1]), np.median(gy[..., 1])]])
            source = None
            if is_polychromatic(cam):  # the screen's own spectrum through the camera
                wl, S = self.facility.screen_spectrum
                source = ("spectrum", tuple(float(v) for v in wl), tuple(float(v) for v in S))
            kern = kernel_for(cam, source, 1e-6)
            up = max(1, math.ceil(PSF_SAMPLES_PER_CAMERA_PX / math.sqrt(abs(np.linalg.det(J))) - 1e-9))
            yy, xx = np.mgrid[0:cam.height, 0:cam.width].astype(float)
            w = kern.weights(np.stack([xx.ravel(), yy.ravel()], -1))
            self._kernels = ([kern.on_grid(k, J * up) for k in range(w.shape[1])], w, up)
        return self._kernels

    def _apply_psf(self, rate: np.ndarray, xy: np.ndarray) -> np.ndarray:
        """Screen electrons (per screen px) blurred by the camera's non-Gaussian PSF and read at
        each camera pixel's screen point ``xy`` (H, W, 2), per screen px: tile by tile, the
        screen crop under a tile (plus the kernel's reach) cut into ``up`` x ``up`` uniform
        squares, convolved with the kernel(s) and read by cubic interpolation."""
        kernels, weights, up = self.psf_kernels()
        H, W = xy.shape[:2]
        reach = max(g.shape[0] // 2 for g in kernels) // up + 4  # screen px
        padded = np.pad(rate, reach)  # no light beyond the screen
        w_all = weights.reshape(H, W, -1)
        out = np.zeros((H, W))
        for ty in range(0, H, PSF_TILE_PX):
            for tx in range(0, W, PSF_TILE_PX):
                sub = xy[ty:ty + PSF_TILE_PX, tx:tx + PSF_TILE_PX] + reach  # in the padded screen
                ok = np.all(np.isfinite(sub), axis=-1) & (sub[..., 0] > 0) & (sub[..., 1] > 0) \
                    & (sub[..., 0] < padded.shape[1] - 1) & (sub[..., 1] < padded.shape[0] - 1)
                if not ok.any():
                    continue
                x0 = max(0, int(np.floor(sub[ok][:, 0].min())) - reach)
                y0 = max(0, int(np.floor(sub[ok][:, 1].min())) - reach)
                x1 = min(padded.shape[1], int(np.ceil(sub[ok][:, 0].max())) + reach + 1)
                y1 = min(padded.shape[0], int(np.ceil(sub[ok][:, 1].max())) + reach + 1)
                crop = padded[y0:y1, x0:x1]
                if up > 1:
                    crop = np.repeat(np.repeat(crop, up, axis=0), up, axis=1) / (up * up)
                # the centre of fine sample k of screen pixel s is at s - 0.5 + (k + 0.5) / up
                at = [((sub[..., 1] - y0 + 0.5) * up - 0.5).ravel(), ((sub[..., 0] - x0 + 0.5) * up - 0.5).ravel()]
                tile_w = w_all[ty:ty + PSF_TILE_PX, tx:tx + PSF_TILE_PX]
                for k, g in enumerate(kernels):
                    wk = tile_w[..., k]
                    if not np.any(wk > 0.0):
                        continue
                    blurred = fftconvolve(crop, g, mode="same")
                    v = ndimage.map_coordinates(blurred, at, order=3, mode="constant", cval=0.0).reshape(wk.shape)
                    out[ty:ty + PSF_TILE_PX, tx:tx + PSF_TILE_PX] += wk * v * (up * up)
        return out

    def expected_electrons(self, screen_dn: np.ndarray) -> np.ndarray:
        """Noise-free camera electrons of a screen image, shape (H, W) of the camera."""
        cam = self.facility.camera
        xy, area = self.camera_map()
        k = self.facility.electrons_per_s_per_w_m2() * cam.exposure_s
        rate = self.emission_w_m2(screen_dn) * k  # e- per screen pixel
        if self.psf_kernels() is None:  # the Gaussian: defocus and pixel footprint as one Gaussian, in screen px
            scale = float(np.sqrt(np.median(area)))
            sigma = math.hypot(cam.psf.equivalent_sigma_px(cam) * scale, scale / math.sqrt(12.0))
            blurred = ndimage.gaussian_filter(rate, sigma, mode="nearest")
            vals = ndimage.map_coordinates(blurred, [xy[..., 1].ravel(), xy[..., 0].ravel()], order=3, mode="constant", cval=0.0)
        else:  # the renderer's pixel-integrated kernel(s)
            vals = self._apply_psf(rate, xy)
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
