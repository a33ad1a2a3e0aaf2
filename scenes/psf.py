"""Point-spread-function models of a camera: what its optics do to a point, before any pixel.

A camera carries one model (``Camera.psf``); the renderer (:mod:`skynav.renderer.kernels`) turns it
into pixel-integrated stamps, sweeps them along streaks and convolves resolved bodies with them.
Every model is a frozen value object (equality, hash, pickle, a repr that evals back), written to
scene files, recipes, facility cameras, the ground truth and the manifest by :meth:`to_dict` and
read back by :func:`psf_from_dict`:

- ``{model: gaussian, sigma_px: 0.5}``: a circular Gaussian (``camera.defocus_sigma_px`` is its
  shorthand and the default);
- ``{model: airy, obscuration: 0.0, wavelength_nm: 550}``: Fraunhofer diffraction of the annular
  aperture (central obscuration as a fraction of the diameter) of the camera's f-number at its
  pixel pitch; without ``wavelength_nm``, polychromatic: the sum over the band of the Airy
  patterns weighted by each source's electron spectrum (spectrum x camera response);
- ``{model: optical, obscuration, zernike_waves: {4: 0.5, 7: 0.1}, wavelength_nm}``: the same
  pupil with a wavefront of Noll-indexed Zernike terms (amplitudes in waves RMS at
  ``wavelength_nm``, the normalisation of Noll 1976 and GalSim's ``aberrations``), by FFT;
- ``{model: tabulated, file: psf.npy, oversampling: 4}``: a measured PSF image (``.npy`` or
  ``.fits``, ``oversampling`` samples per pixel, centred on its middle sample, normalised to
  a sum of 1 on load); ``field: [{x_px, y_px, file}, ...]`` instead of ``file``: one image per
  point of a rectangular grid across the field, interpolated bilinearly between grid points
  (:mod:`skynav.scenes.psf_measured`, which also reads these mappings: :func:`psf_from_dict`).

Pixel convention (docs/conventions.md): ``(x, y)`` with x along columns, the centre of the top-left
pixel at ``(0, 0)``. Tables are indexed ``[row, column]`` = ``[y, x]``.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from skynav.infra.errors import ConfigValueError

__all__ = ["GaussianPSFModel", "AiryPSFModel", "OpticalPSFModel", "PSF_MODELS", "MAX_HALF_SIZE_PX", "noll_to_nm",
           "zernike", "FWHM_PER_SIGMA"]

#: Default largest stamp half size of the diffraction and measured models, px (the key
#: ``max_half_px`` changes it): the slow 1/r^3 wings of diffraction leave 2 lambda F / (pi^2 r)
#: of the flux beyond radius r (1.1e-3 beyond 16 px for the paper camera at 550 nm, 7e-4
#: beyond 24 px; 3 % beyond 16 px at lambda F = 2.55 px); the stamps hold the PSF as it is and
#: the light beyond them is not drawn (the truth records each source's ``flux_fraction_drawn``).
#: The stamp's size sets most of a frame's cost; a faint source's is cut further by the
#: renderer (``TableKernel.half_sizes_px``; benchmarks/psf_bench.py measures the cost,
#: docs/performance.md).
MAX_HALF_SIZE_PX = 16


def _check_cap(obj):
    v = obj.max_half_px
    if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or not 2 <= v <= 64:
        raise ConfigValueError("camera.psf.max_half_px", v, "an integer in 2..64 (px)")
    object.__setattr__(obj, "max_half_px", int(v))

PSF_MODELS = ("gaussian", "airy", "optical", "tabulated")


def _num(value, key, *, lo=None, hi=None, allowed="a finite number"):
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) or not math.isfinite(value):
        raise ConfigValueError(key, value, allowed)
    v = float(value)
    if (lo is not None and v < lo) or (hi is not None and v > hi):
        raise ConfigValueError(key, value, allowed)
    return v


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


# ----------------------------------------------------------------------------- widths
#: FWHM / sigma of a Gaussian: the equivalent sigma of a model is its FWHM over this.
FWHM_PER_SIGMA = 2.0 * math.sqrt(2.0 * math.log(2.0))


def _airy_half_width_lf(obscuration: float) -> float:
    """Radius of half maximum of the annular Airy pattern, in units of lambda F (0.5145 for a
    clear aperture): the root of ``a(v)^2 = 1/2`` below the first zero, ``a`` the amplitude
    normalised at the centre, ``v = pi r / (lambda F)``."""
    from scipy.optimize import brentq  # scipy: only a width asks for it
    from scipy.special import j1

    e = float(obscuration)

    def amp(v):
        a = 2.0 * j1(v) / v
        if e > 0:
            a -= e * e * 2.0 * j1(e * v) / (e * v)
        return a / (1.0 - e * e)

    return brentq(lambda v: amp(v) ** 2 - 0.5, 1e-6, 3.0) / math.pi


def _mean_wavelength_nm(camera) -> float:
    """The response-weighted mean wavelength of the camera's band, nm (a flat spectrum's)."""
    wl = np.asarray(camera.response_wavelengths_nm, dtype=float)
    q = np.asarray(camera.response_qe_t, dtype=float)
    return float(np.sum(q * wl) / np.sum(q))


def _half_max_fwhm(image: np.ndarray, step_px: float) -> float:
    """Equivalent FWHM of an image sampled every ``step_px``: the diameter of the disc whose
    area is the area above half the peak (a circular profile's FWHM; any shape's core width)."""
    area = float(np.count_nonzero(image >= 0.5 * image.max())) * step_px * step_px
    return 2.0 * math.sqrt(area / math.pi)



def _lambda_f_px(camera, wavelength_nm: float) -> float:
    """lambda x f-number in pixels (the diffraction scale), with the x pixel pitch."""
    return wavelength_nm * 1e-3 * camera.f_number / camera.pixel_pitch_um


def _diffraction_half_size(camera, flux_fraction: float, wavelength_nm: float, obscuration: float,
                           cap: int = MAX_HALF_SIZE_PX) -> int:
    """Stamp half size holding all but ``flux_fraction`` of an Airy pattern (capped).

    The encircled energy of an (annular) Airy pattern tends to ``1 - 2 / (pi^2 (1 - e) r /
    (lambda F))`` (Born & Wolf 8.5; the obscured pupil's ring spacing is the same, its
    energy in the wings grows as ``1/(1 - e)``); a square of half size ``h`` holds more than the
    circle of radius ``h - 0.5``.
    """
    lf = _lambda_f_px(camera, wavelength_nm)
    r = 2.0 * lf / (math.pi**2 * (1.0 - obscuration) * flux_fraction) + 0.5
    return int(min(cap, max(2, math.ceil(r))))


@dataclass(frozen=True)
class GaussianPSFModel:
    """Circular Gaussian of standard deviation ``sigma_px`` (px): today's default PSF.

    Parameters
    ----------
    sigma_px : float
        Standard deviation, px, in [0, 1000] (0: all the light in one pixel); Andreis et al.
        (2024), Table 4: 0.5 px of defocus.

    Examples
    --------
    >>> from skynav.scenes import GaussianPSFModel
    >>> GaussianPSFModel(0.5).to_dict()
    {'model': 'gaussian', 'sigma_px': 0.5}
    >>> GaussianPSFModel(0.5).half_size_px(1e-6)   # px: a 7 x 7 stamp
    3
    """

    sigma_px: float = 0.5
    model = "gaussian"
    polychromatic = False

    def __post_init__(self):
        object.__setattr__(self, "sigma_px", _num(self.sigma_px, "camera.psf.sigma_px", lo=0.0, hi=1e3, allowed="a number in [0, 1000] px"))

    def half_size_px(self, flux_fraction_lost: float, camera=None) -> int:
        """Stamp half size leaving out less than ``flux_fraction_lost`` (the renderer's rule)."""
        # scipy.special: ~0.2 s to import; the dataset reader imports this module, only sizing a PSF stamp needs it
        from scipy.special import erfinv

        if self.sigma_px == 0.0:
            return 0
        r = math.sqrt(2.0) * self.sigma_px * float(erfinv(math.sqrt(1.0 - flux_fraction_lost)))
        return max(0, int(math.ceil(r - 1e-12)))

    def reach_px(self, camera=None) -> float:
        """How far from a source its light reaches, px (the margin a scene keeps stars within):
        6 sigma."""
        return 6.0 * self.sigma_px

    def fwhm_px(self, camera=None) -> float:
        """Full width at half maximum, px: ``2 sqrt(2 ln 2) sigma``."""
        return FWHM_PER_SIGMA * self.sigma_px

    def equivalent_sigma_px(self, camera=None) -> float:
        """The sigma of the Gaussian of the same FWHM, px: ``sigma_px`` itself."""
        return self.sigma_px

    def to_dict(self) -> dict:
        """The model's mapping (a scene file's ``camera.psf``; :func:`psf_from_dict` inverts it)."""
        return {"model": "gaussian", "sigma_px": self.sigma_px}


@dataclass(frozen=True, kw_only=True)
class AiryPSFModel:
    """Diffraction of an annular aperture at the camera's f-number (the Airy pattern).

    Fraunhofer diffraction at the camera's f-number and pixel pitch; ``wavelength_nm`` None:
    polychromatic, the Airy patterns over the band weighted by each source's electron spectrum.

    Parameters
    ----------
    obscuration : float
        Diameter ratio of the central obstruction, in [0, 0.95].
    wavelength_nm : float or None
        Monochromatic wavelength, nm (None: polychromatic).
    max_half_px : int
        Largest stamp half size, px (the wings beyond are cut; :data:`MAX_HALF_SIZE_PX`).

    References
    ----------
    Born, M. & Wolf, E., Principles of Optics, Sec. 8.5.2 (the Airy pattern); the annular
    aperture's pattern is the difference of two of them.

    Examples
    --------
    >>> from skynav.scenes import AiryPSFModel, paper_camera
    >>> airy = AiryPSFModel(obscuration=0.3, wavelength_nm=550.0)
    >>> airy.to_dict()
    {'model': 'airy', 'obscuration': 0.3, 'wavelength_nm': 550.0}
    >>> airy.half_size_px(1e-6, paper_camera())   # px: capped at max_half_px
    16
    """

    obscuration: float = 0.0
    wavelength_nm: float | None = None
    max_half_px: int = MAX_HALF_SIZE_PX
    model = "airy"

    @property
    def polychromatic(self) -> bool:
        """True without ``wavelength_nm``: the pattern is each source's own spectrum's."""
        return self.wavelength_nm is None

    def __post_init__(self):
        _check_cap(self)
        object.__setattr__(self, "obscuration", _num(self.obscuration, "camera.psf.obscuration", lo=0.0, hi=0.95,
                                                     allowed="a number in [0, 0.95] (diameter ratio)"))
        if self.wavelength_nm is not None:
            object.__setattr__(self, "wavelength_nm", _num(self.wavelength_nm, "camera.psf.wavelength_nm", lo=100.0, hi=20000.0,
                                                           allowed="a wavelength in [100, 20000] nm (or absent: polychromatic)"))

    def half_size_px(self, flux_fraction_lost: float, camera) -> int:
        """Stamp half size leaving out less than ``flux_fraction_lost``, px, at most ``max_half_px``."""
        wl = self.wavelength_nm if self.wavelength_nm is not None else max(camera.response_wavelengths_nm)
        return _diffraction_half_size(camera, flux_fraction_lost, wl, self.obscuration, self.max_half_px)

    def reach_px(self, camera) -> float:
        """How far from a source its light reaches, px: the stamp half size at 1e-6."""
        return float(self.half_size_px(1e-6, camera))

    def fwhm_px(self, camera) -> float:
        """Full width at half maximum of the pattern (before pixel integration), px: 1.029
        lambda F for a clear aperture, narrower with an obscuration; polychromatic: at the
        response-weighted mean wavelength of the camera's band."""
        wl = self.wavelength_nm if self.wavelength_nm is not None else _mean_wavelength_nm(camera)
        return 2.0 * _airy_half_width_lf(self.obscuration) * _lambda_f_px(camera, wl)

    def equivalent_sigma_px(self, camera) -> float:
        """The sigma of the Gaussian of the same FWHM, px (what a detector's matched window or a
        width threshold needs; the Airy's wings are not Gaussian)."""
        return self.fwhm_px(camera) / FWHM_PER_SIGMA

    def to_dict(self) -> dict:
        """The model's mapping (a scene file's ``camera.psf``; :func:`psf_from_dict` inverts it)."""
        d = {"model": "airy", "obscuration": self.obscuration}
        if self.wavelength_nm is not None:
            d["wavelength_nm"] = self.wavelength_nm
        if self.max_half_px != MAX_HALF_SIZE_PX:
            d["max_half_px"] = self.max_half_px
        return d


@dataclass(frozen=True, kw_only=True)
class OpticalPSFModel:
    """Annular pupil with Noll-indexed Zernike aberrations, monochromatic at ``wavelength_nm``.

    ``zernike_waves``: ``((noll_index, waves_rms), ...)`` sorted by index (a mapping is
    accepted and sorted); index 1 (piston) is meaningless and refused, indices run to 36.

    Parameters
    ----------
    wavelength_nm : float
        Wavelength, nm, in [100, 20000].
    obscuration : float
        Diameter ratio of the central obstruction, in [0, 0.95].
    zernike_waves : tuple or dict
        Noll index (2..36) -> amplitude, waves RMS at ``wavelength_nm`` (zeros dropped).
    max_half_px : int
        Largest stamp half size, px.

    References
    ----------
    Noll, R. J. (1976), "Zernike polynomials and atmospheric turbulence", JOSA 66, 207 (the
    indices and normalisation; as GalSim's ``aberrations``).

    Examples
    --------
    >>> from skynav.scenes import OpticalPSFModel
    >>> defocus = OpticalPSFModel(wavelength_nm=550.0, zernike_waves={4: 0.5})
    >>> defocus.zernike_waves, defocus.to_dict()["zernike_waves"]
    (((4, 0.5),), {'4': 0.5})
    """

    wavelength_nm: float
    obscuration: float = 0.0
    zernike_waves: tuple = ()
    max_half_px: int = MAX_HALF_SIZE_PX
    model = "optical"
    polychromatic = False

    def __post_init__(self):
        _check_cap(self)
        object.__setattr__(self, "obscuration", _num(self.obscuration, "camera.psf.obscuration", lo=0.0, hi=0.95,
                                                     allowed="a number in [0, 0.95] (diameter ratio)"))
        object.__setattr__(self, "wavelength_nm", _num(self.wavelength_nm, "camera.psf.wavelength_nm", lo=100.0, hi=20000.0,
                                                       allowed="a wavelength in [100, 20000] nm"))
        z = self.zernike_waves
        items = z.items() if isinstance(z, dict) else z
        out = {}
        for item in items:
            if not (isinstance(item, (tuple, list)) and len(item) == 2):
                raise ConfigValueError("camera.psf.zernike_waves", z, "a mapping of Noll index (2..36) to waves RMS")
            k, v = item
            try:
                j = int(k)
            except (TypeError, ValueError):
                raise ConfigValueError("camera.psf.zernike_waves", k, "Noll indices 2..36") from None
            if j != float(k) or not 2 <= j <= 36:
                raise ConfigValueError("camera.psf.zernike_waves", k, "Noll indices 2..36")
            out[j] = _num(v, f"camera.psf.zernike_waves.{j}", lo=-10.0, hi=10.0, allowed="a number of waves in [-10, 10]")
        object.__setattr__(self, "zernike_waves", tuple(sorted((j, w) for j, w in out.items() if w != 0.0)))

    def half_size_px(self, flux_fraction_lost: float, camera) -> int:
        """Stamp half size leaving out less than ``flux_fraction_lost``, px, at most ``max_half_px``."""
        # aberrations spread the core by about the wavefront slope: 4 lambda F per wave RMS
        waves = math.sqrt(sum(w * w for _, w in self.zernike_waves))
        base = _diffraction_half_size(camera, flux_fraction_lost, self.wavelength_nm, self.obscuration, self.max_half_px)
        extra = 8.0 * waves * _lambda_f_px(camera, self.wavelength_nm)
        return int(min(self.max_half_px, math.ceil(base + extra)))

    def reach_px(self, camera) -> float:
        """How far from a source its light reaches, px: the stamp half size at 1e-6."""
        return float(self.half_size_px(1e-6, camera))

    def fwhm_px(self, camera) -> float:
        """Equivalent full width at half maximum (before pixel integration), px: the diameter
        of the disc whose area is the pattern's area above half its peak (an aberrated pattern
        is not round; the Airy's FWHM without aberrations, to 1 %). The pattern: a 64-sample
        pupil's Fourier transform every lambda F / 32."""
        return _optical_fwhm_px(self, camera)

    def equivalent_sigma_px(self, camera) -> float:
        """The sigma of the Gaussian of the same (equivalent) FWHM, px."""
        return self.fwhm_px(camera) / FWHM_PER_SIGMA

    def to_dict(self) -> dict:
        """The model's mapping (a scene file's ``camera.psf``; :func:`psf_from_dict` inverts it)."""
        d = {"model": "optical", "obscuration": self.obscuration, "wavelength_nm": self.wavelength_nm,
             "zernike_waves": {str(j): w for j, w in self.zernike_waves}}
        if self.max_half_px != MAX_HALF_SIZE_PX:
            d["max_half_px"] = self.max_half_px
        return d


@functools.lru_cache(maxsize=16)
def _optical_fwhm_px(model, camera) -> float:
    """:meth:`OpticalPSFModel.fwhm_px` (cached per model and camera: ~0.1 s)."""
    lf = _lambda_f_px(camera, model.wavelength_nm)
    waves = math.sqrt(sum(w * w for _, w in model.zernike_waves))
    n_p, step = 64, 1.0 / 32.0  # pupil samples; focal step in lambda F
    half = int(math.ceil((3.0 + 8.0 * waves) / step))
    xc = ((np.arange(n_p) + 0.5) / n_p - 0.5) * 2.0  # unit-radius pupil coordinates
    yy, xx = np.meshgrid(xc, xc, indexing="ij")
    rho, theta = np.hypot(xx, yy), np.arctan2(yy, xx)
    wf = sum(a * zernike(j, rho, theta) for j, a in model.zernike_waves) if model.zernike_waves else 0.0
    pupil = np.where((rho <= 1.0) & (rho >= model.obscuration), np.exp(2j * np.pi * wf), 0.0)
    u = np.arange(-half, half + 1) * step  # lambda F
    a = np.exp(np.pi * 1j * np.outer(u, xc))  # x in units of D / 2: exp(2 pi i (x/2) u)
    image = np.abs(a @ pupil @ a.T) ** 2
    return _half_max_fwhm(image, step * lf)
