"""Sub-pixel detection of dots in a camera capture: threshold and label, then a blurred-disc fit.

1. The capture, less the background level, is divided by the camera's relative response (``gain``,
   per pixel: the flat captures, so PRNU, vignetting, the screen's non-uniformity and the solid
   angle of a screen pixel all cancel and a dot becomes the plain image of a disc).
2. Blobs are found above a threshold halfway between the background and the bright dots and
   labelled (scikit-image, (row, col) order flipped to (x, y) here). Blobs much smaller than the
   typical dot (hot pixels, cosmic-ray hits) or touching the image edge are dropped, and so is a
   dot whose window leaves the image.
3. Each dot gets a square window (all dots of one size are stacked into an ``(N, w, w)`` array:
   no per-dot Python loop), re-centred on the first moment of its signal, and a local background:
   the sigma-clipped median of an annulus around the dot.
4. The centre is the least-squares fit of a blurred disc, ``A * erfc((r - R) / (sqrt(2) s)) / 2``
   (a disc of radius ``R`` seen through a Gaussian blur ``s``: defocus and pixel footprint), with
   ``x, y, A, R, s`` free, by a few damped Gauss-Newton iterations over all dots at once, started
   from the moment centroid. Pixels far off the fitted model (a hot pixel or a cosmic ray next to
   the dot) are masked out and the fit repeated.

The model is point-symmetric about its centre, as the image of a small disc is to first order in
the distortion, so its mismatch with the true dot shape (an ellipse, a non-Gaussian blur) does not
move the centre; a first moment in a finite window, by contrast, is pulled by the window's edge and
sums the noise of every pixel with a lever arm.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# fit region: the dot's threshold radius plus this margin (px); the background annulus lies
# between the fit region and the window's edge, ANNULUS_PX wide
FIT_MARGIN_PX = 2.5
ANNULUS_PX = 2.5
GAUSS_NEWTON_ITERATIONS = 8
OUTLIER_SIGMA = 6.0


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
        Half-size of the fit window (the fit region and the background annulus are scaled into
        it); default from each blob's size.
    """
    from skimage import measure

    img = np.asarray(image, dtype=float)
    bg = float(np.median(img if background is None else background))
    sig = img - bg
    if gain is not None:
        sig = sig / np.asarray(gain, dtype=float)
    noise = 1.4826 * np.median(np.abs(sig - np.median(sig))) + 0.5
    bright = np.percentile(sig, 99.9)
    thr = max(0.3 * bright, 6.0 * noise)
    labels = measure.label(sig > thr, connectivity=2)
    props = measure.regionprops(labels)
    if not props:
        return _empty()
    areas = np.array([p.area for p in props], dtype=float)
    bbox = np.array([p.bbox for p in props])
    cyx = np.array([p.centroid for p in props])
    H, W = img.shape
    keep = (areas >= 0.25 * np.median(areas)) & (bbox[:, 0] > 0) & (bbox[:, 1] > 0) & (bbox[:, 2] < H) & (bbox[:, 3] < W)
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


def _fit_windows(sig, cyx, r_blob, h, noise):
    """Centres (x, y) and fluxes of the dots near ``cyx`` (rows, cols), windows of half-size ``h``;
    NaN where a window leaves the image or the fit fails."""
    H, W = sig.shape
    n = len(cyx)
    out = np.full((n, 2), np.nan)
    flux = np.zeros(n)
    cy0, cx0 = np.round(cyx[:, 0]).astype(int), np.round(cyx[:, 1]).astype(int)
    inside = (cy0 - h >= 0) & (cx0 - h >= 0) & (cy0 + h < H) & (cx0 + h < W)
    idx = np.flatnonzero(inside)
    if not idx.size:
        return out, flux
    cy0, cx0, r_blob = cy0[idx], cx0[idx], r_blob[idx]
    d = np.arange(-h, h + 1)
    win = sig[(cy0[:, None] + d)[:, :, None], (cx0[:, None] + d)[:, None, :]]     # (N, w, w)
    yy, xx = np.meshgrid(d.astype(float), d.astype(float), indexing="ij")         # window coords
    # scale the fit region and the annulus into a window that was fixed by the caller
    span = min(1.0, h / (r_blob.max() + FIT_MARGIN_PX + ANNULUS_PX))
    r_fit = (r_blob + FIT_MARGIN_PX * span)[:, None, None]
    r_out = (r_blob + (FIT_MARGIN_PX + ANNULUS_PX) * span)[:, None, None]

    # first moment of the signal inside the fit region, re-centred twice (start of the fit)
    x = np.zeros(len(idx))
    y = np.zeros(len(idx))
    for _ in range(3):
        rr = np.hypot(xx - x[:, None, None], yy - y[:, None, None])
        s = np.where(rr <= r_fit - 1.0, win, 0.0)
        tot = s.sum(axis=(1, 2))
        good = tot > 0
        x = np.where(good, (s * xx).sum(axis=(1, 2)) / np.where(good, tot, 1.0), x)
        y = np.where(good, (s * yy).sum(axis=(1, 2)) / np.where(good, tot, 1.0), y)
    x, y = np.clip(x, -1.0, 1.0), np.clip(y, -1.0, 1.0)
    rr = np.hypot(xx - x[:, None, None], yy - y[:, None, None])

    # local background: sigma-clipped median of the annulus
    ann = np.where((rr > r_fit) & (rr <= r_out), win, np.nan).reshape(len(idx), -1)
    for _ in range(3):
        med = np.nanmedian(ann, axis=1)
        mad = 1.4826 * np.nanmedian(np.abs(ann - med[:, None]), axis=1)
        ann = np.where(np.abs(ann - med[:, None]) <= 3.0 * np.maximum(mad, 0.5 * noise)[:, None], ann, np.nan)
    b = np.nanmedian(ann, axis=1)
    b = np.where(np.isfinite(b), b, 0.0)
    data = win - b[:, None, None]
    fitm = (rr <= r_fit).astype(float)

    # blurred-disc fit, all dots at once (damped Gauss-Newton with per-dot step acceptance)
    q = np.stack([x, y, np.zeros(len(idx)), r_blob, np.full(len(idx), 0.6)], -1)  # x, y, A, R, s
    top = np.sort(np.where(fitm > 0, data, -np.inf).reshape(len(idx), -1), axis=1)[:, -5:]
    q[:, 2] = np.maximum(np.mean(top, axis=1), noise)
    wgt = fitm.copy()
    lam = np.full(len(idx), 1e-3)

    def model(q):
        dx = xx - q[:, 0, None, None]
        dy = yy - q[:, 1, None, None]
        r = np.maximum(np.hypot(dx, dy), 1e-9)
        s = q[:, 4, None, None]
        u = (r - q[:, 3, None, None]) / (np.sqrt(2.0) * s)
        from scipy.special import erfc

        g = 0.5 * erfc(u)
        return g, u, r, dx, dy

    def cost(q, wgt):
        g, *_ = model(q)
        res = data - q[:, 2, None, None] * g
        return (wgt * res * res).sum(axis=(1, 2)), res

    c, res = cost(q, wgt)
    for it in range(GAUSS_NEWTON_ITERATIONS):
        if it in (3, 5):  # mask outliers (hot pixel, cosmic ray) against the current fit
            sd = np.maximum(1.4826 * _masked_median_abs(res, fitm), noise)
            wgt = fitm * (np.abs(res) <= OUTLIER_SIGMA * sd[:, None, None])
            c, res = cost(q, wgt)
        g, u, r, dx, dy = model(q)
        A, s = q[:, 2, None, None], q[:, 4, None, None]
        dg_du = -np.exp(-u * u) / np.sqrt(np.pi)
        df_dr = A * dg_du / (np.sqrt(2.0) * s)
        J = np.stack([-df_dr * dx / r, -df_dr * dy / r, g, -df_dr, -A * dg_du * u / s], -1).reshape(len(idx), -1, 5)
        wv = wgt.reshape(len(idx), -1)
        JTJ = np.einsum("npi,np,npj->nij", J, wv, J)
        JTr = np.einsum("npi,np->ni", J, wv * res.reshape(len(idx), -1))
        diag = np.einsum("nii->ni", JTJ)
        M = JTJ + lam[:, None, None] * np.einsum("ni,ij->nij", diag, np.eye(5))
        try:
            step = np.linalg.solve(M, JTr[..., None])[..., 0]
        except np.linalg.LinAlgError:  # a degenerate window (no signal): its step is then 0
            step = np.einsum("nij,nj->ni", np.linalg.pinv(M), JTr)
        qn = q + step
        qn[:, 4] = np.clip(qn[:, 4], 0.1, 5.0)
        qn[:, 3] = np.clip(qn[:, 3], 0.1, h)
        cn, resn = cost(qn, wgt)
        better = np.isfinite(cn) & (cn <= c)
        q = np.where(better[:, None], qn, q)
        c = np.where(better, cn, c)
        res = np.where(better[:, None, None], resn, res)
        lam = np.where(better, lam * 0.3, lam * 10.0)
    good = (np.abs(q[:, 0]) <= 1.5) & (np.abs(q[:, 1]) <= 1.5) & (q[:, 2] > 0) & np.isfinite(c)
    out[idx] = np.where(good[:, None], np.stack([cx0 + q[:, 0], cy0 + q[:, 1]], -1), np.nan)
    flux[idx] = (fitm * data).sum(axis=(1, 2))
    return out, flux


def _masked_median_abs(res, mask):
    a = np.where(mask > 0, np.abs(res), np.nan).reshape(len(res), -1)
    return np.nanmedian(a, axis=1)


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
