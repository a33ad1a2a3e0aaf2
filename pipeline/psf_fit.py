"""Star positions by a least-squares fit of a pixel-integrated Gaussian: the improved mode's
final centroids, free of the pull towards the pixel centre of Eq. 7-8 on narrow PSFs.

Core module. Eq. 7-8's ``I^2``-weighted centre of brightness is pulled towards the centre of the
brightest pixel when the PSF is not much wider than a pixel (a 0.5 px Gaussian, an Airy of
1 px FWHM): on such frames the error of a bright star is ~0.05-0.1 px, set by where the star
falls inside its pixel, not by its noise. Fitting the pixel-integrated profile instead,

    ``m_ij = A Ex_j(x, s) Ey_i(y, s) + b``,  ``Ex_j = Phi((j + 1/2 - x) / s) - Phi((j - 1/2 - x) / s)``

(``Phi`` the standard normal CDF, pixel ``[i, j]`` centred on ``(X, Y) = (j, i)``), by
Gauss-Newton on a square stamp around each spot, removes that pull for any symmetric PSF close
to a Gaussian: the fit's symmetric model is centred where the symmetric data are. The width ``s``
is the frame's own: fitted on its brightest unsaturated stars (:func:`frame_psf_sigma_px`), then
held for every star, so the fit needs neither the camera's PSF model nor its gain.
"""

from __future__ import annotations

import numpy as np

from scipy.special import ndtr

__all__ = ["fit_gaussian_xy", "frame_psf_sigma_px", "stamp_half_px"]

_INV_SQRT_2PI = 0.3989422804014327


def stamp_half_px(sigma_px: float) -> int:
    """Half-size of the fitting stamp: the core and the first ring of wing (``2 s + 1`` px), 2 to 6."""
    return int(np.clip(np.ceil(2.0 * sigma_px + 1.0), 2, 6))


def _stamps(img, xy, half):
    """``(data (N, S, S) float, corner (N, 2) int, ok (N,))``: square stamps of side ``2 half + 1``
    around the rounded positions; ``ok`` False where a stamp would leave the image."""
    H, W = img.shape
    c = np.rint(np.asarray(xy, float)).astype(np.intp)
    ok = np.all(np.isfinite(xy), axis=1)
    c[~ok] = 0
    ok &= (c[:, 0] - half >= 0) & (c[:, 0] + half < W) & (c[:, 1] - half >= 0) & (c[:, 1] + half < H)
    d = np.arange(-half, half + 1)
    rr = np.clip(c[:, 1, None] + d[None, :], 0, H - 1)
    cc = np.clip(c[:, 0, None] + d[None, :], 0, W - 1)
    data = img[rr[:, :, None], cc[:, None, :]].astype(np.float64)
    return data, c - half, ok


def _profile(edges, s):
    """Pixel-integrated 1-D Gaussian of width ``s`` over the pixels between ``edges`` (N, S + 1),
    the pixel edges minus the position: ``(e, de/dposition, de/ds)``, each (N, S)."""
    z = edges / s
    p = np.exp(-0.5 * z * z) * _INV_SQRT_2PI
    zp = z * p
    e = np.diff(ndtr(z), axis=1)
    de_dx = -np.diff(p, axis=1) / s
    de_ds = -np.diff(zp, axis=1) / s
    return e, de_dx, de_ds


def _gauss_newton(data, corner, xy0, s, *, fit_width: bool, iterations: int):
    """Gauss-Newton on every stamp at once: ``(xy (N, 2), s (N,), converged (N,))``."""
    n, S, _ = data.shape
    edges = np.arange(S + 1, dtype=np.float64) - 0.5
    x, y = xy0[:, 0] - corner[:, 0], xy0[:, 1] - corner[:, 1]
    b = np.minimum(np.min(data.reshape(n, -1), axis=1), np.median(data.reshape(n, -1), axis=1))
    A = np.clip((data - b[:, None, None]).sum(axis=(1, 2)), 1.0, None)
    s = np.full(n, float(s)) if np.ndim(s) == 0 else np.asarray(s, float).copy()
    good = np.ones(n, bool)
    ones = np.ones((n, S * S))
    for _ in range(iterations):
        e, de, ds = _profile(edges[None, :] - np.concatenate([x, y])[:, None], np.concatenate([s, s])[:, None])
        ex, ey, dex, dey, dsx, dsy = e[:n], e[n:], de[:n], de[n:], ds[:n], ds[n:]
        m = A[:, None, None] * ey[:, :, None] * ex[:, None, :] + b[:, None, None]
        cols = [A[:, None, None] * ey[:, :, None] * dex[:, None, :],
                A[:, None, None] * dey[:, :, None] * ex[:, None, :],
                ey[:, :, None] * ex[:, None, :]]
        if fit_width:
            cols.append(A[:, None, None] * (ey[:, :, None] * dsx[:, None, :] + dsy[:, :, None] * ex[:, None, :]))
        J = np.stack([c.reshape(n, -1) for c in cols[:3]] + [ones] + [c.reshape(n, -1) for c in cols[3:]],
                     axis=1)  # (N, p, S^2): x, y, A, b (, s)
        r = (data - m).reshape(n, -1, 1)
        JtJ = J @ J.transpose(0, 2, 1)
        Jtr = (J @ r)[..., 0]
        d = np.arange(JtJ.shape[1])
        JtJ[:, d, d] *= 1.0 + 1e-12  # a zero column (A = 0) makes a non-finite step: not converged
        JtJ[:, d, d] += 1e-300
        with np.errstate(all="ignore"):
            step = np.linalg.solve(JtJ, Jtr[..., None])[..., 0]
        good &= np.all(np.isfinite(step), axis=1)
        step[~good] = 0.0
        step[:, :2] = np.clip(step[:, :2], -0.5, 0.5)  # a damped start: no jump out of the stamp
        x, y, A, b = x + step[:, 0], y + step[:, 1], A + step[:, 2], b + step[:, 3]
        if fit_width:
            s = np.clip(s + np.clip(step[:, -1], -0.5 * s, 0.5 * s), 0.15, 8.0)
    half = (S - 1) / 2
    good &= (np.abs(x - half) < 1.0) & (np.abs(y - half) < 1.0) & (A > 0)
    return np.stack([x + corner[:, 0], y + corner[:, 1]], -1), s, good


def frame_psf_sigma_px(img, xy, flux_dn, *, max_dn: float, n_stars: int = 12, start_px: float = 0.8) -> float:
    """The frame's Gaussian width (px): the median of the widths fitted on the ``n_stars``
    brightest spots whose 9 x 9 stamp lies in the image with no pixel at ``0.8 max_dn``, each
    started from ``start_px`` (5 Gauss-Newton steps); nan when fewer than 3 fit."""
    order = np.argsort(-np.asarray(flux_dn, float), kind="stable")[:4 * n_stars]
    xy = np.asarray(xy, float)[order]
    data, corner, ok = _stamps(img, xy, 4)
    ok &= (data >= 0.8 * max_dn).sum(axis=(1, 2)) == 0
    sel = np.flatnonzero(ok)[:n_stars]
    if len(sel) < 3:
        return float("nan")
    _, s, good = _gauss_newton(data[sel], corner[sel], xy[sel], start_px, fit_width=True, iterations=5)
    s = s[good]
    return float(np.median(s)) if len(s) >= 3 else float("nan")


def fit_gaussian_xy(img, xy, *, sigma_px: float, max_dn: float, iterations: int = 2):
    """``(xy (N, 2), fitted (N,))``: each spot's position by the least-squares fit of a
    pixel-integrated Gaussian of width ``sigma_px`` plus a constant (module docstring), started
    from ``xy``; where the stamp leaves the image, holds a saturated pixel, or the fit does not
    stay within 1 px of the stamp's centre, the input position and ``fitted`` False."""
    xy = np.asarray(xy, float).reshape(-1, 2)
    out = xy.copy()
    if len(xy) == 0 or not np.isfinite(sigma_px) or sigma_px <= 0:
        return out, np.zeros(len(xy), bool)
    data, corner, ok = _stamps(np.asarray(img), xy, stamp_half_px(sigma_px))
    ok &= (data >= max_dn).sum(axis=(1, 2)) == 0
    sel = np.flatnonzero(ok)
    fitted = np.zeros(len(xy), bool)
    if len(sel):
        fit, _, good = _gauss_newton(data[sel], corner[sel], xy[sel], sigma_px, fit_width=False, iterations=iterations)
        out[sel[good]] = fit[good]
        fitted[sel[good]] = True
    return out, fitted
