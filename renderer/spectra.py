"""Spectra shared by the analytic rasteriser and the Mitsuba path: one wavelength grid, the
Vega zero point, the Johnson V passband, the Sun, blackbodies, the camera response and the
relative reflectance of the bodies.

All spectral irradiances are W m^-2 nm^-1 at the pupil; wavelengths are nm (vacuum).

Data sources (installed packages only, nothing downloads):

* Vega: HST CALSPEC ``alpha_lyr_stis_011`` (Bohlin 2014, AJ 147, 127), shipped by ``pyphot``.
* Johnson V: ``GROUND_JOHNSON_V`` (the synphot/Bessell 1990 ground Johnson V curve; the
  table header says ``DETECTOR energy``: it is an energy response function), shipped by
  ``pyphot``.
* Sun at 1 AU: HST CALSPEC ``sun_reference_stis_001`` (Bohlin, Dickinson & Calzetti 2001,
  AJ 122, 2118), 119.5-2695.7 nm, shipped by ``pyphot``. It integrates to 1326 W m^-2 over its
  span; the missing infrared tail (a 5772 K blackbody beyond 2.7 um) brings it to the solar
  constant 1361 W m^-2 (IAU 2015 B3 nominal; Kopp & Lean 2011) within 0.3 %.
* Blackbodies: colour-science ``planck_law``.

The data tables are read by :mod:`skynav.scenes.reference_spectra` (lazily, from file objects,
cached): the renderer itself opens no file.
"""

from __future__ import annotations

import warnings

import numpy as np

from skynav.scenes.constants import SOLAR_CONSTANT_W_M2

__all__ = [
    "WAVELENGTHS_NM",
    "VEGA_V_MAG",
    "V_PASSBAND_RESPONSE",
    "vega_spectrum_w_m2_nm",
    "johnson_v_passband",
    "solar_irradiance_1au_w_m2_nm",
    "solar_spectrum_range_nm",
    "blackbody_w_m2_nm_shape",
    "response_on_grid",
    "reflectance_shape",
    "teff_from_b_minus_v",
    "photon_weighted_v_flux",
    "SOLAR_CONSTANT_W_M2",
]

#: The one wavelength grid shared with the Mitsuba path, nm: 350..1050 every 5 nm (141 samples).
#: It covers the camera response of ``skynav.scenes.camera.default_response_curve``.
WAVELENGTHS_NM = np.arange(350.0, 1050.0 + 0.5 * 5.0, 5.0)
WAVELENGTHS_NM.setflags(write=False)

#: Johnson V magnitude of Vega (Bessell & Murphy 2012, PASP 124, 140: V = 0.03). The V
#: magnitude system is ``V = -2.5 log10(N / N_Vega) + VEGA_V_MAG`` with ``N`` the photon-counting
#: in-band signal (see :func:`photon_weighted_v_flux`).
VEGA_V_MAG = 0.03

#: Total solar irradiance at 1 AU, W m^-2: :data:`skynav.scenes.constants.SOLAR_CONSTANT_W_M2`
#: (IAU 2015 B3 nominal 1361; a reference figure only, the solar spectrum is the CALSPEC table).

#: How the library tabulates the V curve: ``"energy"`` (response per unit energy). A
#: photon-counting detector with this energy response has a photon response ``S_E / lambda``.
V_PASSBAND_RESPONSE = "energy"


# ------------------------------------------------------------------------------- data tables
# Read by the scenes adapter (skynav.scenes.reference_spectra): the renderer does no file I/O.
from skynav.scenes.reference_spectra import johnson_v_table as _v_table  # noqa: E402
from skynav.scenes.reference_spectra import read_calspec, read_synphot_csv  # noqa: E402,F401  (re-exported)
from skynav.scenes.reference_spectra import sun_table as _sun_table  # noqa: E402
from skynav.scenes.reference_spectra import vega_table as _vega_table  # noqa: E402


def _interp0(wl, x, y):
    """Linear interpolation, zero outside the table."""
    return np.interp(np.asarray(wl, dtype=float), x, y, left=0.0, right=0.0)


# ------------------------------------------------------------------------------- spectra
def vega_spectrum_w_m2_nm(wl) -> np.ndarray:
    """Spectral irradiance of Vega at the Earth (CALSPEC ``alpha_lyr_stis_011``).

    Parameters
    ----------
    wl : array_like, nm

    Returns
    -------
    ndarray, same shape as ``wl``, W m^-2 nm^-1 (linear interpolation; 0 outside 90-300000 nm)

    Examples
    --------
    >>> 3.3e-11 < float(vega_spectrum_w_m2_nm(550.0)) < 3.8e-11
    True
    """
    x, y = _vega_table()
    return _interp0(wl, x, y)


def johnson_v_passband(wl) -> np.ndarray:
    """Johnson V energy response function ``S_E(lambda)``, peak-normalised to 1.

    Library: pyphot ``GROUND_JOHNSON_V`` (synphot's ground Johnson V, after Bessell 1990,
    PASP 102, 1181). Zero outside 475-700 nm.

    Parameters
    ----------
    wl : array_like, nm

    Returns
    -------
    ndarray, same shape as ``wl``, dimensionless
    """
    x, y = _v_table()
    return _interp0(wl, x, y)


def v_passband_range_nm() -> tuple[float, float]:
    """Wavelength span of the V table, nm."""
    x, _ = _v_table()
    return float(x[0]), float(x[-1])


def photon_weighted_v_flux(wl, flux_w_m2_nm) -> np.ndarray:
    """Photon-counting V-band signal of a spectrum, up to a constant.

    A photon-counting detector with the library's energy response ``S_E`` has photon response
    ``S_E / lambda`` (Bessell & Murphy 2012, appendix), so its count rate is proportional to
    ``integral F(lambda) lambda (S_E / lambda) dlambda = integral F S_E dlambda``. Magnitudes
    are ratios of this quantity to Vega's.

    Parameters
    ----------
    wl : ndarray, shape (M,), nm, ascending, covering the V band (475-700 nm)
    flux_w_m2_nm : ndarray, shape (..., M), W m^-2 nm^-1

    Returns
    -------
    ndarray, shape (...), W m^-2 (in-band, V-response weighted)
    """
    wl = np.asarray(wl, dtype=float)
    s = johnson_v_passband(wl)
    return np.trapezoid(np.asarray(flux_w_m2_nm, dtype=float) * s, wl, axis=-1)


def solar_irradiance_1au_w_m2_nm(wl) -> np.ndarray:
    """Solar spectral irradiance at 1 AU (CALSPEC ``sun_reference_stis_001``).

    Parameters
    ----------
    wl : array_like, nm

    Returns
    -------
    ndarray, same shape as ``wl``, W m^-2 nm^-1 (zero outside 119.5-2695.7 nm)

    Notes
    -----
    Over the table's span it integrates to 1326 W m^-2; over the camera band (350-1050 nm)
    to about 830 W m^-2 (61 % of the solar constant).
    """
    x, y = _sun_table()
    return _interp0(wl, x, y)


def solar_spectrum_range_nm() -> tuple[float, float]:
    """Wavelength span of the solar table, nm."""
    x, _ = _sun_table()
    return float(x[0]), float(x[-1])


def blackbody_w_m2_nm_shape(teff_k, wl) -> np.ndarray:
    """Planck spectral radiance ``B_lambda(T)`` (colour-science ``planck_law``), as a shape.

    Parameters
    ----------
    teff_k : float or ndarray, shape (N,), K
    wl : ndarray, shape (M,), nm

    Returns
    -------
    ndarray, shape (M,) for scalar ``teff_k`` else (N, M); W m^-2 sr^-1 nm^-1 (the absolute
    scale is meaningless for a star: callers normalise it to a magnitude).
    """
    with warnings.catch_warnings():
        # colour-science warns at import that matplotlib (plotting only) is absent
        warnings.simplefilter("ignore")
        # colour-science: ~1 s to import, only the blackbody shape needs it
        from colour.colorimetry import planck_law

    wl = np.asarray(wl, dtype=float)
    t = np.asarray(teff_k, dtype=float)
    # planck_law takes metres, ravels both inputs and returns (M, N) (squeezed), in
    # W sr^-1 m^-2 m^-1
    b = np.asarray(planck_law(wl.ravel() * 1e-9, t.ravel()), dtype=float).reshape(wl.size, t.size)
    return (b.T * 1e-9).reshape(t.shape + wl.shape)


def response_on_grid(camera, wl) -> np.ndarray:
    """The camera's QE x T interpolated (linear) on ``wl``; zero outside its table.

    Parameters
    ----------
    camera : skynav.scenes.camera.Camera
    wl : array_like, nm

    Returns
    -------
    ndarray, same shape as ``wl``, dimensionless (electrons per photon at the pupil)
    """
    return _interp0(wl, np.asarray(camera.response_wavelengths_nm), np.asarray(camera.response_qe_t))


def teff_from_b_minus_v(b_minus_v) -> np.ndarray:
    """Effective temperature of a star from its B-V colour (Ballesteros 2012, EPL 97, 34008).

    ``T = 4600 K (1 / (0.92 (B-V) + 1.7) + 1 / (0.92 (B-V) + 0.62))``; B-V is clipped to
    [-0.4, 2.5] (the formula's blackbody fit range).

    Parameters
    ----------
    b_minus_v : array_like, mag

    Returns
    -------
    ndarray, same shape, K
    """
    bv = np.clip(np.asarray(b_minus_v, dtype=float), -0.4, 2.5)
    return 4600.0 * (1.0 / (0.92 * bv + 1.7) + 1.0 / (0.92 * bv + 0.62))


# ------------------------------------------------------------------------------- reflectance
def _logistic(x):
    return 1.0 / (1.0 + np.exp(-x))


def _band(wl, centre_nm, fwhm_nm, depth):
    """Multiplicative absorption band ``1 - depth * gaussian``."""
    sig = fwhm_nm / 2.3548
    return 1.0 - depth * np.exp(-0.5 * ((wl - centre_nm) / sig) ** 2)


def _refl_mars(wl):
    # Red slope of the bright regions: geometric albedo ~0.10 at 450 nm rising to ~0.30 at
    # 700 nm and flat to 1 um (Mallama 2007, Icarus 192, 404, fig. 3; Bell et al. 1990).
    return 0.09 + 0.21 * _logistic((wl - 590.0) / 35.0)


def _refl_moon(wl):
    # Smooth red slope: reflectance roughly doubles from 400 to 1000 nm (Lane & Irvine 1973,
    # AJ 78, 267; ROLO, Kieffer & Stone 2005, AJ 129, 2887).
    return 0.6 + 0.8 * (wl - 400.0) / 600.0


def _refl_jupiter(wl):
    # Karkoschka 1994 (Icarus 111, 174) full-disk albedo: blue-absorbing hazes below 500 nm,
    # CH4 bands at 619, 727, 890 nm (depths ~0.15, 0.45, 0.9) and 1000 nm.
    base = 0.35 + 0.2 * _logistic((wl - 480.0) / 40.0)
    return base * _band(wl, 619.0, 12.0, 0.15) * _band(wl, 727.0, 15.0, 0.45) * _band(wl, 890.0, 30.0, 0.9) * _band(wl, 1000.0, 40.0, 0.3)


def _refl_saturn(wl):
    # Karkoschka 1994: like Jupiter, slightly redder continuum, CH4 bands a little weaker.
    base = 0.3 + 0.3 * _logistic((wl - 500.0) / 45.0)
    return base * _band(wl, 619.0, 12.0, 0.12) * _band(wl, 727.0, 15.0, 0.4) * _band(wl, 890.0, 30.0, 0.85) * _band(wl, 1000.0, 40.0, 0.3)


def _refl_uranus_neptune(wl):
    # Karkoschka 1994: strong CH4 absorption longward of 600 nm (blue-green colour).
    base = 0.55 - 0.1 * _logistic((wl - 500.0) / 40.0)
    return base * _band(wl, 619.0, 15.0, 0.4) * _band(wl, 727.0, 20.0, 0.8) * _band(wl, 790.0, 40.0, 0.6) * _band(wl, 890.0, 40.0, 0.97) * _band(wl, 1000.0, 60.0, 0.8)


def _refl_mercury(wl):
    # Steep red slope of Mercury's regolith (Mallama et al. 2002, Icarus 155, 253).
    return 0.5 + 1.0 * (wl - 400.0) / 600.0


def _refl_venus(wl):
    # Venus clouds: UV absorber below ~500 nm, flat in the visible-NIR (Mallama et al. 2006).
    return 0.6 + 0.3 * _logistic((wl - 450.0) / 30.0)


_REFLECTANCE = {
    "mars": _refl_mars,
    "moon": _refl_moon,
    "jupiter": _refl_jupiter,
    "saturn": _refl_saturn,
    "uranus": _refl_uranus_neptune,
    "neptune": _refl_uranus_neptune,
    "mercury": _refl_mercury,
    "venus": _refl_venus,
}


def reflectance_shape(body, wl) -> np.ndarray:
    """Relative spectral reflectance of a body, normalised to 1 at 550 nm.

    Smooth documented shapes (sources in the per-body functions); flat (1) for an unknown
    body or the Earth. Only the shape matters: bodies are normalised to their V magnitude.

    Parameters
    ----------
    body : str
        Body name (case-insensitive; "mars barycenter" style names use their first word).
    wl : array_like, nm

    Returns
    -------
    ndarray, same shape as ``wl``, dimensionless, > 0
    """
    wl = np.asarray(wl, dtype=float)
    key = str(body).strip().lower().split()[0] if str(body).strip() else ""
    fn = _REFLECTANCE.get(key)
    if fn is None:
        return np.ones_like(wl)
    return fn(wl) / fn(np.array(550.0))
