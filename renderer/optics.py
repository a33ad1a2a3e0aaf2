"""Tables of pixel-integrated PSFs: diffraction (Airy), pupil FFT with Zernikes, measured images.

Every non-Gaussian model of :mod:`skynav.scenes.psf` becomes one or more fine tables
``P(u, v)``: the PSF integrated over one pixel whose centre is offset ``(u, v)`` px from the
point, sampled every ``1/N`` px (``N`` samples per pixel) on a square of ``L = 2 h + 4`` px
(``h`` the stamp half size); :class:`~skynav.renderer.table_kernels.TableKernel` reads stamps out of them.

Method
------
1. The PSF's intensity ``I`` (per px^2, integral 1) on the fine grid:

   - Airy: the analytic pattern of an annular pupil (Born & Wolf 8.6.3; obscured form in
     Mahajan 1986) ``I(r) = pi / (4 (lf)^2 (1 - e^2)) [2 J1(v)/v - e^2 2 J1(e v)/(e v)]^2``,
     ``v = pi r / lf``, ``lf = lambda F / pixel pitch``; polychromatic: the sum over the band
     (10 nm steps) weighted by the source's electron spectrum (spectrum x lambda/hc x QE x T),
     through a radial profile read linearly on a grid of 1/(16 N) px. The renderer does not make
     one such table per source: it tabulates the camera's polychromatic Airy once, at a few
     *spectral nodes* (:func:`spectral_nodes`: blackbodies whose effective wavelengths are
     log-spaced over the stars' and bodies' range, as few as keep the linear interpolation
     between nodes within :data:`SPECTRAL_TOLERANCE` of the peak), and draws each source with
     each star with the blend of the two nodes around its own effective wavelength
     (:func:`kernel_for`); a body (reflected sunlight) and a bench screen with the exact table
     of their own spectrum (:func:`source_kernel`, also the reference the blend is tested
     against);
   - optical: ``|F(pupil exp(2 pi i W))|^2`` with ``W = sum_j a_j Z_j`` (Noll 1976
     normalisation, waves RMS), the pupil 512 samples across, each the mean field of 4 x 4
     sub-samples inside the annulus, ``F`` a matrix Fourier transform straight onto the fine
     focal grid;
   - tabulated: the measured image (normalised to a sum of 1) at its own ``oversampling``,
     re-centred by a Fourier shift when its size is even, and resampled by zero-padding its
     spectrum to at least 16 samples per pixel.

2. Pixel integration: ``P = IFFT(FFT(I) sinc(f_x) sinc(f_y))`` (f in cycles/px), exact for
   a band-limited ``I`` (diffraction is band-limited at ``1/lf`` cycles/px; the fine step is
   at most ``lf/2``, Nyquist).

Orientation: x = column, y = row, the Zernike angle from +x towards +y, the same as GalSim's
``OpticalPSF`` drawn with ``array[row, col]`` (checked against it in
``tests/renderer/test_psf_models_against_galsim.py``).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
from scipy.special import j1

from skynav.scenes.psf import zernike
from skynav.scenes.psf_measured import TabulatedPSFModel

from . import spectra
from .kernels import GaussianKernel
from .table_kernels import TableKernel

__all__ = ["airy_intensity", "pixel_integrate", "fine_sampling", "airy_table",
           "optical_table", "tabulated_tables", "electron_spectrum", "effective_wavelength_nm", "SpectralNodes",
           "spectral_nodes", "kernel_for", "source_kernel", "SPECTRAL_TOLERANCE"]

#: Largest error, in units of the peak of the pixel-integrated PSF, that the linear
#: interpolation between two spectral nodes of a polychromatic Airy may make, measured on the
#: monochromatic pattern at the node's effective wavelengths (whose change with wavelength
#: bounds the band-averaged one's): half the 1e-3 of the peak the GalSim comparison allows,
#: the other half left to a source's spectrum differing from the node blackbodies' at the same
#: effective wavelength.
SPECTRAL_TOLERANCE = 5e-4

#: Blackbody temperatures whose effective wavelengths (with every body's) the nodes span, K;
#: a source beyond them takes the end node's table.
SPECTRAL_TEFF_RANGE_K = (2000.0, 50000.0)

#: Fewest fine samples per pixel of the tables.
DEFAULT_OVERSAMPLING = 16

#: Fine samples per lambda F the tables are raised to: a stamp reads its table bilinearly
#: between samples, which errs by about ``0.5 / (n lf)^2`` of the peak (measured against GalSim's
#: pixel-convolved Airy: 1.9e-3 at lambda F = 1 px and 16 samples per px, 4.8e-4 at 2.55 px);
#: 48 per lambda F keeps it near 2e-4 (5e-4 at lambda F = 1 px, where :data:`MAX_OVERSAMPLING`
#: caps it), within the 1e-3 of the peak the GalSim comparison allows.
SAMPLES_PER_LAMBDA_F = 48

#: Most fine samples per pixel from :data:`SAMPLES_PER_LAMBDA_F` (the tables' memory grows as
#: its square: a polychromatic Airy keeps several); Nyquist may ask for more.
MAX_OVERSAMPLING = 32


def fine_sampling(lf_px: float, oversampling: int = DEFAULT_OVERSAMPLING) -> int:
    """Fine samples per pixel: ``oversampling``, raised to :data:`SAMPLES_PER_LAMBDA_F` per
    lambda F, at most :data:`MAX_OVERSAMPLING` (and never below Nyquist, ``2 / lf``)."""
    want = min(MAX_OVERSAMPLING, math.ceil(SAMPLES_PER_LAMBDA_F / lf_px))
    return int(max(oversampling, want, math.ceil(2.0 / lf_px)))


def airy_intensity(r_px, lf_px: float, obscuration: float = 0.0) -> np.ndarray:
    """Airy pattern of an annular pupil, per px^2 (integral 1 over the plane).

    Parameters
    ----------
    r_px : array_like, px
        Distance from the centre.
    lf_px : float
        Wavelength x f-number / pixel pitch.
    obscuration : float
        Diameter ratio of the central obstruction.
    """
    e = float(obscuration)
    v = np.pi * np.asarray(r_px, dtype=float) / lf_px
    small = v < 1e-8
    vs = np.where(small, 1.0, v)
    a = np.where(small, 1.0, 2.0 * j1(vs) / vs)
    if e > 0:
        a = a - e * e * np.where(small, 1.0, 2.0 * j1(e * vs) / (e * vs))
    return np.pi / (4.0 * lf_px * lf_px * (1.0 - e * e)) * a * a


def pixel_integrate(intensity: np.ndarray, n: int, shift=(0.0, 0.0), up: int = 1) -> np.ndarray:
    """Pixel-integrated table of an intensity sampled every ``1/n`` px (per px^2): the
    convolution with a 1 x 1 px box by FFT (``sinc`` in frequency), so each value is the
    fraction of the flux in a pixel centred there. ``shift`` = (dy, dx) fine samples moves the
    table (a Fourier shift, for images whose centre falls between samples); ``up`` > 1
    resamples it every ``1/(n up)`` px by zero-padding the spectrum (exact for a band-limited
    PSF sampled above Nyquist), so the stamps' bilinear read stays fine."""
    ny, nx = intensity.shape
    fy = np.fft.fftfreq(ny, d=1.0 / n)  # cycles per px
    fx = np.fft.rfftfreq(nx, d=1.0 / n)
    k = np.sinc(fy)[:, None] * np.sinc(fx)[None, :]
    if shift[0] or shift[1]:
        k = k * np.exp(-2j * np.pi * (fy[:, None] * shift[0] / n + fx[None, :] * shift[1] / n))
    spec = np.fft.rfft2(intensity) * k
    if up > 1:
        big = np.zeros((ny * up, (nx * up) // 2 + 1), dtype=complex)
        hy = (ny + 1) // 2
        big[:hy, : spec.shape[1]] = spec[:hy]
        big[ny * up - (ny - hy):, : spec.shape[1]] = spec[hy:]
        return np.fft.irfft2(big, s=(ny * up, nx * up)) * (up * up)
    return np.fft.irfft2(spec, s=(ny, nx))


def _grid(n: int, length_px: int):
    """Offsets of the fine samples from the centre (index ``n L / 2``), px, shape (n L,)."""
    size = n * length_px
    return (np.arange(size) - size // 2) / n


def airy_table(lf_px, weights, obscuration: float, half: int, n: int) -> np.ndarray:
    """Pixel-integrated Airy table; ``lf_px`` and ``weights`` arrays for a polychromatic sum."""
    lf = np.atleast_1d(np.asarray(lf_px, dtype=float))
    w = np.atleast_1d(np.asarray(weights, dtype=float))
    w = w / w.sum()
    length = 2 * half + 4
    u = _grid(n, length)
    r_max = math.sqrt(2.0) * (length / 2.0 + 1.0)
    r = np.arange(0.0, r_max, 1.0 / (16 * n))
    prof = np.zeros_like(r)
    for lfk, wk in zip(lf, w):
        prof += wk * airy_intensity(r, lfk, obscuration)
    rr = np.hypot(u[:, None], u[None, :])
    if lf.size == 1:
        img = airy_intensity(rr, lf[0], obscuration)  # monochromatic: exact, no radial read
    else:
        img = np.interp(rr, r, prof)
    return pixel_integrate(img, n)


def _pupil(n_p: int, obscuration: float, zernikes, sub: int = 4):
    """Complex pupil sampled ``n_p`` x ``n_p`` across the aperture diameter (coordinates in
    units of D, sample centres at ``(k + 0.5) / n_p - 0.5``): each sample the mean, over its
    ``sub`` x ``sub`` sub-samples, of ``exp(2 pi i W)`` inside the annulus (0 outside), so the
    grey edge and the wavefront's change across a sample both enter (taking ``W`` at the
    sample's centre left 2e-3 of the peak at one wave of defocus and 256 samples)."""
    xc = (np.arange(n_p) + 0.5) / n_p - 0.5
    off = ((np.arange(sub) + 0.5) / sub - 0.5) / n_p
    x = (xc[:, None] + off[None, :]).ravel() * 2.0  # unit-radius coordinates of the sub-samples
    yy, xx = np.meshgrid(x, x, indexing="ij")
    rho = np.hypot(xx, yy)
    inside = (rho <= 1.0) & (rho >= obscuration)
    wf = np.zeros_like(rho)
    if zernikes:
        theta = np.arctan2(yy, xx)
        for j, a in zernikes:
            wf += a * zernike(j, rho, theta)
    field = np.where(inside, np.exp(2j * np.pi * wf), 0.0)
    return xc, field.reshape(n_p, sub, n_p, sub).mean(axis=(1, 3))


#: Pupil samples across the aperture diameter of the optical model, each the mean of 4 x 4
#: sub-samples (against 1024 samples: 1.3e-4 of the peak at 0.4 waves of defocus, 5.5e-4 at one
#: wave; the focal grid is set apart, by MFT).
PUPIL_SAMPLES = 512


def optical_table(lf_px: float, obscuration: float, zernikes, half: int, n: int) -> np.ndarray:
    """Pixel-integrated table of an aberrated annular pupil (monochromatic).

    The focal-plane field on the fine grid is a matrix Fourier transform of the pupil
    (Soummer et al. 2007, Opt. Express 15, 15935): ``E = A_y P A_x^T`` with
    ``A[u, x] = exp(2 pi i x u / lf)`` (x in units of the diameter, u in px), so the pupil's
    sampling and the table's are independent; ``I = |E|^2 / (lf^2 A)``, ``A = pi (1 - e^2) / 4``
    the annulus' area in units of D^2, has integral 1 over the whole plane (Parseval for the
    continuous pupil: its whole flux is ``lf^2 A``). The anti-aliased samples are not used for
    the normalisation: the grey edge samples' ``sum |P|^2 dx^2`` falls short of the area (by
    3e-3 at 256 samples), the difference being light their aliases put hundreds of px away, and
    dividing by it made the core that much too bright.
    """
    length = 2 * half + 4
    u = _grid(n, length)
    xc, p = _pupil(PUPIL_SAMPLES, obscuration, zernikes)
    dx = 1.0 / PUPIL_SAMPLES
    a = np.exp(2j * np.pi * np.outer(u, xc) / lf_px)  # (n L, n_p), the same matrix for both axes
    e = (a @ p @ a.T) * (dx * dx)
    area = math.pi * (1.0 - obscuration * obscuration) / 4.0
    img = (e.real**2 + e.imag**2) / (lf_px * lf_px * area)
    return pixel_integrate(img, n)


def tabulated_tables(model: TabulatedPSFModel, half: int) -> tuple:
    """Pixel-integrated tables of a measured PSF (one per field-grid point), resampled to at
    least :data:`DEFAULT_OVERSAMPLING` samples per pixel. Returns (tables, samples per px)."""
    n = model.oversampling
    up = max(1, math.ceil(DEFAULT_OVERSAMPLING / n))
    length = 2 * half + 4
    size = n * length
    out = []
    for t in model.tables:
        ny, nx = t.shape
        img = np.zeros((size, size))
        # centre of the measured image ((ny - 1)/2, (nx - 1)/2) -> sample size // 2 (+ a half
        # sample, shifted back by Fourier, for even sizes)
        oy, ox = size // 2 - (ny - 1) // 2, size // 2 - (nx - 1) // 2
        sy0, sx0 = max(0, -oy), max(0, -ox)
        dy0, dx0 = max(0, oy), max(0, ox)
        hy, hx = min(ny - sy0, size - dy0), min(nx - sx0, size - dx0)
        img[dy0:dy0 + hy, dx0:dx0 + hx] = t[sy0:sy0 + hy, sx0:sx0 + hx] * (n * n)
        shift = (-0.5 if ny % 2 == 0 else 0.0, -0.5 if nx % 2 == 0 else 0.0)
        out.append(pixel_integrate(img, n, shift, up=up))
    return tuple(out), n * up


def electron_spectrum(camera, source) -> tuple:
    """Wavelengths (nm, 10 nm steps over the camera's band) and relative electrons per nm of a
    source: ``("star", teff_k)`` (a blackbody), ``("body", name)`` (Sun x reflectance) or
    ``("spectrum", wavelengths_nm, relative_w_m2_nm)`` (any emitter, e.g. a bench screen; read
    linearly, zero outside its table)."""
    lo, hi = min(camera.response_wavelengths_nm), max(camera.response_wavelengths_nm)
    wl = np.arange(lo, hi + 1e-9, 10.0)
    if source[0] == "star":
        f = spectra.blackbody_w_m2_nm_shape(float(source[1]), wl)
    elif source[0] == "spectrum":
        f = np.interp(wl, np.asarray(source[1], dtype=float), np.asarray(source[2], dtype=float), left=0.0, right=0.0)
    else:
        f = spectra.solar_irradiance_1au_w_m2_nm(wl) * spectra.reflectance_shape(source[1], wl)
    e = np.asarray(f, dtype=float).reshape(-1) * wl * spectra.response_on_grid(camera, wl)
    return wl, e


def effective_wavelength_nm(camera, source) -> float:
    """Electron-weighted mean wavelength of a source through the camera, nm (the spectral
    coordinate of the polychromatic tables): ``sum e(l) l / sum e(l)`` of :func:`electron_spectrum`."""
    wl, e = electron_spectrum(camera, source)
    return float(np.sum(e * wl) / np.sum(e))


def star_effective_wavelengths_nm(camera, teff_k) -> np.ndarray:
    """:func:`effective_wavelength_nm` of blackbodies, vectorised over ``teff_k`` (N,), nm."""
    t = np.asarray(teff_k, dtype=float).reshape(-1)
    lo, hi = min(camera.response_wavelengths_nm), max(camera.response_wavelengths_nm)
    wl = np.arange(lo, hi + 1e-9, 10.0)
    if t.size == 0:
        return np.zeros(0)
    f = spectra.blackbody_w_m2_nm_shape(t, wl).reshape(t.size, wl.size)
    e = f * (wl * spectra.response_on_grid(camera, wl))[None, :]
    return (e @ wl) / e.sum(axis=1)


def lambda_f_px(camera, wavelength_nm) -> np.ndarray:
    return np.asarray(wavelength_nm, dtype=float) * 1e-3 * camera.f_number / camera.pixel_pitch_um


@dataclass(frozen=True, kw_only=True)
class SpectralNodes:
    """Where a camera's polychromatic Airy is tabulated (see :func:`spectral_nodes`).

    Attributes
    ----------
    wavelength_nm : tuple of float
        Effective wavelengths of the nodes, ascending, nm (one node: a single table).
    teff_k : tuple of float
        The blackbody temperature whose spectrum (x the camera's response) makes each node's
        table, K.
    tolerance : float
        The interpolation error asked for, units of the peak.
    error : float
        The largest interpolation error of the monochromatic proxy on these nodes (at the
        midpoints between them), units of the peak.
    """

    wavelength_nm: tuple
    teff_k: tuple
    tolerance: float
    error: float


def _teff_at_wavelength(camera, lam_nm: float) -> float:
    """The blackbody temperature whose effective wavelength is ``lam_nm`` (bisection in log T;
    the effective wavelength falls monotonically with temperature)."""
    a, b = math.log(500.0), math.log(1e6)
    for _ in range(60):
        m = 0.5 * (a + b)
        if float(star_effective_wavelengths_nm(camera, [math.exp(m)])[0]) > lam_nm:
            a = m
        else:
            b = m
    return math.exp(0.5 * (a + b))


@functools.lru_cache(maxsize=16)
def spectral_nodes(camera, tolerance: float = SPECTRAL_TOLERANCE, max_intervals: int = 64) -> SpectralNodes:
    """The spectral nodes of a camera's polychromatic Airy, chosen once per camera (cached).

    The nodes are log-spaced in effective wavelength over the range of blackbodies of
    :data:`SPECTRAL_TEFF_RANGE_K` and of every body's reflected sunlight. Their number doubles
    (1, 2, 4, ... ``max_intervals`` intervals) until the linear interpolation between
    neighbouring nodes of the *monochromatic* pixel-integrated Airy at those wavelengths errs
    by at most ``tolerance`` of its peak at every interval's midpoint (the table's core, |u| <=
    4 px, where the pattern changes most). A diffraction pattern narrower than a pixel (the
    paper camera's lambda F = 0.09 px) needs a single interval; a sampled one (2.2 px) a few
    dozen.
    """
    model = camera.psf
    lams = list(star_effective_wavelengths_nm(camera, SPECTRAL_TEFF_RANGE_K))
    lams += [effective_wavelength_nm(camera, ("body", b)) for b in sorted(spectra._REFLECTANCE) + ["earth"]]
    lo, hi = math.log(min(lams)), math.log(max(lams))
    band_lo = min(camera.response_wavelengths_nm)
    n = fine_sampling(float(lambda_f_px(camera, band_lo)))
    half = min(4, int(model.half_size_px(1e-6, camera)))
    tables = {}

    def table(x):  # the monochromatic proxy at ln(wavelength) x
        key = round(x, 12)
        if key not in tables:
            tables[key] = airy_table(float(lambda_f_px(camera, math.exp(x))), [1.0], model.obscuration, half, n)
        return tables[key]

    intervals, err = 1, 0.0
    while True:
        xs = np.linspace(lo, hi, intervals + 1)
        err = 0.0
        for a, b in zip(xs[:-1], xs[1:]):
            ta, tb, tm = table(a), table(b), table(0.5 * (a + b))
            err = max(err, float(np.max(np.abs(0.5 * (ta + tb) - tm)) / tm.max()))
        if err <= tolerance or intervals >= max_intervals or hi - lo < 1e-9:
            break
        intervals *= 2
    if hi - lo < 1e-9:
        xs = np.array([lo])
    wl = tuple(float(math.exp(x)) for x in xs)
    return SpectralNodes(wavelength_nm=wl, teff_k=tuple(_teff_at_wavelength(camera, w) for w in wl),
                         tolerance=float(tolerance), error=err)


def _gaussian_kernel(camera, model, source, half):
    return GaussianKernel(model.sigma_px)


def _airy_kernel(camera, model, source, half):
    floor = camera.sensor.read_noise_e  # the noise a faint source's smaller stamps are sized by
    if model.wavelength_nm is not None:
        lf = float(lambda_f_px(camera, model.wavelength_nm))
        n = fine_sampling(lf)
        return TableKernel((airy_table(lf, [1.0], model.obscuration, half, n),), n, half, noise_floor_e=floor)
    if source is not None:
        return source_kernel(camera, source, half=half)
    nodes = spectral_nodes(camera)
    n = fine_sampling(float(lambda_f_px(camera, min(camera.response_wavelengths_nm))))
    tables = []
    for teff in nodes.teff_k:
        wl, e = electron_spectrum(camera, ("star", teff))
        tables.append(airy_table(lambda_f_px(camera, wl), e, model.obscuration, half, n))
    return TableKernel(tuple(tables), n, half, wavelengths_nm=nodes.wavelength_nm, noise_floor_e=floor)


def _optical_kernel(camera, model, source, half):
    lf = float(lambda_f_px(camera, model.wavelength_nm))
    n = fine_sampling(lf)
    return TableKernel((optical_table(lf, model.obscuration, model.zernike_waves, half, n),), n, half,
                       noise_floor_e=camera.sensor.read_noise_e)


def _tabulated_kernel(camera, model, source, half):
    tables, n = tabulated_tables(model, half)
    return TableKernel(tables, n, half, grid=model.grid, noise_floor_e=camera.sensor.read_noise_e)


#: The one dispatch from a scene's PSF *model* (:mod:`skynav.scenes.psf`, by its ``model`` name)
#: to the builder of the renderer's *kernel*: ``builder(camera, model, source, half)``.
KERNEL_BUILDERS = {
    "gaussian": _gaussian_kernel,
    "airy": _airy_kernel,
    "optical": _optical_kernel,
    "tabulated": _tabulated_kernel,
}


@functools.lru_cache(maxsize=64)
def kernel_for(camera, source=None, flux_fraction_lost: float = 1e-6):
    """The renderer's kernel of the camera's PSF model, built once per camera (cached).

    The one dispatch from a model to its kernel: :data:`KERNEL_BUILDERS`, by the model's
    ``model`` name. A Gaussian is a :class:`~skynav.renderer.kernels.GaussianKernel`, every
    other model a :class:`~skynav.renderer.table_kernels.TableKernel`, whose faint sources' stamps are
    sized by the camera's read noise (:meth:`~skynav.renderer.table_kernels.TableKernel.half_sizes_px`).

    Parameters
    ----------
    camera : skynav.scenes.camera.Camera
        The camera: its ``psf`` model, f-number, pixel pitch, response and read noise.
    source : tuple, optional
        None: the kernel every source is drawn with (for a polychromatic Airy the tables of its
        :func:`spectral_nodes`, whose stamps take each point's effective wavelength). A source
        (``("star", teff_k)``, ``("body", name)``, ``("spectrum", wavelengths, values)``,
        hashable) on a polychromatic camera: :func:`source_kernel`, the table of its own
        spectrum.
    flux_fraction_lost : float
        The render's ``flux_fraction_lost``: the model sizes the stamps for it (capped at its
        ``max_half_px``).

    Returns
    -------
    GaussianKernel or TableKernel

    Examples
    --------
    >>> from skynav.renderer import kernel_for
    >>> from skynav.scenes import paper_camera
    >>> kernel_for(paper_camera())
    GaussianKernel(sigma_px=0.5)
    """
    model = camera.psf
    half = 0 if model.model == "gaussian" else int(model.half_size_px(flux_fraction_lost, camera))
    return KERNEL_BUILDERS[model.model](camera, model, source, half)


def source_kernel(camera, source, flux_fraction_lost: float = 1e-6, half: int | None = None):
    """The exact polychromatic Airy of one source's own electron spectrum (one table): the
    reference :func:`kernel_for`'s interpolated nodes are tested against, and the kernel of a
    body (reflected sunlight, whose absorption bands make a pattern no blackbody's matches to
    1e-3: 8e-3 of the peak for Mars at lambda F = 2.2 px); :func:`kernel_for` caches it per
    camera and source."""
    model = camera.psf
    if half is None:
        half = int(model.half_size_px(flux_fraction_lost, camera))
    wl, e = electron_spectrum(camera, source)
    lf = lambda_f_px(camera, wl)
    n = fine_sampling(float(lambda_f_px(camera, min(camera.response_wavelengths_nm))))
    return TableKernel((airy_table(lf, e, model.obscuration, half, n),), n, half, noise_floor_e=camera.sensor.read_noise_e)


def is_polychromatic(camera) -> bool:
    """Whether the camera's PSF model blends its tables by each source's spectrum."""
    return camera.psf.polychromatic
