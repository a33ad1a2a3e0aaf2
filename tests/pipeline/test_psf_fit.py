"""The improved mode's PSF-fit centroids (``pipeline/psf_fit.py``) against stars GalSim draws: the
fitted position is where GalSim put the star, Eq. 7-8's ``I^2`` centroid is pulled towards the
pixel centre on narrow PSFs, and the frame's width is GalSim's.

GalSim (Rowe et al. 2015) draws each star (its profile convolved with the pixel) on an image whose
bounds start at (0, 0), so its pixel centres are skynav's (``benchmarks/foreign_frames.py``).
"""

from __future__ import annotations

import numpy as np
import pytest

galsim = pytest.importorskip("galsim")

from skynav.pipeline.centroids import detect_spots  # noqa: E402
from skynav.pipeline.psf_fit import fit_gaussian_xy, frame_psf_sigma_px  # noqa: E402

BACKGROUND_DN = 100.0


def _profile(kind):
    if kind == "gaussian":
        return galsim.Gaussian(sigma=0.5)
    if kind == "airy":
        return galsim.Airy(lam_over_diam=1.0 / 1.028993969962188)  # FWHM 1 px
    return galsim.Moffat(beta=3.0, fwhm=1.2)


def _field(kind, flux, rng, *, n=40, size=256):
    """A grid of ``n`` stars at random sub-pixel positions (noise-free), and their positions."""
    p = _profile(kind)
    image = galsim.ImageD(size, size, xmin=0, ymin=0, scale=1.0)
    g = int(np.ceil(np.sqrt(n)))
    step = size / (g + 1)
    xy = []
    for k in range(n):
        x = step * (1 + k % g) + rng.uniform(-0.5, 0.5)
        y = step * (1 + k // g) + rng.uniform(-0.5, 0.5)
        b = galsim.BoundsI(int(x) - 12, int(x) + 12, int(y) - 12, int(y) + 12)
        p.withFlux(flux).drawImage(image=image[b], center=galsim.PositionD(x, y), add_to_image=True)
        xy.append((x, y))
    return image.array + BACKGROUND_DN, np.array(xy)


def _detected(img, xy_true):
    """Eq. 7-8's centroids of the field, in the order of ``xy_true``."""
    sp = detect_spots(img, T=5.0, threshold_dn=BACKGROUND_DN + 5.0, background_dn=BACKGROUND_DN)
    d = np.hypot(*(sp.xy_px[None, :, :] - xy_true[:, None, :]).transpose(2, 0, 1))
    return sp.xy_px[np.argmin(d, axis=1)], sp.flux_dn[np.argmin(d, axis=1)]


@pytest.mark.parametrize("kind, tol_px", [("gaussian", 1e-3), ("airy", 0.01), ("moffat", 0.03)])
def test_the_fit_finds_galsims_star_where_eq_7_8_is_pulled_to_the_pixel_centre(kind, tol_px):
    """Noise-free stars of 20000 DN at random phases (a 0.5 px Gaussian, a 1 px FWHM Airy, a
    Moffat of beta 3 and FWHM 1.2 px): the fit is within ``tol_px`` of GalSim's position (the
    model is exact for the Gaussian: measured under 1e-4 px; a Gaussian fitted to the Airy's
    core: 0.007 px at most, rms 0.002; to the Moffat's, whose wings the stamp cuts unevenly:
    0.027, rms 0.018 against Eq. 7-8's 0.034), while Eq. 7-8's ``I^2`` centroids of the same
    stars err by more than 0.03 px rms (their pull towards the pixel centre: 0.034 to 0.094)."""
    rng = np.random.default_rng(11)
    img, xy = _field(kind, 2e4, rng)
    c0, flux = _detected(img, xy)
    sigma = frame_psf_sigma_px(img, c0, flux, max_dn=1e9)
    fit, ok = fit_gaussian_xy(img, c0, sigma_px=sigma, max_dn=1e9)
    assert ok.all()
    assert np.max(np.abs(fit - xy)) < tol_px
    assert np.sqrt(np.mean((c0 - xy) ** 2)) > 0.03


def test_the_frame_width_is_galsims_gaussian_sigma():
    """The width fitted on the brightest stars is GalSim's sigma, 0.5 px, within 1 %."""
    img, xy = _field("gaussian", 2e4, np.random.default_rng(3))
    c0, flux = _detected(img, xy)
    assert frame_psf_sigma_px(img, c0, flux, max_dn=1e9) == pytest.approx(0.5, rel=0.01)


def test_with_noise_the_fit_is_unbiased_and_beats_eq_7_8():
    """Poisson stars of 3000 e- on 20 e- of sky with 5 e- read noise (1 e-/DN), 0.5 px Gaussian,
    400 draws: the fit's mean error is within 4 standard errors of zero on each axis and its rms
    is below Eq. 7-8's (whose pull towards the pixel centre adds ~0.05 px)."""
    rng = np.random.default_rng(5)
    errs_fit, errs_i2 = [], []
    for _ in range(10):
        clean, xy = _field("gaussian", 3000.0, rng)
        img = rng.poisson(clean - BACKGROUND_DN + 20.0) + rng.normal(0.0, 5.0, clean.shape) + BACKGROUND_DN - 20.0
        sp = detect_spots(img, T=5.0, threshold_dn=BACKGROUND_DN + 5 * 6.7, background_dn=BACKGROUND_DN)
        d = np.hypot(*(sp.xy_px[None, :, :] - xy[:, None, :]).transpose(2, 0, 1))
        found = d.min(axis=1) < 1.0
        c0 = sp.xy_px[np.argmin(d, axis=1)][found]
        fit, ok = fit_gaussian_xy(img, c0, sigma_px=0.5, max_dn=1e9)
        errs_fit.append((fit - xy[found])[ok])
        errs_i2.append((c0 - xy[found])[ok])
    ef, ei = np.concatenate(errs_fit), np.concatenate(errs_i2)
    assert len(ef) > 300
    assert np.all(np.abs(ef.mean(axis=0)) < 4 * ef.std(axis=0) / np.sqrt(len(ef)))
    assert np.sqrt(np.mean(ef ** 2)) < np.sqrt(np.mean(ei ** 2))


def test_saturated_or_clipped_stamps_keep_their_input_position():
    """A stamp with a pixel at ``max_dn`` or reaching past the image edge is not fitted: the
    input position comes back, flagged."""
    img, xy = _field("gaussian", 2e4, np.random.default_rng(2), n=4, size=64)
    start = np.vstack([xy + 0.1, [[1.0, 30.0]]])
    fit, ok = fit_gaussian_xy(img, start, sigma_px=0.5, max_dn=float(img.max()))
    assert not ok[-1] and np.array_equal(fit[-1], start[-1])
    brightest = int(np.argmax([img[int(round(y)), int(round(x))] for x, y in xy]))
    assert not ok[brightest] and np.array_equal(fit[brightest], start[brightest])
    assert ok.sum() == 3
