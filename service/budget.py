"""What a render request will cost, estimated before it renders, and the server's budget for it.

``skynav serve`` renders what a client asks, and a few keys scale a frame's work far beyond its
pixels: the PSF's stamp (a Gaussian ``sigma_px`` of 1000 px is a 9801 x 9801 stamp per star), the
streak of a moving camera (sub-samples along every star's path), the PSF tables of a measured or
diffraction PSF, and Mitsuba's samples per pixel of a resolved body. :func:`estimate` adds the
costs of a built scene's parts, in bytes of memory at the peak and seconds of one core, and
:func:`check_budget` refuses a scene above the server's budget (``--max-request-memory``,
``--max-request-seconds``) with one line that names the key behind the largest part and the
limit, before anything is drawn. The estimate is an upper bound of the usual case, not a
promise: the worker's hard memory cap and deadline (:mod:`skynav.service.pool`) stand behind it.

The parts and their constants (each a slope measured on the dev machine, one thread, by
``python benchmarks/request_cost_bench.py``, which renders requests that stress one part at a
time and prints each one's estimate beside the measured growth of the worker's peak RSS and its
time; the constants are rounded up from the largest ratio measured):

- the request itself (validation, the scene's sky, the truth): :data:`BASE_BYTES`,
  :data:`BASE_SECONDS`; the frame (float64 work arrays, the noise, the encoders):
  :data:`FRAME_BYTES_PER_PX`, :data:`FRAME_SECONDS_PER_PX`;
- point sources (stars, bodies not ray-traced): each is cut into sub-samples along its path over
  the exposure (one when it does not move, two Gauss-Legendre nodes per panel of the kernel's
  quadrature step when it does: :func:`skynav.renderer.raster.streak_subsamples`), each
  sub-sample drawn as a ``(2h + 1)^2`` stamp; the rasteriser draws the stamps in chunks of
  ``2^22`` entries (or one stamp when a stamp is larger): :data:`STAMP_BYTES_PER_ENTRY` per
  entry of the chunk and :data:`SUBSAMPLE_BYTES` per sub-sample; :data:`STAMP_SECONDS_PER_ENTRY`
  per entry drawn and :data:`SUBSAMPLE_SECONDS` per sub-sample;
- PSF tables (every model but the Gaussian): ``(n (2h + 4))^2`` samples per table (``n`` samples
  per pixel), one table per spectral node, field-grid point or drawn body:
  :data:`TABLE_BYTES_PER_SAMPLE`, :data:`TABLE_SECONDS_PER_SAMPLE`;
- Mitsuba: per resolved body, its crop's pixels times the samples per pixel (the stratified
  sampler's square) per sub-frame, :data:`MITSUBA_SECONDS_PER_SAMPLE`; its memory does not grow
  with the samples (Dr.Jit's LLVM backend draws them inside one kernel: the same peak at 64 and
  4096 spp on a 340 x 340 crop), only with the crop (:data:`MITSUBA_BYTES_PER_BODY`,
  :data:`MITSUBA_BYTES_PER_CROP_PX`). A wavefront (crop pixels x spp) beyond 2^32 samples is
  refused outright (:data:`MITSUBA_MAX_WAVEFRONT`), whatever the budget: Mitsuba then splits
  it into passes, and its multi-pass path crashes the process.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from skynav.infra.errors import ConfigValueError
from skynav.renderer.crop_geometry import CROP_MARGIN_PX, CROP_QUANTUM_PX, MAX_CROP_PX
from skynav.renderer.optics import DEFAULT_OVERSAMPLING, fine_sampling, lambda_f_px, spectral_nodes

#: Default budget of one request: peak memory beyond the warm worker's, bytes, and seconds of one
#: core. Two workers (a 2-core machine) each at their budget stay within ~3 GB with their warm
#: state (~0.4 GB each), which leaves an 8 GB machine room for the rest of its work.
MAX_REQUEST_MEMORY = 1 << 30
MAX_REQUEST_SECONDS = 10.0

BASE_BYTES = 64e6
BASE_SECONDS = 0.1
FRAME_BYTES_PER_PX = 48.0
FRAME_SECONDS_PER_PX = 1.6e-7
STAMP_BYTES_PER_ENTRY = 64.0
STAMP_SECONDS_PER_ENTRY = 3e-8
SUBSAMPLE_BYTES = 160.0
SUBSAMPLE_SECONDS = 4e-6
TABLE_BYTES_PER_SAMPLE = 12.0
TABLE_SECONDS_PER_SAMPLE = 2e-7
MITSUBA_BYTES_PER_BODY = 64e6
MITSUBA_BYTES_PER_CROP_PX = 64.0
MITSUBA_SECONDS_PER_SAMPLE = 8e-8
MITSUBA_MAX_WAVEFRONT = 2**32 - 1

#: Stamp entries the rasteriser draws at once (:mod:`skynav.renderer.raster`).
CHUNK_ENTRIES = 1 << 22


@dataclass(frozen=True)
class Part:
    """One part of a request's cost: the key behind it (as the request spells it), its value,
    bytes of memory at its peak, seconds of one core."""

    key: str
    value: object
    bytes: float
    seconds: float


@dataclass(frozen=True)
class Budget:
    """The server's budget of one request (``skynav serve --max-request-memory``,
    ``--max-request-seconds``)."""

    max_bytes: float = MAX_REQUEST_MEMORY
    max_seconds: float = MAX_REQUEST_SECONDS

    @property
    def max_file_bytes(self) -> int:
        """Bytes of files one request may read in all (its PSF images: each is held as float64
        tables, normalised, while the next is read): a quarter of the memory budget, checked as
        they are read, before the estimate (which needs the scene they belong to)."""
        return int(self.max_bytes // 4)


def _psf_key(mapping: dict) -> tuple:
    """The key and value that set the PSF's stamp, as the request spells them."""
    cam = mapping.get("camera") if isinstance(mapping.get("camera"), dict) else {}
    psf = cam.get("psf")
    if isinstance(psf, dict):
        model = psf.get("model")
        for k in ("sigma_px", "max_half_px", "field", "file", "oversampling"):
            if k in psf:
                value = psf[k]
                return f"camera.psf.{k}", (f"{len(value)} grid points" if k == "field" and isinstance(value, list)
                                           else value)
        return "camera.psf.model", model
    if "defocus_sigma_px" in cam:
        return "camera.defocus_sigma_px", cam["defocus_sigma_px"]
    return "camera.psf", "the camera's PSF"


def _streak_px(scene) -> float:
    """Longest path of a source over the exposure, px: the camera's rate across the boresight
    over the pixel's field, and about it at the frame's corner."""
    cam = scene.camera
    wx, wy, wz = (abs(float(w)) for w in scene.angular_velocity_rad_s)
    corner_px = math.hypot(cam.width, cam.height) / 2.0
    return cam.exposure_s * (math.hypot(wx, wy) / cam.ifov_rad + wz * corner_px)


def _point_sources(scene, options, mapping, kernel_step_px: float) -> list:
    """The parts of the stars and the bodies drawn as points."""
    cam = scene.camera
    model = cam.psf
    h = int(model.half_size_px(options.flux_fraction_lost, cam))
    entries = float(2 * h + 1) ** 2
    n = len(scene.stars.v_mag) + len(scene.bodies)
    streak = _streak_px(scene)
    per_source = 1.0 if streak <= 0 else 2.0 * math.ceil(streak / kernel_step_px) + 2.0
    m = n * per_source
    chunk = max(entries, min(m * entries, CHUNK_ENTRIES))
    psf_key, psf_value = _psf_key(mapping)
    parts = [Part(psf_key, psf_value, STAMP_BYTES_PER_ENTRY * chunk, STAMP_SECONDS_PER_ENTRY * m * entries)]
    if streak > 0:
        att = mapping.get("attitude") if isinstance(mapping.get("attitude"), dict) else {}
        parts.append(Part("attitude.angular_velocity_deg_s", att.get("angular_velocity_deg_s"), SUBSAMPLE_BYTES * m,
                          SUBSAMPLE_SECONDS * m))
    return parts


def _tables(scene, options, mapping) -> list:
    """The part of the PSF tables (none for a Gaussian)."""
    cam = scene.camera
    model = cam.psf
    if model.model == "gaussian":
        return []
    h = int(model.half_size_px(options.flux_fraction_lost, cam))
    if model.model == "tabulated":
        n = model.oversampling * max(1, math.ceil(DEFAULT_OVERSAMPLING / model.oversampling))
        count = len(model.tables)
    else:
        wl = model.wavelength_nm if model.wavelength_nm is not None else min(cam.response_wavelengths_nm)
        n = fine_sampling(float(lambda_f_px(cam, wl)))
        count = 1 if model.wavelength_nm is not None or model.model == "optical" else len(spectral_nodes(cam).teff_k)
        count += len(scene.bodies)   # a body's own spectrum is a table of its own
    samples = count * float(n * (2 * h + 4)) ** 2
    key, value = _psf_key(mapping)
    return [Part(key, value, TABLE_BYTES_PER_SAMPLE * samples, TABLE_SECONDS_PER_SAMPLE * samples)]


def _mitsuba(scene, options) -> list:
    """The part of the resolved bodies (Mitsuba); a wavefront Mitsuba cannot render is refused."""
    if not options.resolved:
        return []
    spp = math.ceil(math.sqrt(options.mitsuba_spp)) ** 2   # the stratified sampler's square
    streak = _streak_px(scene)
    parts = []
    for b in scene.bodies:
        if not b.resolved:
            continue
        side = min(MAX_CROP_PX, b.angular_diameter_px + 2 * CROP_MARGIN_PX + 2 * CROP_QUANTUM_PX + streak)
        wavefront = side * side * spp
        if wavefront > MITSUBA_MAX_WAVEFRONT:
            raise ConfigValueError("render.mitsuba_spp", options.mitsuba_spp,
                                   f"at most {MITSUBA_MAX_WAVEFRONT // int(side * side)} for {b.name}'s "
                                   f"{int(side)} x {int(side)} px crop (Mitsuba renders at most 2^32 samples at once)")
        parts.append(Part("render.mitsuba_spp", options.mitsuba_spp, MITSUBA_BYTES_PER_BODY + MITSUBA_BYTES_PER_CROP_PX * side * side,
                          MITSUBA_SECONDS_PER_SAMPLE * wavefront * options.mitsuba_time_samples))
    return parts


def estimate(scene, options, mapping: dict | None = None) -> list:
    """The parts of the cost of rendering ``scene`` with ``options`` (:class:`Part` each), the key
    of each spelled as in ``mapping`` (the request). Raises ConfigValueError for a request
    Mitsuba cannot render at all."""
    mapping = mapping or {}
    cam = scene.camera
    px = float(cam.width) * cam.height
    parts = [Part("camera.width x camera.height", f"{cam.width} x {cam.height}", BASE_BYTES + FRAME_BYTES_PER_PX * px,
                  BASE_SECONDS + FRAME_SECONDS_PER_PX * px)]
    model = cam.psf
    if model.model == "gaussian":
        step = min(max(1.5 * model.sigma_px, 0.01), 0.75)   # GaussianKernel.quadrature_step_px, without a kernel
    else:
        step = 0.35                                          # TableKernel.quadrature_step_px
    parts += _point_sources(scene, options, mapping, step)
    parts += _tables(scene, options, mapping)
    parts += _mitsuba(scene, options)
    return parts


def _gb(n: float) -> str:
    return f"{n / 2**30:.2f} GiB" if n >= 2**27 else f"{n / 2**20:.0f} MiB"


def check_budget(scene, options, budget: Budget, mapping: dict | None = None) -> list:
    """The parts of :func:`estimate`, after refusing a request above ``budget``: a
    ConfigValueError naming the key of its largest part, the estimate and the limit."""
    parts = estimate(scene, options, mapping)
    total_b = sum(p.bytes for p in parts)
    total_s = sum(p.seconds for p in parts)
    if total_b > budget.max_bytes:
        top = max(parts, key=lambda p: p.bytes)
        raise ConfigValueError(top.key, top.value, f"a request within this server's memory budget: about "
                                                   f"{_gb(total_b)} estimated, at most {_gb(budget.max_bytes)} "
                                                   f"(skynav serve --max-request-memory)")
    if total_s > budget.max_seconds:
        top = max(parts, key=lambda p: p.seconds)
        raise ConfigValueError(top.key, top.value, f"a request within this server's time budget: about "
                                                   f"{total_s:.0f} s estimated, at most {budget.max_seconds:g} s "
                                                   f"(skynav serve --max-request-seconds)")
    return parts
