"""Tables of pixel-integrated PSFs: diffraction (Airy), pupil FFT with Zernikes, measured images.

Every non-Gaussian model of :mod:`skynav.scenes.psf` becomes one or more fine tables
``P(u, v)``: the PSF integrated over one pixel whose centre is offset ``(u, v)`` px from the
point, sampled every ``1/N`` px (``N`` samples per pixel) on a square of ``L = 2 h + 4`` px
(``h`` the stamp half size); :class:`~skynav.renderer.psf.TablePSF` reads stamps out of them.

Method
------
1. The PSF's intensity ``I`` (per px^2, integral 1) on the fine grid:

   - Airy: the analytic pattern of an annular pupil (Born & Wolf 8.6.3; obscured form in
     Mahajan 1986) ``I(r) = pi / (4 (lf)^2 (1 - e^2)) [2 J1(v)/v - e^2 2 J1(e v)/(e v)]^2``,
     ``v = pi r / lf``, ``lf = lambda F / pixel pitch``; polychromatic: the sum over the band
     (10 nm steps) weighted by the source's electron spectrum (spectrum x lambda/hc x QE x T),
     through a radial profile read linearly on a grid of 1/(16 N) px;
   - optical: ``|F(pupil exp(2 pi i W))|^2`` with ``W = sum_j a_j Z_j`` (Noll 1976
     normalisation, waves RMS), the pupil 256 samples across, anti-aliased (each sample's area
     fraction inside the annulus from 8 x 8 sub-samples), ``F`` a matrix Fourier transform
     straight onto the fine focal grid;
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

import numpy as np
from scipy.special import j1

from skynav.scenes.psf import AiryPSFModel, GaussianPSFModel, OpticalPSFModel, TabulatedPSFModel

from . import spectra
from .psf import GaussianPSF, TablePSF

__all__ = ["noll_to_nm", "zernike", "airy_intensity", "pixel_integrate", "fine_sampling", "airy_table",
           "optical_table", "tabulated_tables", "electron_spectrum", "TEFF_BIN_EDGES_K"]

#: Effective-temperature bins of the polychromatic star tables, K (log-spaced; one table per bin,
#: made at the bin's geometric centre).
TEFF_BIN_EDGES_K = (0.0, 3000.0, 4000.0, 5000.0, 6000.0, 7500.0, 10000.0, 15000.0, np.inf)
_BIN_TEFF_K = (2600.0, 3500.0, 4500.0, 5500.0, 6700.0, 8700.0, 12200.0, 20000.0)

#: Fine samples per pixel of the tables (at least 2 per lambda F: Nyquist of diffraction).
DEFAULT_OVERSAMPLING = 16


def fine_sampling(lf_px: float, oversampling: int = DEFAULT_OVERSAMPLING) -> int:
    """Fine samples per pixel: ``oversampling``, raised to Nyquist (``2 / lf``) if needed."""
    return int(max(oversampling, math.ceil(2.0 / lf_px)))


def noll_to_nm(j: int) -> tuple:
    """Radial degree n and azimuthal frequency m (signed: m < 0 is a sine term) of Noll index j.

    Examples
    --------
    >>> [noll_to_nm(j) for j in (1, 2, 3, 4, 7, 8, 11)]
    [(0, 0), (1, 1), (1, -1), (2, 0), (3, -1), (3, 1), (4, 0)]
    """
    ns, ms = [0, 0], [0, 0]  # index j directly (GalSim's noll_to_zern ordering)
    while len(ns) <= j:
        n = ns[-1] + 1
        ns.extend([n] * (n + 1))
        if n % 2 == 0:
            ms.append(0)
            m = 2
        else:
            m = 1
        pm = 1 if (n // 2) % 2 == 0 else -1
        while m <= n:
            ms.extend([pm * m, -pm * m])
            m += 2
    return ns[j], ms[j]


def zernike(j: int, rho, theta) -> np.ndarray:
    """Noll-normalised Zernike ``Z_j`` (RMS 1 over the unit disk) at polar pupil coordinates."""
    n, m = noll_to_nm(j)
    am = abs(m)
    r = np.zeros_like(np.asarray(rho, dtype=float))
    for s in range((n - am) // 2 + 1):
        c = (-1) ** s * math.factorial(n - s) / (math.factorial(s) * math.factorial((n + am) // 2 - s)
                                                 * math.factorial((n - am) // 2 - s))
        r = r + c * rho ** (n - 2 * s)
    if m == 0:
        return math.sqrt(n + 1) * r
    ang = np.cos(am * theta) if m > 0 else np.sin(am * theta)
    return math.sqrt(2 * (n + 1)) * r * ang


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


def _pupil(n_p: int, obscuration: float, zernikes, sub: int = 8):
    """Complex pupil sampled ``n_p`` x ``n_p`` across the aperture diameter (coordinates in
    units of D, sample centres at ``(k + 0.5) / n_p - 0.5``), anti-aliased (area fraction of
    each sample inside the annulus from ``sub`` x ``sub`` sub-samples), times ``exp(2 pi i W)``."""
    xc = (np.arange(n_p) + 0.5) / n_p - 0.5
    off = ((np.arange(sub) + 0.5) / sub - 0.5) / n_p
    x = (xc[:, None] + off[None, :]).ravel() * 2.0  # unit-radius coordinates of the sub-samples
    rho = np.hypot(x[None, :], x[:, None])
    inside = (rho <= 1.0) & (rho >= obscuration)
    area = inside.reshape(n_p, sub, n_p, sub).mean(axis=(1, 3))
    yc2, xc2 = np.meshgrid(2.0 * xc, 2.0 * xc, indexing="ij")
    rc, tc = np.hypot(xc2, yc2), np.arctan2(yc2, xc2)
    wf = np.zeros_like(rc)
    for j, a in zernikes:
        wf += a * zernike(j, rc, tc)
    return xc, area * np.exp(2j * np.pi * wf)


#: Pupil samples across the aperture diameter of the optical model (the wavefront of Zernikes
#: up to index 36 varies over >= 10 samples per cycle; the focal grid is set apart, by MFT).
PUPIL_SAMPLES = 256


def optical_table(lf_px: float, obscuration: float, zernikes, half: int, n: int) -> np.ndarray:
    """Pixel-integrated table of an aberrated annular pupil (monochromatic).

    The focal-plane field on the fine grid is a matrix Fourier transform of the pupil
    (Soummer et al. 2007, Opt. Express 15, 15935): ``E = A_y P A_x^T`` with
    ``A[u, x] = exp(2 pi i x u / lf)`` (x in units of the diameter, u in px), so the pupil's
    sampling and the table's are independent; ``I = |E|^2 / (lf^2 sum |P|^2 dx^2)`` (Parseval)
    has integral 1 over the whole plane.
    """
    length = 2 * half + 4
    u = _grid(n, length)
    xc, p = _pupil(PUPIL_SAMPLES, obscuration, zernikes)
    dx = 1.0 / PUPIL_SAMPLES
    a = np.exp(2j * np.pi * np.outer(u, xc) / lf_px)  # (n L, n_p), the same matrix for both axes
    e = (a @ p @ a.T) * (dx * dx)
    img = (e.real**2 + e.imag**2) / (lf_px * lf_px * float(np.sum(np.abs(p) ** 2)) * dx * dx)
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
    source: ``("star", teff_k)`` (a blackbody) or ``("body", name)`` (Sun x reflectance)."""
    lo, hi = min(camera.response_wavelengths_nm), max(camera.response_wavelengths_nm)
    wl = np.arange(lo, hi + 1e-9, 10.0)
    if source[0] == "star":
        f = spectra.blackbody_w_m2_nm_shape(float(source[1]), wl)
    else:
        f = spectra.solar_irradiance_1au_w_m2_nm(wl) * spectra.reflectance_shape(source[1], wl)
    e = np.asarray(f, dtype=float).reshape(-1) * wl * spectra.response_on_grid(camera, wl)
    return wl, e


def teff_bin(teff_k) -> np.ndarray:
    """Index of the polychromatic star table of each effective temperature."""
    return np.clip(np.searchsorted(np.asarray(TEFF_BIN_EDGES_K[1:-1]), np.asarray(teff_k, dtype=float), side="right"),
                   0, len(_BIN_TEFF_K) - 1)


def lambda_f_px(camera, wavelength_nm) -> np.ndarray:
    return np.asarray(wavelength_nm, dtype=float) * 1e-3 * camera.f_number / camera.pixel_pitch_um


@functools.lru_cache(maxsize=64)
def kernel_for(camera, source=None, flux_fraction_lost: float = 1e-6):
    """The renderer's kernel of the camera's PSF for one source class (cached per camera).

    ``source``: None (monochromatic models), ``("star", bin)`` or ``("body", name)`` for a
    polychromatic Airy. A Gaussian is :class:`~skynav.renderer.psf.GaussianPSF` itself.
    """
    model = camera.psf
    if isinstance(model, GaussianPSFModel):
        return GaussianPSF(model.sigma_px)
    half = int(model.half_size_px(flux_fraction_lost, camera))
    if isinstance(model, AiryPSFModel):
        if model.wavelength_nm is not None:
            lf = float(lambda_f_px(camera, model.wavelength_nm))
            n = fine_sampling(lf)
            return TablePSF((airy_table(lf, [1.0], model.obscuration, half, n),), n, half)
        src = source if source is not None else ("star", int(teff_bin(5800.0)))
        spec = ("star", _BIN_TEFF_K[src[1]]) if src[0] == "star" else src
        wl, e = electron_spectrum(camera, spec)
        lf = lambda_f_px(camera, wl)
        n = fine_sampling(float(lf.min()))
        return TablePSF((airy_table(lf, e, model.obscuration, half, n),), n, half)
    if isinstance(model, OpticalPSFModel):
        lf = float(lambda_f_px(camera, model.wavelength_nm))
        n = fine_sampling(lf)
        return TablePSF((optical_table(lf, model.obscuration, model.zernike_waves, half, n),), n, half)
    if isinstance(model, TabulatedPSFModel):
        tables, n = tabulated_tables(model, half)
        return TablePSF(tables, n, half, grid=model.grid)
    raise TypeError(f"unknown PSF model {model!r}")


def is_polychromatic(camera) -> bool:
    m = camera.psf
    return isinstance(m, AiryPSFModel) and m.wavelength_nm is None
