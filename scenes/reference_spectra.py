"""The reference spectra: Vega, the Sun and the Johnson V passband, read from installed tables.

Adapter for the data tables that the ``pyphot`` package installs (its code is not imported:
importing pyphot pulls pandas and h5py). Nothing downloads. The tables are read lazily (first
call), from file objects, and cached; the renderer's spectra (``skynav.renderer.spectra``) build
on them without opening files themselves.

Sources
-------
* Vega: HST CALSPEC ``alpha_lyr_stis_011`` (Bohlin 2014, AJ 147, 127).
* Sun at 1 AU: HST CALSPEC ``sun_reference_stis_001`` (Bohlin, Dickinson & Calzetti 2001,
  AJ 122, 2118), 119.5-2695.7 nm.
* Johnson V: ``GROUND_JOHNSON_V`` (synphot's ground Johnson V after Bessell 1990; an energy
  response function).
"""

from __future__ import annotations

import functools
import io
import os
import warnings

import numpy as np
from astropy.io import fits

from skynav.infra.data_files import pyphot_table_path

__all__ = ["read_calspec", "read_synphot_csv", "vega_table", "sun_table", "johnson_v_table"]

_FLAM_TO_W_M2_NM = 1e-7 / 1e-4 * 10.0  # erg s^-1 cm^-2 A^-1 -> W m^-2 nm^-1  (= 1e-2)


def read_calspec(fobj) -> tuple[np.ndarray, np.ndarray]:
    """Read a CALSPEC FITS table (``WAVELENGTH`` in Angstrom, ``FLUX`` in FLAM).

    Parameters
    ----------
    fobj : binary file object

    Returns
    -------
    wavelength_nm : ndarray, shape (M,), nm
    flux_w_m2_nm : ndarray, shape (M,), W m^-2 nm^-1
    """
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # CALSPEC headers carry float TNULLn: harmless VerifyWarning
        with fits.open(io.BytesIO(fobj.read())) as hdul:
            data = hdul[1].data
            wl = np.asarray(data["WAVELENGTH"], dtype=float) / 10.0
            fl = np.asarray(data["FLUX"], dtype=float) * _FLAM_TO_W_M2_NM
    good = np.isfinite(fl) & (fl >= 0)
    return wl[good], fl[good]


def read_synphot_csv(fobj) -> tuple[np.ndarray, np.ndarray]:
    """Read a pyphot ASCII filter table (``WAVELENGTH`` in Angstrom, ``THROUGHPUT``).

    Returns
    -------
    wavelength_nm : ndarray, shape (M,), nm
    throughput : ndarray, shape (M,), dimensionless
    """
    text = fobj.read().decode("ascii")
    rows = [ln for ln in text.splitlines() if ln and not ln.startswith("#") and not ln.startswith("WAVELENGTH")]
    arr = np.array([[float(v) for v in ln.split(",")] for ln in rows])
    return arr[:, 0] / 10.0, arr[:, 1]


@functools.lru_cache(maxsize=None)
def vega_table() -> tuple[np.ndarray, np.ndarray]:
    """Vega (CALSPEC ``alpha_lyr_stis_011``): wavelength_nm (M,), flux W m^-2 nm^-1 (M,)."""
    with open(pyphot_table_path("alpha_lyr_stis_011.fits"), "rb") as f:
        return read_calspec(f)


@functools.lru_cache(maxsize=None)
def sun_table() -> tuple[np.ndarray, np.ndarray]:
    """The Sun at 1 AU (CALSPEC ``sun_reference_stis_001``): wavelength_nm, W m^-2 nm^-1."""
    with open(pyphot_table_path("sun_reference_stis_001.fits"), "rb") as f:
        return read_calspec(f)


@functools.lru_cache(maxsize=None)
def johnson_v_table() -> tuple[np.ndarray, np.ndarray]:
    """Johnson V energy response, sorted, clipped at 0 and normalised to a peak of 1."""
    with open(pyphot_table_path(os.path.join("ascii_sources", "ground_johnson_v.csv")), "rb") as f:
        wl, t = read_synphot_csv(f)
    order = np.argsort(wl)
    wl, t = wl[order], np.clip(t[order], 0.0, None)
    return wl, t / t.max()
