"""Spectral radiometry: magnitudes and spectra to photo-electrons per second at the detector.

A source with spectral irradiance ``F(lambda)`` at the pupil (W m^-2 nm^-1) gives

    e-/s = A * integral F(lambda) / (h c / lambda) * R(lambda) dlambda

with ``A`` the aperture area (m^2) and ``R`` the camera's QE x T (electrons per photon at the
pupil). Multiply by ``camera.exposure_s`` for electrons per frame.

Magnitudes are Johnson V in the Vega system, synthetic and photon-counting:
``V = -2.5 log10(N / N_Vega) + VEGA_V_MAG`` with ``N = integral F S_E dlambda`` (see
:func:`skynav.renderer.spectra.photon_weighted_v_flux`), CALSPEC Vega and ``VEGA_V_MAG = 0.03``.

* Stars: a blackbody at ``teff_k`` scaled to the catalog V. A table of e-/s and in-band
  irradiance at V = 0 over a fine log-Teff grid (1000-60000 K, 600 nodes, cubic spline in
  log T resampled to 20000 nodes read linearly; < 1e-6 relative error) makes thousands of stars cost microseconds.
* Bodies (unresolved planets, moons): the solar spectrum at 1 AU times the body's relative
  reflectance (:func:`skynav.renderer.spectra.reflectance_shape`) scaled to the body's V.
* Zero point ``zero_point_e_per_s``: the CALSPEC Vega spectrum itself scaled to V = 0 (the A0V
  standard); a 9600 K blackbody at V = 0 differs from it by the Balmer and Paschen features
  (see ``zero_point_blackbody_e_per_s``).
"""

from __future__ import annotations

import functools

import numpy as np
from scipy.interpolate import CubicSpline

from skynav.scenes.constants import C_M_S as _C_M_S
from skynav.scenes.constants import PLANCK_J_S as _H_J_S

from . import spectra

__all__ = ["Radiometry", "TEFF_TABLE_RANGE_K", "FINE_STEP_NM"]

#: Effective-temperature span of the star table, K (values outside are clipped to it).
TEFF_TABLE_RANGE_K = (1000.0, 60000.0)
_N_TEFF = 600
_N_TEFF_DENSE = 20000

#: Step of the internal integration grid, nm (fine enough to resolve CALSPEC Vega's lines
#: and the solar Fraunhofer structure to better than 1e-4 in band integrals).
FINE_STEP_NM = 0.25


_LN10_OVER_2P5 = np.log(10.0) / 2.5


def _photons_per_joule(wl_nm):
    """lambda / (h c): photons per joule at wavelength ``wl_nm``."""
    return np.asarray(wl_nm, dtype=float) * 1e-9 / (_H_J_S * _C_M_S)


class Radiometry:
    """Electrons per second of stars and bodies through one camera.

    Build with :meth:`for_camera` (cached per camera: the camera is hashable).

    Attributes
    ----------
    camera : skynav.scenes.camera.Camera
        The camera (aperture, QE x T, band).
    aperture_area_m2 : float
        Entrance pupil area, m^2.
    band_nm : tuple of float
        Wavelength span where the camera response is tabulated, nm (the band of the
        ``*_irradiance_w_m2`` figures).
    zero_point_e_per_s : float
        e-/s of the Vega spectrum scaled to V = 0 (A0V standard).
    zero_point_blackbody_e_per_s : float
        e-/s of a 9600 K blackbody at V = 0.

    Examples
    --------
    >>> from skynav.renderer import Radiometry
    >>> from skynav.scenes import paper_camera
    >>> rad = Radiometry.for_camera(paper_camera())
    >>> rad.band_nm, f"{rad.zero_point_e_per_s:.3g}"   # nm; e-/s of Vega at V = 0
    ((350.0, 1050.0), '5.8e+06')
    >>> f"{float(rad.star_electrons_per_s(5.0, 5800.0)):.3g}"   # a V = 5 solar-type star, e-/s
    '6.65e+04'
    """

    def __init__(self, camera):
        self.camera = camera
        self.aperture_area_m2 = float(camera.aperture_area_m2)
        rw = np.asarray(camera.response_wavelengths_nm, dtype=float)
        self.band_nm = (float(rw.min()), float(rw.max()))
        n = int(round((self.band_nm[1] - self.band_nm[0]) / FINE_STEP_NM))
        self._wl = np.linspace(self.band_nm[0], self.band_nm[1], n + 1)
        # electrons per (W m^-2 nm^-1) per nm on the fine grid: A * lambda/(h c) * R
        self._e_kernel = self.aperture_area_m2 * _photons_per_joule(self._wl) * spectra.response_on_grid(camera, self._wl)
        lo, hi = spectra.v_passband_range_nm()
        nv = int(round((hi - lo) / FINE_STEP_NM))
        self._wl_v = np.linspace(lo, hi, nv + 1)
        self._n_vega = float(spectra.photon_weighted_v_flux(self._wl_v, spectra.vega_spectrum_w_m2_nm(self._wl_v)))

        # Vega at V = 0
        vega_scale = 10.0 ** (0.4 * spectra.VEGA_V_MAG)
        self.zero_point_e_per_s = vega_scale * self._band_electrons(spectra.vega_spectrum_w_m2_nm(self._wl))

        # star table at V = 0 versus log Teff
        self._log_teff = np.linspace(np.log(TEFF_TABLE_RANGE_K[0]), np.log(TEFF_TABLE_RANGE_K[1]), _N_TEFF)
        teff = np.exp(self._log_teff)
        scale = self._v0_scale(spectra.blackbody_w_m2_nm_shape(teff, self._wl_v))  # (T,)
        bb = spectra.blackbody_w_m2_nm_shape(teff, self._wl)  # (T, M)
        e0 = scale * self._band_electrons(bb)
        irr0 = scale * np.trapezoid(bb, self._wl, axis=-1)
        # dense lookup tables from the cubic spline, read with np.interp (linear in log T:
        # < 1e-7 relative error, cheaper than evaluating the spline)
        self._log_teff_dense = np.linspace(self._log_teff[0], self._log_teff[-1], _N_TEFF_DENSE)
        self._log_e0_dense = CubicSpline(self._log_teff, np.log(e0))(self._log_teff_dense)
        self._log_irr0_dense = CubicSpline(self._log_teff, np.log(irr0))(self._log_teff_dense)
        self.zero_point_blackbody_e_per_s = float(self.star_electrons_per_s(0.0, 9600.0))
        self._body_cache: dict = {}

    # ------------------------------------------------------------------ construction
    @classmethod
    def for_camera(cls, camera) -> "Radiometry":
        """The (cached) radiometry of ``camera``.

        Parameters
        ----------
        camera : skynav.scenes.camera.Camera
            The camera (hashable: one radiometry per camera).

        Returns
        -------
        Radiometry
            The same object for an equal camera.
        """
        return _for_camera(camera)

    def __repr__(self) -> str:
        return f"Radiometry.for_camera({self.camera!r})"

    # ------------------------------------------------------------------ helpers
    def _band_electrons(self, flux_w_m2_nm):
        return np.trapezoid(np.asarray(flux_w_m2_nm) * self._e_kernel, self._wl, axis=-1)

    def _v0_scale(self, shape_on_v_grid):
        """Factor that brings a spectral shape (sampled on the V grid) to V = 0."""
        n = spectra.photon_weighted_v_flux(self._wl_v, shape_on_v_grid)
        # V = -2.5 log10(n / n_vega) + V_vega = 0  =>  n = n_vega 10^(0.4 V_vega)
        return self._n_vega * 10.0 ** (0.4 * spectra.VEGA_V_MAG) / n

    @staticmethod
    def _mag_factor(v_mag):
        return 10.0 ** (-0.4 * np.asarray(v_mag, dtype=float))

    def _lookup(self, table, teff_k):
        """Linear interpolation on the uniform log-Teff grid by direct indexing (np.interp's
        binary search costs more for many unsorted queries)."""
        t = np.clip(np.asarray(teff_k, dtype=float), *TEFF_TABLE_RANGE_K)
        u = (np.log(t) - self._log_teff_dense[0]) * ((_N_TEFF_DENSE - 1) / (self._log_teff_dense[-1] - self._log_teff_dense[0]))
        i = np.minimum(u.astype(np.intp), _N_TEFF_DENSE - 2)
        f = u - i
        return table[i] * (1.0 - f) + table[i + 1] * f

    # ------------------------------------------------------------------ general
    def electrons_per_s_from_spectral_irradiance(self, irradiance_w_m2_nm, wavelengths_nm=None) -> np.ndarray:
        """Photo-electrons per second of a spectral irradiance at the pupil.

        Parameters
        ----------
        irradiance_w_m2_nm : ndarray, shape (..., M), W m^-2 nm^-1
            Sampled on ``wavelengths_nm`` (default :data:`spectra.WAVELENGTHS_NM`, the grid
            shared with the Mitsuba path).
        wavelengths_nm : ndarray, shape (M,), nm, optional

        Returns
        -------
        ndarray, shape (...), e-/s

        Notes
        -----
        Trapezoid rule on the given grid of ``E * lambda/(h c) * R * A``, with ``R`` the camera
        response interpolated onto that grid. For smooth spectra (blackbodies) on the 5 nm
        shared grid it agrees with the fine-grid star table to ~1e-4.
        """
        wl = spectra.WAVELENGTHS_NM if wavelengths_nm is None else np.asarray(wavelengths_nm, dtype=float)
        k = self.aperture_area_m2 * _photons_per_joule(wl) * spectra.response_on_grid(self.camera, wl)
        return np.trapezoid(np.asarray(irradiance_w_m2_nm, dtype=float) * k, wl, axis=-1)

    def v_mag_of_spectrum(self, irradiance_w_m2_nm, wavelengths_nm) -> np.ndarray:
        """Synthetic Johnson V magnitude (photon-counting, Vega = 0.03) of a spectrum.

        Parameters
        ----------
        irradiance_w_m2_nm : ndarray, shape (..., M), W m^-2 nm^-1
        wavelengths_nm : ndarray, shape (M,), nm, covering 475-740 nm

        Returns
        -------
        ndarray, shape (...), mag
        """
        n = spectra.photon_weighted_v_flux(wavelengths_nm, irradiance_w_m2_nm)
        return -2.5 * np.log10(n / self._n_vega) + spectra.VEGA_V_MAG

    # ------------------------------------------------------------------ stars
    def star_electrons_per_s(self, v_mag, teff_k) -> np.ndarray:
        """e-/s of blackbody stars of V magnitude ``v_mag`` and temperature ``teff_k``.

        Parameters
        ----------
        v_mag : array_like, mag
        teff_k : array_like, K (broadcast with ``v_mag``; clipped to TEFF_TABLE_RANGE_K)

        Returns
        -------
        ndarray, broadcast shape, e-/s
        """
        log_e0 = self._lookup(self._log_e0_dense, teff_k)
        return np.exp(log_e0 - _LN10_OVER_2P5 * np.asarray(v_mag, dtype=float))

    def star_irradiance_w_m2(self, v_mag, teff_k) -> np.ndarray:
        """In-band irradiance at the pupil (integral of F over the response's span ``band_nm``).

        Parameters
        ----------
        v_mag : array_like, mag
        teff_k : array_like, K

        Returns
        -------
        ndarray, broadcast shape, W m^-2
        """
        log_i0 = self._lookup(self._log_irr0_dense, teff_k)
        return np.exp(log_i0 - _LN10_OVER_2P5 * np.asarray(v_mag, dtype=float))

    def star_spectral_irradiance_w_m2_nm(self, v_mag, teff_k, wavelengths_nm=None) -> np.ndarray:
        """Spectral irradiance of one blackbody star normalised to ``v_mag``.

        Parameters
        ----------
        v_mag : float, mag
        teff_k : float, K
        wavelengths_nm : ndarray, shape (M,), nm (default ``spectra.WAVELENGTHS_NM``)

        Returns
        -------
        ndarray, shape (M,), W m^-2 nm^-1
        """
        wl = spectra.WAVELENGTHS_NM if wavelengths_nm is None else np.asarray(wavelengths_nm, dtype=float)
        scale = self._v0_scale(spectra.blackbody_w_m2_nm_shape(teff_k, self._wl_v))
        return scale * self._mag_factor(v_mag) * spectra.blackbody_w_m2_nm_shape(teff_k, wl)

    # ------------------------------------------------------------------ bodies
    def _body_v0(self, body):
        key = str(body).strip().lower()
        hit = self._body_cache.get(key)
        if hit is None:
            shape_v = spectra.solar_irradiance_1au_w_m2_nm(self._wl_v) * spectra.reflectance_shape(key, self._wl_v)
            scale = float(self._v0_scale(shape_v))
            shape = spectra.solar_irradiance_1au_w_m2_nm(self._wl) * spectra.reflectance_shape(key, self._wl)
            hit = (scale, scale * float(self._band_electrons(shape)), scale * float(np.trapezoid(shape, self._wl)))
            self._body_cache[key] = hit
        return hit

    def body_electrons_per_s(self, body, v_mag) -> np.ndarray:
        """e-/s of an unresolved body of V magnitude ``v_mag`` (Sun x reflectance shape).

        Parameters
        ----------
        body : str
            Body name (see :func:`spectra.reflectance_shape`; unknown names are grey).
        v_mag : array_like, mag

        Returns
        -------
        ndarray, shape of ``v_mag``, e-/s
        """
        return self._body_v0(body)[1] * self._mag_factor(v_mag)

    def body_irradiance_w_m2(self, body, v_mag) -> np.ndarray:
        """In-band irradiance at the pupil of a body (over ``band_nm``).

        Parameters
        ----------
        body : str
            Body name (its reflectance shape; unknown names are grey).
        v_mag : array_like
            V magnitude, mag.

        Returns
        -------
        numpy.ndarray, shape of ``v_mag``
            Irradiance, W/m^2.
        """
        return self._body_v0(body)[2] * self._mag_factor(v_mag)

    def body_spectral_irradiance_w_m2_nm(self, body, v_mag, wavelengths_nm=None) -> np.ndarray:
        """Spectral irradiance at the pupil of a body normalised to ``v_mag``.

        Parameters
        ----------
        body : str
            Body name (its reflectance shape; unknown names are grey).
        v_mag : float
            V magnitude, mag.
        wavelengths_nm : array_like, shape (M,), optional
            Wavelengths, nm (default: the shared fine grid over ``band_nm``).

        Returns
        -------
        numpy.ndarray, shape (M,)
            Spectral irradiance, W m^-2 nm^-1, on ``wavelengths_nm``.
        """
        wl = spectra.WAVELENGTHS_NM if wavelengths_nm is None else np.asarray(wavelengths_nm, dtype=float)
        scale = self._body_v0(body)[0]
        return scale * self._mag_factor(v_mag) * spectra.solar_irradiance_1au_w_m2_nm(wl) * spectra.reflectance_shape(body, wl)


@functools.lru_cache(maxsize=32)
def _for_camera(camera) -> Radiometry:
    return Radiometry(camera)
