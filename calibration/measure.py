"""Point-source measurement shared by every image the closed loop compares: a PSF-fit centroid and
aperture photometry, applied identically to the bench camera's captures and to a dataset's own
software frames.

Core module (NumPy only). For each source, from a predicted position:

1. **Window.** A ``(2 h + 1)^2`` window (default 11 x 11 px) around the brightest pixel within
   2 px of the prediction, so a prediction a pixel or two off does not matter.
2. **Centroid.** A least-squares fit of a pixel-integrated circular Gaussian plus a constant
   background (x, y, flux, background, sigma), weighted by the inverse of the expected pixel
   variance (shot noise of the model + read noise + quantisation), by Levenberg-Marquardt,
   vectorised over all the sources. Saturated pixels get zero weight, so a saturated star or planet
   is located by its unsaturated wings; a symmetric PSF gives an unbiased position whatever its
   exact shape. This is the estimator that reaches the photon limit (the Cramer-Rao bound for a
   Gaussian PSF; e.g. Thomas, Mon. Not. R. Astron. Soc. 371, 2006), where a plain first moment
   in a fixed window also sums the noise of every empty pixel.
3. **Photometry.** The electrons inside a circular aperture (``r_ap_px`` about the fitted centre,
   whole pixels whose centres fall inside) minus the local background: the 3-sigma-clipped mean of
   an annulus ``r_in_px .. r_out_px``. The default aperture (3.5 px) holds all but ~1e-7 of a
   Gaussian PSF of sigma 0.65 px, so a slightly different PSF shape on the bench does not change
   the sum.

Pixel convention (docs/conventions.md): x along columns, y along rows, the centre of the top-left pixel
at (0, 0).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage
from scipy.special import erf

__all__ = ["SourceMeasurements", "measure_sources"]

_SQRT2 = np.sqrt(2.0)
_INV_SQRT2PI = 1.0 / np.sqrt(2.0 * np.pi)


@dataclass(frozen=True, kw_only=True, eq=False)
class SourceMeasurements:
    """Measurements of N sources (rows in the order of the predictions).

    Attributes
    ----------
    xy_px : ndarray, shape (N, 2), px
        Fitted centres (x = column); NaN where ``ok`` is False.
    flux_e : ndarray, shape (N,), e-
        Aperture electrons above the local background; NaN where ``ok`` is False.
    background_e : ndarray, shape (N,), e- per px
        Local background (annulus).
    sigma_px : ndarray, shape (N,), px
        Fitted Gaussian width.
    saturated : ndarray of bool, shape (N,)
        A pixel of the aperture is saturated (the flux is then a lower bound).
    ok : ndarray of bool, shape (N,)
        The window and the annulus lie inside the image and the fit converged.
    """

    xy_px: np.ndarray
    flux_e: np.ndarray
    background_e: np.ndarray
    sigma_px: np.ndarray
    saturated: np.ndarray
    ok: np.ndarray

    def __len__(self) -> int:
        return len(self.xy_px)


def _pixel_profile(c, s, grid):
    """Pixel-integrated 1-D Gaussian and its derivatives in c and s: arrays (N, n)."""
    a = (grid[None, :] + 0.5 - c[:, None]) / s[:, None]
    b = (grid[None, :] - 0.5 - c[:, None]) / s[:, None]
    p = 0.5 * (erf(a / _SQRT2) - erf(b / _SQRT2))
    pa, pb = np.exp(-0.5 * a * a) * _INV_SQRT2PI, np.exp(-0.5 * b * b) * _INV_SQRT2PI
    dp_dc = (pb - pa) / s[:, None]
    dp_ds = (pb * b - pa * a) / s[:, None]
    return p, dp_dc, dp_ds


def _model(q, grid):
    """Model windows (N, n, n) and Jacobian (N, n, n, 5) for q = (x, y, flux, bg, sigma), window coords."""
    x, y, f, bg, s = q.T
    px, dpx_dx, dpx_ds = _pixel_profile(x, s, grid)
    py, dpy_dy, dpy_ds = _pixel_profile(y, s, grid)
    shape = py[:, :, None] * px[:, None, :]
    m = bg[:, None, None] + f[:, None, None] * shape
    J = np.empty(m.shape + (5,))
    J[..., 0] = f[:, None, None] * py[:, :, None] * dpx_dx[:, None, :]
    J[..., 1] = f[:, None, None] * dpy_dy[:, :, None] * px[:, None, :]
    J[..., 2] = shape
    J[..., 3] = 1.0
    J[..., 4] = f[:, None, None] * (dpy_ds[:, :, None] * px[:, None, :] + py[:, :, None] * dpx_ds[:, None, :])
    return m, J


def _fit(win, wt, q0, grid, iterations: int):
    """Vectorised Levenberg-Marquardt of the Gaussian model on windows (N, n, n)."""
    q = q0.copy()
    lam = np.full(len(q), 1e-3)
    m, J = _model(q, grid)
    chi2 = np.sum(wt * (win - m) ** 2, axis=(1, 2))
    for _ in range(iterations):
        r = (win - m) * wt
        A = np.einsum("nijk,nijl->nkl", J * wt[..., None], J)
        g = np.einsum("nijk,nij->nk", J, r)
        D = np.einsum("nkk->nk", A)
        A_d = A + (lam[:, None] * np.maximum(D, 1e-30))[:, :, None] * np.eye(5)[None]
        try:
            step = np.linalg.solve(A_d, g[..., None])[..., 0]
        except np.linalg.LinAlgError:
            step = np.zeros_like(q)
            for k in range(len(q)):
                step[k] = np.linalg.lstsq(A_d[k], g[k], rcond=None)[0]
        qn = q + step
        qn[:, 4] = np.clip(qn[:, 4], 0.15, 5.0)
        qn[:, 2] = np.maximum(qn[:, 2], 1e-9)
        mn, Jn = _model(qn, grid)
        chi2n = np.sum(wt * (win - mn) ** 2, axis=(1, 2))
        better = chi2n <= chi2
        q[better], m[better], J[better], chi2[better] = qn[better], mn[better], Jn[better], chi2n[better]
        lam = np.where(better, lam * 0.3, lam * 10.0)
    return q


def _fit_windows(img, sat, ci, cj, b, h, read_noise_e, iterations):
    """Fitted (x, y, flux, bg, sigma) in window coordinates for windows of half-size h at (ci, cj)."""
    win = np.stack([img[i - h:i + h + 1, j - h:j + h + 1] for i, j in zip(ci, cj)])
    swin = np.stack([sat[i - h:i + h + 1, j - h:j + h + 1] for i, j in zip(ci, cj)])
    grid = np.arange(-h, h + 1, dtype=float)
    wsum = np.maximum(win - b[:, None, None], 0.0)
    f0 = np.maximum(wsum.sum(axis=(1, 2)), 1.0)
    x0 = (wsum.sum(axis=1) * grid).sum(axis=1) / f0
    y0 = (wsum.sum(axis=2) * grid).sum(axis=1) / f0
    q0 = np.stack([np.clip(x0, -1, 1), np.clip(y0, -1, 1), f0, b, np.full(len(ci), 0.7)], -1)
    var = read_noise_e ** 2 + np.maximum(win - b[:, None, None], 0.0) + np.maximum(b, 0.0)[:, None, None]
    wt = np.where(swin, 0.0, 1.0 / var)
    return _fit(win, wt, q0, grid, iterations)


def _annulus_background(big, r_in_px: float, r_out_px: float):
    """Each source's background (N,), e-: the 3-sigma-clipped mean of the annulus ``r_in_px`` to
    ``r_out_px`` about the centre of its cut-out ``big`` (N, 2R+1, 2R+1)."""
    R = big.shape[1] // 2
    yy, xx = np.mgrid[-R:R + 1, -R:R + 1]
    rr = np.hypot(xx, yy)
    ann = (rr >= r_in_px) & (rr <= r_out_px)
    vals = big[:, ann]
    keep = np.ones(vals.shape, bool)
    for _ in range(3):
        mu = np.array([v[k].mean() for v, k in zip(vals, keep)])
        sd = np.array([v[k].std() for v, k in zip(vals, keep)])
        keep = np.abs(vals - mu[:, None]) <= 3.0 * np.maximum(sd[:, None], 1e-9)
    return np.array([v[k].mean() for v, k in zip(vals, keep)])


def _refit_saturated(img, sat, ci, cj, b, q, good, h: int, R: int, read_noise_e: float, iterations: int) -> None:
    """A failed fit of a saturated source (a plateau wider than the window leaves too few wing
    pixels), once more in a window twice as large centred on the plateau's centre; where that
    fails too, the background-subtracted first moment of the window (a plateau too wide for a
    Gaussian: a source spread over many screen pixels; unbiased for a symmetric spot). Updates
    the window centres ``ci``, ``cj``, the fits ``q`` and their flags ``good`` in place."""
    retry = np.flatnonzero(~good & np.array([sat[i - 2:i + 3, j - 2:j + 3].any() for i, j in zip(ci, cj)], dtype=bool))
    if not len(retry):
        return
    h2 = min(2 * h, R)
    for k in retry:
        lab, _ = ndimage.label(sat[ci[k] - R:ci[k] + R + 1, cj[k] - R:cj[k] + R + 1])
        core = lab[R - 2:R + 3, R - 2:R + 3]
        sy, sx = np.nonzero(lab == np.bincount(core[core > 0]).argmax())
        ci[k] += int(np.clip(np.round(sy.mean()) - R, -2, 2))
        cj[k] += int(np.clip(np.round(sx.mean()) - R, -2, 2))
    q2 = _fit_windows(img, sat, ci[retry], cj[retry], b[retry], h2, read_noise_e, 2 * iterations)
    ok2 = (np.abs(q2[:, 0]) < h2 - 1) & (np.abs(q2[:, 1]) < h2 - 1) & (q2[:, 2] > 0) & np.all(np.isfinite(q2), axis=1)
    for n, k in enumerate(retry):
        if not ok2[n]:
            w = img[ci[k] - h2:ci[k] + h2 + 1, cj[k] - h2:cj[k] + h2 + 1] - b[k]
            w = np.where(w > 0, w, 0.0)
            g = np.arange(-h2, h2 + 1, dtype=float)
            if w.sum() > 0:
                q2[n, :2] = (w.sum(axis=0) @ g) / w.sum(), (w.sum(axis=1) @ g) / w.sum()
                q2[n, 2] = w.sum()
                ok2[n] = bool(np.all(np.abs(q2[n, :2]) < h2 - 1))
    q[retry], good[retry] = q2, ok2


def _aperture_photometry(img, sat, fx, fy, good, b, r_ap_px: float) -> tuple:
    """``(flux, saturated)`` (N,) of the sources centred at ``fx``, ``fy`` (px) whose fit is
    ``good`` (NaN and False elsewhere): the sum within ``r_ap_px`` of the centre less the
    background ``b`` a pixel, e-, and whether a saturated pixel is in the aperture."""
    flux = np.full(len(fx), np.nan)
    satf = np.zeros(len(fx), bool)
    ra = int(np.ceil(r_ap_px)) + 1
    ay, ax = np.mgrid[-ra:ra + 1, -ra:ra + 1]
    for k, (x, y) in enumerate(zip(fx, fy)):
        if not good[k]:
            continue
        i0, j0 = int(np.round(y)), int(np.round(x))
        inap = np.hypot(j0 + ax - x, i0 + ay - y) <= r_ap_px
        patch = img[i0 - ra:i0 + ra + 1, j0 - ra:j0 + ra + 1]
        flux[k] = float(np.sum(patch[inap] - b[k]))
        satf[k] = bool(sat[i0 - ra:i0 + ra + 1, j0 - ra:j0 + ra + 1][inap].any())
    return flux, satf


def measure_sources(image_e, guess_xy_px, *, saturated=None, read_noise_e: float = 10.0, half_window_px: int = 5,
                    r_ap_px: float = 3.5, r_in_px: float = 6.0, r_out_px: float = 10.0, iterations: int = 25) -> SourceMeasurements:
    """Centroid and aperture photometry of point sources (see the module docstring).

    Parameters
    ----------
    image_e : ndarray, shape (H, W), e-
        The image in electrons (a camera's DN minus its offset, divided by its gain).
    guess_xy_px : ndarray, shape (N, 2), px
        Predicted positions (x = column); the window is centred on the brightest pixel within
        2 px of each.
    saturated : ndarray of bool, shape (H, W), optional
        Pixels at the sensor's full scale: left out of the fit, and flagged in photometry.
    read_noise_e : float
        Per-pixel noise floor of the image (read noise and quantisation in quadrature), e-; sets
        the fit weights with the shot noise of the model.
    half_window_px : int
        Fit window half-size h (window 2h+1 px).
    r_ap_px, r_in_px, r_out_px : float
        Aperture radius and background annulus, px.

    Returns
    -------
    SourceMeasurements

    Examples
    --------
    >>> yy, xx = np.mgrid[0:40, 0:40]
    >>> img = 5.0 + 1e4 * np.exp(-((xx - 20.3) ** 2 + (yy - 19.6) ** 2) / (2 * 0.8 ** 2)) / (2 * np.pi * 0.8 ** 2)
    >>> m = measure_sources(img, np.array([[21.0, 19.0]]))
    >>> np.round(m.xy_px, 2).tolist(), bool(abs(m.flux_e[0] / 1e4 - 1) < 0.01)
    ([[20.3, 19.6]], True)
    """
    img = np.asarray(image_e, dtype=float)
    H, W = img.shape
    guess = np.asarray(guess_xy_px, dtype=float).reshape(-1, 2)
    n = len(guess)
    sat = np.zeros((H, W), bool) if saturated is None else np.asarray(saturated, bool)
    h = int(half_window_px)
    R = int(np.ceil(r_out_px))
    out_xy = np.full((n, 2), np.nan)
    flux = np.full(n, np.nan)
    bg = np.full(n, np.nan)
    sig = np.full(n, np.nan)
    satf = np.zeros(n, bool)
    ok = np.zeros(n, bool)
    fin = np.all(np.isfinite(guess), axis=1)
    gi = np.where(fin, np.round(guess[:, 1]), -10 * (R + h)).astype(int)
    gj = np.where(fin, np.round(guess[:, 0]), -10 * (R + h)).astype(int)
    m = R + h + 2
    inside = fin & (gi >= m) & (gj >= m) & (gi < H - m) & (gj < W - m)
    idx = np.flatnonzero(inside)
    if len(idx) == 0:
        return SourceMeasurements(xy_px=out_xy, flux_e=flux, background_e=bg, sigma_px=sig, saturated=satf, ok=ok)
    big = np.stack([img[i - R:i + R + 1, j - R:j + R + 1] for i, j in zip(gi[idx], gj[idx])])
    b = _annulus_background(big, r_in_px, r_out_px)
    # recentre on the brightest pixel within 2 px of the prediction
    c = big[:, R - 2:R + 3, R - 2:R + 3].reshape(len(idx), -1).argmax(axis=1)
    ci = gi[idx] + c // 5 - 2
    cj = gj[idx] + c % 5 - 2
    q = _fit_windows(img, sat, ci, cj, b, h, read_noise_e, iterations)
    good = (np.abs(q[:, 0]) < h - 1) & (np.abs(q[:, 1]) < h - 1) & (q[:, 2] > 0) & np.all(np.isfinite(q), axis=1)
    _refit_saturated(img, sat, ci, cj, b, q, good, h, R, read_noise_e, iterations)
    fx, fy = cj + q[:, 0], ci + q[:, 1]
    flux[idx], satf[idx] = _aperture_photometry(img, sat, fx, fy, good, b, r_ap_px)
    out_xy[idx] = np.where(good[:, None], np.stack([fx, fy], -1), np.nan)
    bg[idx] = b
    sig[idx] = q[:, 4]
    ok[idx] = good
    return SourceMeasurements(xy_px=out_xy, flux_e=flux, background_e=bg, sigma_px=sig, saturated=satf, ok=ok)
