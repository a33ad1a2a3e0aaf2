"""The PSF models against GalSim (an independent implementation: its own Bessel functions, its own
pupil sampling and FFTs, its own pixel convolution).

Camera of the comparisons: f/20, 5 um pixels, so lambda F / pitch = 2.2 px at 550 nm (a sampled
PSF; the paper camera's f/2.2 x 13.8 um is 0.09 px, where every model is one pixel wide). Both
images are drawn on the same (2h+1)^2 stamp at the same point and normalised to the same flux
on it (the renderer's stamps hold the whole flux, the diffraction wings beyond h folded back),
then compared pixel by pixel in units of the peak.
"""

import functools

import galsim  # the test extra installs it
import numpy as np
import pytest

from skynav.renderer.optics import airy_intensity, kernel_for
from skynav.renderer.psf import stamp_origin
from skynav.scenes.camera import Camera

PITCH_UM, F_NUMBER, WL_NM = 5.0, 20.0, 550.0
LF_PX = WL_NM * 1e-3 * F_NUMBER / PITCH_UM  # lambda F in px: GalSim's lam_over_diam at scale 1
PHASES = [(0.0, 0.0), (0.3, -0.2), (-0.45, 0.41)]
COMA = {4: 0.3, 7: 0.2, 8: -0.1}  # defocus + coma (y and x), waves RMS


def _camera(psf):
    return Camera(width=64, height=64, focal_length_mm=100.0, pixel_pitch_um=PITCH_UM, f_number=F_NUMBER, psf=psf)


def _galsim_stamp(gpsf, xy, h):
    """GalSim's pixel-convolved image of ``gpsf`` at point ``xy`` on our stamp of half size h."""
    n = 2 * h + 1
    o = stamp_origin(np.reshape(xy, (1, 2)), h)[0]
    img = galsim.ImageD(n, n, scale=1.0)
    # our stamp's centre pixel (o + h) is GalSim's true centre; offset = point - that centre
    gpsf.drawImage(img, offset=(xy[0] - (o[0] + h), xy[1] - (o[1] + h)), method="auto")
    return img.array / img.array.sum()


@functools.lru_cache(maxsize=None)
def _galsim_optical(obscuration, zernikes):
    """GalSim's OpticalPSF (built once: ~5 s); ``zernikes`` as ((j, waves), ...)."""
    ab = np.zeros(12)
    for j, a in zernikes:
        ab[j] = a
    return galsim.OpticalPSF(lam_over_diam=LF_PX, obscuration=obscuration, aberrations=list(ab),
                             pad_factor=4, oversampling=4)


def test_airy_profile_matches_galsim_airy():
    """The analytic annular Airy intensity (per px^2, integral 1) against galsim.Airy.xValue, to
    1e-9 of the peak (two Bessel implementations agree to ~1e-12)."""
    r = np.linspace(0.0, 12.0, 241)
    for e in (0.0, 0.3):
        g = galsim.Airy(lam_over_diam=LF_PX, obscuration=e)
        ref = np.array([g.xValue(galsim.PositionD(float(x), 0.0)) for x in r])
        ours = airy_intensity(r, LF_PX, e)
        assert np.max(np.abs(ours - ref)) < 1e-9 * ref[0]


@pytest.mark.parametrize("phase", PHASES)
def test_airy_stamps_match_galsim_in_every_pixel(phase):
    """Monochromatic annular Airy, pixel-integrated: within 1e-3 of the peak in every pixel
    (measured 6.2e-5 to 6.6e-4 on the 33 x 33 stamp; the bilinear read between 1/16 px samples dominates)."""
    k = kernel_for(_camera({"model": "airy", "obscuration": 0.3, "wavelength_nm": WL_NM}), None, 1e-6)
    xy = np.array([32.0 + phase[0], 31.0 + phase[1]])
    ours = k.stamp(xy, k.half)
    ref = _galsim_stamp(galsim.Airy(lam_over_diam=LF_PX, obscuration=0.3), xy, k.half)
    assert abs(ours.sum() - 1.0) < 1e-12
    assert np.max(np.abs(ours - ref)) < 1e-3 * ref.max()


@pytest.mark.parametrize("phase", PHASES)
def test_optical_defocus_and_coma_match_galsim_optical_psf(phase):
    """Defocus 0.3 + coma (0.2, -0.1) waves, obscuration 0.2: within 1e-3 of the peak in every
    pixel (measured 6.7e-4 to 7.5e-4: GalSim's pupil is sampled on its own grid)."""
    cam = _camera({"model": "optical", "obscuration": 0.2, "wavelength_nm": WL_NM, "zernike_waves": COMA})
    k = kernel_for(cam, None, 1e-6)
    xy = np.array([32.0 + phase[0], 31.0 + phase[1]])
    ours = k.stamp(xy, k.half)
    ref = _galsim_stamp(_galsim_optical(0.2, tuple(COMA.items())), xy, k.half)
    assert np.max(np.abs(ours - ref)) < 1e-3 * ref.max()


def test_coma_centroid_bias_matches_galsim():
    """The centre of light of a coma stamp is biased by > 1 px; ours and GalSim's agree to
    2e-3 px (measured 3.4e-4 px; on the same stamp; both carry the same truncation)."""
    cam = _camera({"model": "optical", "obscuration": 0.2, "wavelength_nm": WL_NM, "zernike_waves": COMA})
    k = kernel_for(cam, None, 1e-6)
    h = k.half
    gpsf = _galsim_optical(0.2, tuple(COMA.items()))
    for phase in PHASES:
        xy = np.array([32.0 + phase[0], 31.0 + phase[1]])
        o = stamp_origin(xy.reshape(1, 2), h)[0]
        yy, xx = np.indices((2 * h + 1, 2 * h + 1))
        bias = []
        for img in (k.stamp(xy, h), _galsim_stamp(gpsf, xy, h)):
            bias.append(np.array([(img * xx).sum() + o[0], (img * yy).sum() + o[1]]) / img.sum() - xy)
        assert np.hypot(*bias[0]) > 1.0  # the bias is real and large
        assert np.max(np.abs(bias[0] - bias[1])) < 2e-3


def _galsim_polychromatic(cam, source, obscuration):
    """GalSim Sum of monochromatic Airy patterns weighted by a source's electrons per 10 nm."""
    from skynav.renderer.optics import electron_spectrum, lambda_f_px

    wl, e = electron_spectrum(cam, source)
    w = e / e.sum()
    keep = w > 1e-6 * w.max()
    return galsim.Sum([galsim.Airy(lam_over_diam=float(lf), obscuration=obscuration, flux=float(wk))
                       for lf, wk in zip(lambda_f_px(cam, wl[keep]), w[keep])])


@pytest.mark.parametrize("source", [("star", 2600.0), ("star", 5800.0), ("star", 9400.0), ("star", 30000.0),
                                    ("body", "mars"), ("body", "neptune")])
def test_polychromatic_airy_matches_a_galsim_sum_of_airy_patterns(source):
    """Without wavelength_nm the Airy is the band's sum weighted by the source's electron
    spectrum. The renderer draws a star with the blend of the tables at the two spectral nodes
    around its effective wavelength (blackbody spectra; 17 nodes on this camera, lambda F = 2.2
    px), a body with the table of its own spectrum: against a GalSim Sum of monochromatic Airy
    patterns with the source's own weights, within 1e-3 of the peak in every pixel (measured
    3.2e-4 to 8.0e-4: the bilinear read between 1/16 px samples alone is 5.9e-4 to 7.2e-4 for
    the bodies' own tables; the blend adds at most the 2.6e-4 of the next test)."""
    from skynav.renderer.optics import star_effective_wavelengths_nm

    cam = _camera({"model": "airy", "obscuration": 0.2})
    xy = np.array([32.3, 31.6])
    if source[0] == "star":
        k = kernel_for(cam, None, 1e-6)
        assert len(k.tables) > 1  # the interpolation between nodes is what is tested
        ours = k.stamp(xy, k.half, star_effective_wavelengths_nm(cam, [source[1]])[0])
    else:
        k = kernel_for(cam, source, 1e-6)
        ours = k.stamp(xy, k.half)
    ref = _galsim_stamp(_galsim_polychromatic(cam, source, 0.2), xy, k.half)
    assert np.max(np.abs(ours - ref)) < 1e-3 * ref.max()


def test_spectral_nodes_interpolate_within_their_tolerance_of_each_source_s_own_table():
    """The fast path (the nodes' blend at a star's effective wavelength) against the reference
    (the table of the star's own spectrum, :func:`source_kernel`), 40 temperatures 2000..50000 K
    at three phases: within twice the nodes' stated tolerance (5e-4) of the peak (measured 2.6e-4:
    the monochromatic proxy bounds the interpolation, the spectra differ from the nodes' only
    in their width)."""
    from skynav.renderer.optics import SPECTRAL_TOLERANCE, source_kernel, spectral_nodes, star_effective_wavelengths_nm

    cam = _camera({"model": "airy", "obscuration": 0.2})
    nodes = spectral_nodes(cam)
    assert nodes.error <= nodes.tolerance == SPECTRAL_TOLERANCE
    k = kernel_for(cam, None, 1e-6)
    teff = np.geomspace(2000.0, 50000.0, 40)
    lam = star_effective_wavelengths_nm(cam, teff)
    worst = 0.0
    for t, lm in zip(teff, lam):
        ref = source_kernel(cam, ("star", float(t)), 1e-6)
        for phase in PHASES:
            xy = np.array([32.0 + phase[0], 31.0 + phase[1]])
            r = ref.stamp(xy, k.half)
            worst = max(worst, float(np.max(np.abs(k.stamp(xy, k.half, lm) - r)) / r.max()))
    assert worst < 2 * SPECTRAL_TOLERANCE, worst
