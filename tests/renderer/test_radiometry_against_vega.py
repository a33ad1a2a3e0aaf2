"""Radiometry against an independent direct integration of the CALSPEC Vega spectrum.

The oracle here reads the library's tables with its own code (astropy.io.fits.getdata on the FITS file,
numpy.loadtxt on the V curve), integrates on the tables' native wavelength samples with
Simpson's rule, and uses its own Planck formula; it shares no code path with the renderer's
tabulated radiometry (0.25 nm grid, colour's planck_law, log-Teff lookup table).
"""

from __future__ import annotations

import importlib.util
import os
import warnings

import numpy as np
import pytest
from scipy.integrate import simpson

from skynav.renderer import spectra
from skynav.renderer.radiometry import Radiometry
from skynav.scenes.camera import paper_camera

H = 6.62607015e-34  # J s (SI exact)
C = 299792458.0  # m/s (SI exact)
KB = 1.380649e-23  # J/K (SI exact)


def _libs():
    return os.path.join(list(importlib.util.find_spec("pyphot").submodule_search_locations)[0], "libs")


def _calspec(name):
    from astropy.io import fits

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        t = fits.getdata(os.path.join(_libs(), name), 1)
    wl_nm = np.asarray(t["WAVELENGTH"], float) / 10.0
    f = np.asarray(t["FLUX"], float) * 1e-2  # erg s-1 cm-2 A-1 -> W m-2 nm-1
    return wl_nm, f


def _v_curve():
    a = np.loadtxt(os.path.join(_libs(), "ascii_sources", "ground_johnson_v.csv"), delimiter=",", comments="#", skiprows=9)
    return a[:, 0] / 10.0, a[:, 1]


def _planck(wl_nm, t_k):
    lam = wl_nm * 1e-9
    return 2 * H * C**2 / lam**5 / np.expm1(H * C / (lam * KB * t_k))


def _teff_ballesteros(bv):
    # Ballesteros (2012), EPL 97, 34008, eq. 14
    return 4600.0 * (1.0 / (0.92 * bv + 1.7) + 1.0 / (0.92 * bv + 0.62))


@pytest.fixture(scope="module")
def cam():
    return paper_camera()


@pytest.fixture(scope="module")
def rad(cam):
    return Radiometry.for_camera(cam)


def _direct_electrons_per_s(cam, wl_nm, flux_w_m2_nm):
    rw, rq = np.asarray(cam.response_wavelengths_nm), np.asarray(cam.response_qe_t)
    m = (wl_nm >= rw[0]) & (wl_nm <= rw[-1])
    wl, f = wl_nm[m], flux_w_m2_nm[m]
    r = np.interp(wl, rw, rq)
    return cam.aperture_area_m2 * simpson(f * r * wl * 1e-9 / (H * C), x=wl)


def _direct_v_signal(wl_nm, flux_fn):
    vw, vt = _v_curve()
    # energy response curve -> photon-counting signal integral F S_E dlambda (Bessell & Murphy 2012)
    return simpson(flux_fn(vw) * vt, x=vw)


def test_v0_vega_zero_point_matches_direct_integration(cam, rad):
    wl, f = _calspec("alpha_lyr_stis_011.fits")
    f_v0 = f * 10 ** (0.4 * 0.03)  # Vega has V = 0.03 (Bessell & Murphy 2012)
    direct = _direct_electrons_per_s(cam, wl, f_v0)
    print(f"\nzero point (Vega scaled to V=0, paper camera): {rad.zero_point_e_per_s:.4e} e-/s"
          f" = {rad.zero_point_e_per_s * cam.exposure_s:.4e} e- in {cam.exposure_s} s; direct {direct:.4e}")
    print(f"9600 K blackbody at V=0: {rad.zero_point_blackbody_e_per_s:.4e} e-/s")
    # 1 %: the two integrations differ only in grids/quadrature; a wrong unit or constant is >> 1 %
    assert rad.zero_point_e_per_s == pytest.approx(direct, rel=0.01)
    # order of magnitude sanity: V=0 is ~1e8 photons/s/m^2/nm at 550 nm; 2.6e-4 m^2, ~0.5 QE, ~300 nm band
    assert 1e6 < rad.zero_point_e_per_s < 2e7


@pytest.mark.parametrize("bv", [-0.3, 0.0, 0.3, 0.65, 1.0, 1.5, 2.0])
def test_colour_dependence_matches_direct_integration(cam, rad, bv):
    teff = _teff_ballesteros(bv)
    wlv, fv = _calspec("alpha_lyr_stis_011.fits")
    n_vega = _direct_v_signal(wlv, lambda w: np.interp(w, wlv, fv))
    n_bb = _direct_v_signal(wlv, lambda w: _planck(w, teff))
    v_mag = 4.2
    scale = n_vega / n_bb * 10 ** (-0.4 * (v_mag - 0.03))
    wl = np.linspace(350.0, 1050.0, 1401)
    direct = _direct_electrons_per_s(cam, wl, scale * _planck(wl, teff))
    got = rad.star_electrons_per_s(v_mag, teff)
    # 1 %: the brief's tolerance; the implementation agrees to ~1e-5 (quadrature only)
    assert got == pytest.approx(direct, rel=0.01)
    direct_irr = simpson(scale * _planck(wl, teff), x=wl)
    assert rad.star_irradiance_w_m2(v_mag, teff) == pytest.approx(direct_irr, rel=0.01)


def test_star_table_batch_equals_scalar_and_magnitude_law(rad):
    rng = np.random.default_rng(7)
    v = rng.uniform(-1, 8, 50)
    t = rng.uniform(2500, 30000, 50)
    batch = rad.star_electrons_per_s(v, t)
    loop = np.array([rad.star_electrons_per_s(a, b) for a, b in zip(v, t)])
    np.testing.assert_allclose(batch, loop, rtol=1e-14)
    # 5 magnitudes = factor 100 exactly (Pogson)
    assert rad.star_electrons_per_s(5.0, 6000.0) / rad.star_electrons_per_s(0.0, 6000.0) == pytest.approx(0.01, rel=1e-12)


def test_solar_spectrum_total_vs_solar_constant():
    wl, f = _calspec("sun_reference_stis_001.fits")
    table_total = simpson(f, x=wl)
    # the CALSPEC solar table stops at 2.7 um: add the infrared tail as a 5772 K blackbody
    # (IAU 2015 B3 nominal Teff) scaled to the table's last 100 nm
    red = wl > wl[-1] - 100.0
    k = np.mean(f[red]) / np.mean(_planck(wl[red], 5772.0))
    tail_wl = np.geomspace(wl[-1], 1e6, 20000)
    tail = simpson(k * _planck(tail_wl, 5772.0), x=tail_wl)
    total = table_total + tail
    print(f"\nsolar table {table_total:.1f} W/m^2 + IR tail {tail:.1f} = {total:.1f} W/m^2")
    # Kopp & Lean 2011: 1360.8 +- 0.5 W/m^2; CALSPEC solar absolute flux is good to ~1 %
    assert total == pytest.approx(1360.8, rel=0.01)
    # and the renderer's accessor returns the same table
    grid = np.linspace(200.0, 2600.0, 4801)
    np.testing.assert_allclose(spectra.solar_irradiance_1au_w_m2_nm(grid), np.interp(grid, wl, f), rtol=1e-12)


@pytest.mark.parametrize("body", ["mars", "jupiter", "moon", "ceres"])
def test_body_spectrum_has_its_v_magnitude(rad, body):
    wl = np.linspace(470.0, 745.0, 5501)
    e = rad.body_spectral_irradiance_w_m2_nm(body, 1.7, wl)
    # synthetic V by the oracle's own integration on the library's V curve
    wlv, fv = _calspec("alpha_lyr_stis_011.fits")
    v = -2.5 * np.log10(_direct_v_signal(wl, lambda w: np.interp(w, wl, e)) / _direct_v_signal(wlv, lambda w: np.interp(w, wlv, fv))) + 0.03
    assert v == pytest.approx(1.7, abs=2e-3)  # 2 mmag: quadrature on different grids
    # the Mitsuba path's helper on the shared 5 nm grid agrees with the fine-grid figure
    e_grid = rad.body_spectral_irradiance_w_m2_nm(body, 1.7)
    # 0.5 %: point-sampling the solar Fraunhofer structure at 5 nm
    assert rad.electrons_per_s_from_spectral_irradiance(e_grid) == pytest.approx(rad.body_electrons_per_s(body, 1.7), rel=5e-3)


def test_shared_grid_helper_consistent_with_star_table(rad):
    for teff in (3000.0, 5800.0, 9600.0, 25000.0):
        e = rad.star_spectral_irradiance_w_m2_nm(2.0, teff)
        # 1e-3: trapezoid on the 5 nm grid vs 0.25 nm for a smooth blackbody
        assert rad.electrons_per_s_from_spectral_irradiance(e) == pytest.approx(rad.star_electrons_per_s(2.0, teff), rel=1e-3)


def test_for_camera_is_cached_per_camera(cam):
    assert Radiometry.for_camera(cam) is Radiometry.for_camera(paper_camera())
    other = Radiometry.for_camera(cam.replace(f_number=4.4))
    # area scales as 1/N^2
    assert other.zero_point_e_per_s == pytest.approx(Radiometry.for_camera(cam).zero_point_e_per_s / 4.0, rel=1e-12)
