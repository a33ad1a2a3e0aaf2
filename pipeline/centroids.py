"""Spot detection and centroids (Andreis et al. (2023a), Sec. III.A.1, Eq. 6-8).

Core module. Threshold ``I_thr = mean + T * std`` over the image (Eq. 6), connected regions of
the pixels above it (8-connectivity), the ROI of each region with a one-pixel margin, and the centre of brightness with the weight
``w = I / I_max`` inside the ROI (Eq. 7-8), i.e. a sum of ``I^2`` moments.

Pixel convention (docs/conventions.md): x along columns, y along rows, the centre of the top-left pixel
is (0, 0), so the ROI pixel ``[i, j]`` has ``X = j``, ``Y = i``.

Saturated spots: the plateau of clipped pixels has equal weights, so the centroid is the centre of
the plateau plus its rim, which is unbiased for a symmetric PSF; the spot is flagged. Streaked
spots: the centre of brightness of the whole streak is the mid-exposure position for a constant
rate, and the region's elongation is reported so the caller can tell streaks from stars.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

__all__ = ["Spots", "detect_spots", "threshold"]


@dataclass(frozen=True, kw_only=True, eq=False)
class Spots:
    """Detected spots, brightest first.

    Attributes
    ----------
    xy_px : ndarray, shape (N, 2), px
        Centroids (x = column).
    flux_dn : ndarray, shape (N,)
        Sum of background-subtracted DN in the ROI.
    peak_dn : ndarray, shape (N,)
        Brightest pixel, DN.
    n_pixels : ndarray of int, shape (N,)
        Pixels above the threshold in the region.
    saturated : ndarray of bool, shape (N,)
        The region holds a pixel at the sensor's maximum DN.
    elongation : ndarray, shape (N,)
        sqrt of the ratio of the second-moment eigenvalues (1 for a round spot).
    size_px : ndarray, shape (N,)
        Largest side of the region's bounding box, px.
    threshold_dn : float
        The threshold used (Eq. 6).
    """

    xy_px: np.ndarray
    flux_dn: np.ndarray
    peak_dn: np.ndarray
    n_pixels: np.ndarray
    saturated: np.ndarray
    elongation: np.ndarray
    size_px: np.ndarray
    threshold_dn: float

    def __len__(self) -> int:
        return len(self.xy_px)

    def take(self, idx) -> "Spots":
        idx = np.asarray(idx, dtype=np.intp)
        return Spots(xy_px=self.xy_px[idx], flux_dn=self.flux_dn[idx], peak_dn=self.peak_dn[idx],
                     n_pixels=self.n_pixels[idx], saturated=self.saturated[idx],
                     elongation=self.elongation[idx], size_px=self.size_px[idx], threshold_dn=self.threshold_dn)

    @classmethod
    def empty(cls, threshold_dn=float("nan")) -> "Spots":
        z = np.zeros(0)
        return cls(xy_px=np.zeros((0, 2)), flux_dn=z, peak_dn=z, n_pixels=np.zeros(0, dtype=int),
                   saturated=np.zeros(0, dtype=bool), elongation=z, size_px=z, threshold_dn=threshold_dn)


def threshold(image: np.ndarray, T: float) -> float:
    """Eq. 6: ``I_thr = mu_I + T sigma_I`` over the whole image, DN."""
    img = np.asarray(image, dtype=float)
    return float(img.mean() + T * img.std())


def detect_spots(image, *, T: float = 5.0, max_dn: float | None = None, min_pixels: int = 1,
                 max_regions: int = 5000, background: str = "mean", threshold_dn: float | None = None,
                 stats_stride: int = 1, windows_xy=None, window_half_px: float | np.ndarray = 0,
                 background_dn: float | None = None) -> Spots:
    """Spots of an image: Eq. 6 threshold, connected regions, Eq. 7-8 centroids.

    Parameters
    ----------
    image : ndarray, shape (H, W)
        Digital counts (any numeric dtype).
    T : float
        Tuning parameter of Eq. 6.
    max_dn : float, optional
        Saturation level; pixels at or above it mark a spot ``saturated``.
    min_pixels : int
        Regions with fewer pixels above the threshold are dropped (1 keeps single hot pixels,
        which star ID then treats as spikes).
    max_regions : int
        At most this many regions are returned (the brightest); a caller that gets
        ``max_regions`` back knows the frame is not a star field.
    background : {"mean", "median"}
        Level subtracted from the ROI intensities before the moments ("mean": Eq. 6's mu_I,
        the paper; "median": robust to bright extended objects).
    threshold_dn : float, optional
        Use this threshold instead of Eq. 6 (the improved mode's robust one).
    stats_stride : int
        Mean and standard deviation from every ``stats_stride``-th row and column (speed).
    windows_xy : ndarray, shape (K, 2), optional
        Tracking: threshold only the pixels of square windows centred on these predicted
        positions (x = column), half-size ``window_half_px`` (scalar or (K,)), instead of the
        whole frame. Same regions and the same Eq. 7-8 centroids for every spot that lies wholly
        inside a window (the ROI margin may reach one pixel outside it).
    background_dn : float, optional
        With ``threshold_dn``: the background level already computed by the caller (speed).

    Returns
    -------
    Spots

    Notes
    -----
    Connected regions (8-connectivity) are found on the sparse set of pixels above the
    threshold with :func:`scipy.sparse.csgraph.connected_components` (flat indices, so no
    (row, col) / (x, y) flip is needed; x = flat % W, y = flat // W). The ROI of a region is the
    region plus its one-pixel margin (its 8-neighbours): the pixels of the paper's square ROI
    that touch the spot; the square's far corners hold only sub-threshold pixels, whose weight
    ``w I = I^2 / I_max`` is negligible. Since ``I_max`` is constant within a ROI, Eq. 7-8 reduce
    to ``x_c = sum(x I^2) / sum(I^2)``.
    """
    img = np.asarray(image)
    if img.ndim != 2 or img.size == 0:
        raise ValueError(f"image must be a non-empty 2-D array, got shape {img.shape}")
    H, W = img.shape
    thr, bg = _threshold_and_background(img, T=T, threshold_dn=threshold_dn, background_dn=background_dn,
                                        stats_stride=stats_stride, background=background)
    if not np.isfinite(thr) or bg is None:
        return Spots.empty(thr)
    flat_img = img.ravel()
    if windows_xy is None:
        f = np.flatnonzero(flat_img > thr)
    else:
        f = _window_pixels(np.asarray(windows_xy, float).reshape(-1, 2), window_half_px, H, W, flat_img, thr)
    P = len(f)
    if P == 0:
        return Spots.empty(thr)
    if P > 200_000:  # not a star field (a blinded or flat frame): one region per pixel is pointless
        return Spots.empty(thr)
    n, lab = _label_regions(f, W)
    npix = np.bincount(lab, minlength=n)
    flux, xc, yc, elong, i00 = _roi_moments(flat_img, f, lab, n, H, W, bg)
    elong = np.where(npix >= 3, elong, 1.0)
    peak = np.zeros(n)
    np.maximum.at(peak, lab, flat_img[f].astype(np.float64))
    size = _region_size(f, lab, n, H, W)
    keep = np.flatnonzero((npix >= min_pixels) & (i00 > 0))
    keep = keep[np.argsort(-flux[keep], kind="stable")][:max_regions]
    sat = peak[keep] >= max_dn if max_dn is not None else np.zeros(len(keep), bool)
    return Spots(xy_px=np.stack([xc[keep], yc[keep]], -1), flux_dn=flux[keep], peak_dn=peak[keep],
                 n_pixels=npix[keep], saturated=sat, elongation=elong[keep], size_px=size[keep].astype(float),
                 threshold_dn=thr)


def _threshold_and_background(img, *, T, threshold_dn, background_dn, stats_stride, background):
    """``(threshold, background)`` DN of :func:`detect_spots`: Eq. 6 (``mean + T std`` of every
    ``stats_stride``-th row and column) unless ``threshold_dn`` is given; the background is
    ``background_dn``, else that sample's mean or median. ``background`` None: no spot can be found
    (a non-finite threshold, or a flat frame under Eq. 6)."""
    if threshold_dn is not None and background_dn is not None:
        return float(threshold_dn), float(background_dn)
    sub = img[::stats_stride, ::stats_stride].astype(np.float64)
    mu = float(sub.mean())
    sd = float(sub.std())
    thr = mu + T * sd if threshold_dn is None else float(threshold_dn)
    if not np.isfinite(thr) or (threshold_dn is None and sd == 0.0):
        return thr, None
    if background_dn is not None:
        return thr, float(background_dn)
    return thr, (mu if background == "mean" else float(np.median(sub)))


def _label_regions(f, W):
    """``(n, labels)``: the 8-connected regions of the pixels at the sorted flat indices ``f`` of
    an image ``W`` wide (links to the right and to the next row, found by searching ``f``)."""
    P = len(f)
    col = f % W
    src, dst = [np.arange(P)], [np.arange(P)]
    for off, ok in ((1, col < W - 1), (W - 1, col > 0), (W, np.ones(P, bool)), (W + 1, col < W - 1)):
        g = f + off
        pos = np.searchsorted(f, g)
        pos_c = np.minimum(pos, P - 1)
        hit = ok & (pos < P) & (f[pos_c] == g)
        src.append(np.flatnonzero(hit))
        dst.append(pos_c[hit])
    src, dst = np.concatenate(src), np.concatenate(dst)
    graph = coo_matrix((np.ones(len(src), np.int8), (src, dst)), shape=(P, P))
    return connected_components(graph, directed=False)


def _roi_moments(flat_img, f, lab, n, H, W, bg):
    """``(flux, xc, yc, elongation, i00)`` per region: Eq. 7-8 over its ROI, the region's pixels
    plus their 8-neighbours (the first label wins where two margins meet), intensities above
    ``bg``; the elongation from the ``I^2``-weighted second moments (nan where ``i00`` is 0)."""
    rows, col = f // W, f % W
    offs_r = np.array([-1, -1, -1, 0, 0, 0, 1, 1, 1])
    offs_c = np.array([-1, 0, 1, -1, 0, 1, -1, 0, 1])
    rr = (rows[None, :] + offs_r[:, None]).ravel()
    cc = (col[None, :] + offs_c[:, None]).ravel()
    ll = np.tile(lab, 9)
    inside = (rr >= 0) & (rr < H) & (cc >= 0) & (cc < W)
    rr, cc, ll = rr[inside], cc[inside], ll[inside]
    ff = rr * W + cc
    ff, first = np.unique(ff, return_index=True)
    ll = ll[first]
    rr, cc = ff // W, ff % W
    I = np.clip(flat_img[ff].astype(np.float64) - bg, 0.0, None)
    I2 = I * I  # I w with w = I / I_max; the constant 1 / I_max cancels in Eq. 8
    i00 = np.bincount(ll, I2, minlength=n)
    i10 = np.bincount(ll, I2 * cc, minlength=n)
    i01 = np.bincount(ll, I2 * rr, minlength=n)
    flux = np.bincount(ll, I, minlength=n)
    with np.errstate(invalid="ignore", divide="ignore"):
        xc = i10 / i00
        yc = i01 / i00
        cxx = np.bincount(ll, I2 * cc * cc, minlength=n) / i00 - xc * xc
        cyy = np.bincount(ll, I2 * rr * rr, minlength=n) / i00 - yc * yc
        cxy = np.bincount(ll, I2 * cc * rr, minlength=n) / i00 - xc * yc
        tr, det = cxx + cyy, cxx * cyy - cxy * cxy
        disc = np.sqrt(np.clip(tr * tr / 4 - det, 0.0, None))
        elong = np.sqrt((tr / 2 + disc) / np.clip(tr / 2 - disc, 1e-6, None))
    return flux, xc, yc, elong, i00


def _region_size(f, lab, n, H, W):
    """The largest side of each region's bounding box, px."""
    rows, col = f // W, f % W
    rmin = np.full(n, H)
    rmax = np.zeros(n, int)
    cmin = np.full(n, W)
    cmax = np.zeros(n, int)
    np.minimum.at(rmin, lab, rows)
    np.maximum.at(rmax, lab, rows)
    np.minimum.at(cmin, lab, col)
    np.maximum.at(cmax, lab, col)
    return np.maximum(rmax - rmin, cmax - cmin) + 1


def _window_pixels(xy, half, H, W, flat_img, thr) -> np.ndarray:
    """Sorted unique flat indices of the pixels above ``thr`` inside the square windows (centre
    ``xy`` rounded, half-size ``half`` px, scalar or per window) clipped to the image."""
    if len(xy) == 0:
        return np.zeros(0, dtype=np.intp)
    half = np.broadcast_to(np.ceil(np.asarray(half, float)).astype(np.intp), (len(xy),))
    ok = np.all(np.isfinite(xy), axis=1)
    xy, half = xy[ok], half[ok]
    cx = np.rint(xy[:, 0]).astype(np.intp)
    cy = np.rint(xy[:, 1]).astype(np.intp)
    ok = (cx + half >= 0) & (cx - half < W) & (cy + half >= 0) & (cy - half < H)
    cx, cy, half = cx[ok], cy[ok], half[ok]
    out = []
    for h in np.unique(half):
        sel = half == h
        d = np.arange(-h, h + 1)
        rr = np.clip(cy[sel, None] + d[None, :], 0, H - 1)
        cc = np.clip(cx[sel, None] + d[None, :], 0, W - 1)
        f = (rr[:, :, None] * W + cc[:, None, :]).ravel()
        out.append(f[flat_img[f] > thr])
    if not out:
        return np.zeros(0, dtype=np.intp)
    return np.unique(np.concatenate(out))
