"""Sub-pixel detection of dots in a camera capture: threshold and label, then a blurred-disc fit.

1. The capture, less the background level, is divided by the camera's relative response (``gain``,
   per pixel, from the flat captures: PRNU, vignetting, the screen's non-uniformity and the solid
   angle of a screen pixel all cancel, and a dot becomes the plain image of a disc).
2. Blobs are found above a threshold halfway between the background and the bright dots and
   labelled (scikit-image, (row, col) order flipped to (x, y) here). Blobs much smaller than the
   typical dot (hot pixels, cosmic-ray hits) or touching the image edge are dropped.
3. Each dot gets a square window; all windows of one size are stacked into an ``(N, P)`` array of
   pixels (no per-dot Python loop; pixels beyond the image edge are left out). The window is
   centred on the first moment of the dot's signal, and the dot gets a local background from an
   annulus around it: the sigma-clipped median, plus the slope of a plane through the annulus
   pixels kept.
4. The centre is the least-squares fit of a blurred disc, ``A * erfc((r - R) / (sqrt(2) s)) / 2``
   (a disc of radius ``R`` seen through a Gaussian blur ``s``: defocus and pixel footprint), with
   ``x, y, A, R, s`` free, by damped Gauss-Newton (Levenberg-Marquardt) steps over all dots at
   once, started from the moment centroid. Pixels far off the fitted model (a hot pixel or a
   cosmic ray next to the dot) are masked out and the fit goes on; a blob the model cannot
   describe (most pixels masked, or a residual far above the other dots': a cosmic-ray track) is
   dropped.

The model is point-symmetric about its centre, as the image of a small disc is to first order in
the distortion, so its mismatch with the true dot shape (an ellipse, a non-Gaussian blur) does not
move the centre; a first moment in a finite window, by contrast, is pulled by the window's edge and
by a hot pixel, and sums the noise of every pixel with a lever arm.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage
from scipy.special import erfc
from skimage import measure

# fit region: the dot's threshold radius plus this margin (px); the background annulus lies
# between the fit region and the window's edge, ANNULUS_PX wide
FIT_MARGIN_PX = 2.5
ANNULUS_PX = 2.5
GAUSS_NEWTON_ITERATIONS = 8
OUTLIER_SIGMA = 6.0
OUTLIER_PASSES = (3, 5)     # iterations before which pixels off the fit are masked
SHAPE_RMS_FACTOR = 10.0     # a fit residual this many times the capture's median is not a dot


@dataclass(frozen=True)
class Blobs:
    xy_px: np.ndarray      # (N, 2) centres, CONVENTIONS pixel coordinates
    flux: np.ndarray       # (N,) background-subtracted sum, DN (gain-corrected)
    area_px: np.ndarray    # (N,) pixels above the threshold


def _empty() -> Blobs:
    return Blobs(np.zeros((0, 2)), np.zeros(0), np.zeros(0))


def detect_dots(image, *, background=None, gain=None, window_px: int | None = None) -> Blobs:
    """Dots of a capture.

    Parameters
    ----------
    image : ndarray, shape (H, W), DN
    background : ndarray or float, optional
        Dark frame (its median is the level: a per-pixel subtraction would add the dark's own
        noise and rounding) or a level; default: the image median.
    gain : ndarray, shape (H, W), optional
        Relative response of each pixel to a uniform screen (see :func:`relative_response`): the
        signal is divided by it before detection. Default: 1.
    window_px : int, optional
        Half-size of the window (fit region and background annulus); default from each blob's
        size.

    Returns
    -------
    Blobs
        Centres in CONVENTIONS pixel coordinates (x = column, the top-left pixel's centre at 0).
    """
    img = np.asarray(image, dtype=float)
    bg = float(np.median(img if background is None else background))
    sig = img - bg
    if gain is not None:
        sig = sig / np.asarray(gain, dtype=float)
    noise = 1.4826 * np.median(np.abs(sig - np.median(sig))) + 0.5
    bright = np.percentile(sig, 99.9)
    thr = max(0.3 * bright, 6.0 * noise)
    labels = measure.label(sig > thr, connectivity=2)
    n = int(labels.max())
    if n == 0:
        return _empty()
    H, W = img.shape
    lab = labels.ravel()
    areas = np.bincount(lab, minlength=n + 1)[1:].astype(float)
    rows, cols = np.divmod(np.arange(lab.size), W)
    cyx = np.stack([np.bincount(lab, rows, n + 1)[1:], np.bincount(lab, cols, n + 1)[1:]], -1) / areas[:, None]
    edge = np.array([s[0].start == 0 or s[1].start == 0 or s[0].stop == H or s[1].stop == W
                     for s in ndimage.find_objects(labels)])
    keep = (areas >= 0.25 * np.median(areas)) & ~edge  # hot pixels, cosmic rays; dots cut by the edge
    areas, cyx = areas[keep], cyx[keep]
    r_blob = np.sqrt(areas / np.pi)
    if window_px is not None:
        half = np.full(len(areas), int(window_px))
    else:
        half = np.ceil(r_blob + FIT_MARGIN_PX + ANNULUS_PX).astype(int)
    xy = np.full((len(areas), 2), np.nan)
    flux = np.zeros(len(areas))
    for h in np.unique(half):  # one stacked fit per window size (dots, fiducials)
        k = np.flatnonzero(half == h)
        xy[k], flux[k] = _fit_windows(sig, cyx[k], r_blob[k], int(h), noise)
    ok = np.all(np.isfinite(xy), axis=1)
    return Blobs(xy[ok], flux[ok], areas[ok])


def _row_median(a):
    """Median of each row of ``a`` (N, P), NaN entries left out (NaN for an all-NaN row)."""
    srt = np.sort(a, axis=1)  # NaN last
    k = np.isfinite(srt).sum(axis=1)
    lo = np.take_along_axis(srt, np.maximum((k - 1) // 2, 0)[:, None], 1)[:, 0]
    hi = np.take_along_axis(srt, np.maximum(k // 2, 0)[:, None], 1)[:, 0]
    return np.where(k > 0, 0.5 * (lo + hi), np.nan)


def _clipped_median(a, valid, *, nsigma=3.0, floor=0.0, iterations=3, return_kept=False):
    """Row-wise sigma-clipped median of ``a`` (N, P) over the entries where ``valid``; the scale
    is 1.4826 MAD, at least ``floor``. With ``return_kept``, also the mask of the entries kept."""
    a = np.where(valid, a, np.nan)
    med = _row_median(a)
    for _ in range(iterations):
        dev = np.abs(a - med[:, None])
        a = np.where(dev <= nsigma * np.maximum(1.4826 * _row_median(dev), floor)[:, None], a, np.nan)
        med = _row_median(a)
    return (med, np.isfinite(a)) if return_kept else med


def _start_centres(win, ox, oy, r_fit) -> tuple:
    """``(x, y)`` (N,), the fit's start: the first moment of each window ``win`` (N, P) inside
    its fit region (radius ``r_fit`` (N, 1) less a pixel, about the offsets ``ox``, ``oy``
    (P,) from the window's centre pixel), re-centred twice, within a pixel of the centre."""
    N = len(win)
    x = np.zeros(N)
    y = np.zeros(N)
    for _ in range(3):
        s = np.where(np.hypot(ox - x[:, None], oy - y[:, None]) <= r_fit - 1.0, win, 0.0)  # 0 off the image
        tot = s.sum(axis=1)
        good = tot > 0
        x = np.clip(np.where(good, s @ ox / np.where(good, tot, 1.0), x), -1.0, 1.0)
        y = np.clip(np.where(good, s @ oy / np.where(good, tot, 1.0), y), -1.0, 1.0)
    return x, y


def _local_background(win, annulus, u, v, noise: float):
    """Each window's local background (N, P): the sigma-clipped median of its ``annulus`` pixels
    (a mask (N, P)) and its slope, a plane through the kept annulus pixels (stray light, a
    gradient under the dot) in the offsets ``u``, ``v`` (N, P) from the start centre."""
    b, kept = _clipped_median(win, annulus, floor=0.5 * noise, return_kept=True)
    b = np.where(np.isfinite(b), b, 0.0)
    k = kept.astype(float)
    G = np.stack([np.stack([(k * u * u).sum(1), (k * u * v).sum(1)], -1),
                  np.stack([(k * u * v).sum(1), (k * v * v).sum(1)], -1)], -2)
    rhs = np.stack([(k * u * (win - b[:, None])).sum(1), (k * v * (win - b[:, None])).sum(1)], -1)
    ok = np.linalg.det(G) > 1e-6 * np.maximum(np.einsum("nii->n", G), 1.0) ** 2
    G = np.where(ok[:, None, None], G, np.eye(2))
    slope = np.where(ok[:, None], np.linalg.solve(G, rhs[..., None])[..., 0], 0.0)
    return b[:, None] + slope[:, :1] * u + slope[:, 1:] * v


def _fit_discs(data, fitm, ox, oy, x, y, r_blob, h: int, noise: float) -> tuple:
    """The blurred-disc fit of every window at once: ``(q, c, wgt)``, the parameters (N, 5)
    ``(x, y, A, R, s)`` (centre offset, amplitude, disc radius, blur), the weighted sum of
    squared residuals (N,) and the weights (N, P) that outliers (a hot pixel, a cosmic ray)
    left. Levenberg-Marquardt steps with per-dot acceptance from ``(x, y)``, on the
    background-subtracted ``data`` (N, P) over the fit region ``fitm`` (N, P), at the offsets
    ``ox``, ``oy`` (P,); the radius is kept within the window's half-size ``h``."""
    N = len(data)
    a0 = np.mean(np.sort(np.where(fitm > 0, data, -np.inf), axis=1)[:, -5:], axis=1)
    q = np.stack([x, y, np.maximum(a0, noise), r_blob, np.full(N, 0.6)], -1)  # x, y, A, R, s
    sq2 = math.sqrt(2.0)

    def evaluate(q):
        dx = ox - q[:, 0, None]
        dy = oy - q[:, 1, None]
        r = np.maximum(np.hypot(dx, dy), 1e-9)
        u = (r - q[:, 3, None]) / (sq2 * q[:, 4, None])
        g = 0.5 * erfc(u)
        return data - q[:, 2, None] * g, (g, u, r, dx, dy)

    wgt = fitm
    res, parts = evaluate(q)
    c = (wgt * res * res).sum(axis=1)
    lam = np.full(N, 1e-3)
    eye = np.eye(5)
    for it in range(GAUSS_NEWTON_ITERATIONS):
        if it in OUTLIER_PASSES:  # mask outliers (hot pixel, cosmic ray) against the current fit
            sd = np.maximum(1.4826 * _row_median(np.where(fitm > 0, np.abs(res), np.nan)), noise)
            wgt = fitm * (np.abs(res) <= OUTLIER_SIGMA * sd[:, None])
            c = (wgt * res * res).sum(axis=1)
        g, u, r, dx, dy = parts
        A, s = q[:, 2, None], q[:, 4, None]
        df_du = A * (-np.exp(-u * u) / math.sqrt(math.pi))  # d(model)/du
        df_dr = df_du / (sq2 * s)
        J = np.stack([-df_dr * dx / r, -df_dr * dy / r, g, -df_dr, -df_du * u / s], -1)   # (N, P, 5)
        JwT = (J * wgt[..., None]).transpose(0, 2, 1)
        JTJ = np.matmul(JwT, J)
        JTr = np.matmul(JwT, res[..., None])
        M = JTJ + lam[:, None, None] * JTJ * eye
        try:
            step = np.linalg.solve(M, JTr)[..., 0]
        except np.linalg.LinAlgError:  # a degenerate window (no signal)
            step = np.matmul(np.linalg.pinv(M), JTr)[..., 0]
        qn = q + step
        qn[:, 3] = np.clip(qn[:, 3], 0.1, h)
        qn[:, 4] = np.clip(qn[:, 4], 0.1, 5.0)
        resn, partsn = evaluate(qn)
        cn = (wgt * resn * resn).sum(axis=1)
        better = np.isfinite(cn) & (cn <= c)
        q = np.where(better[:, None], qn, q)
        c = np.where(better, cn, c)
        res = np.where(better[:, None], resn, res)
        parts = tuple(np.where(better[:, None], p1, p0) for p0, p1 in zip(parts, partsn))
        lam = np.where(better, lam * 0.3, lam * 10.0)
    return q, c, wgt


def _fit_windows(sig, cyx, r_blob, h, noise):
    """Centres (x, y) and fluxes of the dots near ``cyx`` (rows, cols), windows of half-size ``h``
    (pixels beyond the image left out); NaN where the fit fails or the blob is not a dot."""
    H, W = sig.shape
    n = len(cyx)
    out = np.full((n, 2), np.nan)
    flux = np.zeros(n)
    cy0, cx0 = np.round(cyx[:, 0]).astype(int), np.round(cyx[:, 1]).astype(int)
    # a window may cross the image edge (its pixels there are left out), its centre may not
    idx = np.flatnonzero((cy0 >= 0) & (cx0 >= 0) & (cy0 < H) & (cx0 < W))
    if not idx.size:
        return out, flux
    cy0, cx0, r_blob = cy0[idx], cx0[idx], r_blob[idx]
    # the window's pixels as a flat list of offsets from its centre pixel: windows (N, P)
    d = np.arange(-h, h + 1)
    oyi, oxi = (a.ravel() for a in np.meshgrid(d, d, indexing="ij"))
    oy, ox = oyi.astype(float), oxi.astype(float)
    win = np.pad(sig, h, constant_values=np.nan)[cy0[:, None] + oyi + h, cx0[:, None] + oxi + h]
    valid = np.isfinite(win)
    win = np.where(valid, win, 0.0)
    span = min(1.0, h / (r_blob.max() + FIT_MARGIN_PX + ANNULUS_PX))  # a window fixed by the caller
    r_fit = (r_blob + FIT_MARGIN_PX * span)[:, None]
    r_out = (r_blob + (FIT_MARGIN_PX + ANNULUS_PX) * span)[:, None]

    x, y = _start_centres(win, ox, oy, r_fit)
    rr = np.hypot(ox - x[:, None], oy - y[:, None])
    back = _local_background(win, valid & (rr > r_fit) & (rr <= r_out), ox - x[:, None], oy - y[:, None], noise)

    # the fit sees only the pixels that can fall in a fit region
    keep = np.flatnonzero(np.hypot(ox, oy) <= float(r_fit.max()) + 1.5)
    data = win[:, keep] - back[:, keep]
    fitm = ((rr[:, keep] <= r_fit) & valid[:, keep]).astype(float)
    q, c, wgt = _fit_discs(data, fitm, ox[keep], oy[keep], x, y, r_blob, h, noise)

    # not a dot: a cosmic-ray track or a merged blob the disc model cannot describe (most of its
    # pixels masked, or a residual far above the other dots')
    n_fit = fitm.sum(axis=1)
    rms = np.sqrt(c / np.maximum(wgt.sum(axis=1), 1.0))
    shaped = (wgt.sum(axis=1) >= 0.7 * n_fit) & (rms <= SHAPE_RMS_FACTOR * max(float(np.median(rms)), noise))
    good = (np.abs(q[:, 0]) <= 1.5) & (np.abs(q[:, 1]) <= 1.5) & (q[:, 2] > 0) & np.isfinite(c) & shaped
    out[idx] = np.where(good[:, None], np.stack([cx0 + q[:, 0], cy0 + q[:, 1]], -1), np.nan)
    flux[idx] = (fitm * data).sum(axis=1)
    return out, flux


def relative_response(flats, background, max_dn=None) -> np.ndarray | None:
    """Each pixel's response to a uniform screen relative to the median pixel (PRNU, vignetting,
    screen non-uniformity, solid angle of a screen pixel), from flat captures.

    Parameters
    ----------
    flats : sequence of ndarray, shape (H, W), DN
        The flat captures (any levels: each is weighted by its own median signal).
    background : float
        Background level, DN (the dark's median).
    max_dn : int, optional
        The camera's full scale: a saturated pixel of a flat is left out of that pixel's sum, and a
        flat whose median is within 10 % of full scale is left out.

    Returns
    -------
    ndarray, shape (H, W), or None without usable flats. Pixels the flats hardly reach (< 5 % of
    the median) get 1.
    """
    num = den = None
    for img in flats:
        img = np.asarray(img, dtype=float)
        level = float(np.median(img)) - background
        if level <= 0 or (max_dn is not None and level + background >= 0.9 * max_dn):
            continue
        ok = np.ones(img.shape, bool) if max_dn is None else img < max_dn
        if num is None:
            num, den = np.zeros(img.shape), np.zeros(img.shape)
        num += np.where(ok, img - background, 0.0)
        den += np.where(ok, level, 0.0)
    if num is None:
        return None
    with np.errstate(invalid="ignore", divide="ignore"):
        resp = num / den
    return np.where(np.isfinite(resp) & (resp > 0.05), resp, 1.0)
