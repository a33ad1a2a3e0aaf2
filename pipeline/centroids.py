"""Spot detection and centroids (paper 000 section III.A.1, Eq. 6-8).

Core module. Threshold ``I_thr = mean + T * std`` over the image (Eq. 6), connected regions of
the pixels above it (8-connectivity, scikit-image, (row, col) flipped to (x, y)), a square ROI
around each region with a one-pixel margin, and the centre of brightness with the weight
``w = I / I_max`` inside the ROI (Eq. 7-8), i.e. a sum of ``I^2`` moments.

Pixel convention (CONVENTIONS.md): x along columns, y along rows, the centre of the top-left pixel
is (0, 0), so the ROI pixel ``[i, j]`` has ``X = j``, ``Y = i``.

Saturated spots: the plateau of clipped pixels has equal weights, so the centroid is the centre of
the plateau plus its rim, which is unbiased for a symmetric PSF; the spot is flagged. Streaked
spots: the centre of brightness of the whole streak is the mid-exposure position for a constant
rate, and the region's elongation is reported so the caller can tell streaks from stars.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

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
                 max_regions: int = 5000, background: str = "mean") -> Spots:
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
        Stop labelling when there are more regions than this (a frame of noise); the result is
        then truncated to the brightest ``max_regions``.
    background : {"mean", "median"}
        Level subtracted from the ROI intensities before the moments ("mean": Eq. 6's mu_I,
        the paper; "median": robust to bright extended objects).

    Returns
    -------
    Spots
    """
    from scipy import ndimage

    img = np.asarray(image, dtype=np.float32)
    if img.ndim != 2 or img.size == 0:
        raise ValueError(f"image must be a non-empty 2-D array, got shape {img.shape}")
    mu = float(img.mean())
    sd = float(img.std())
    thr = mu + T * sd
    if not np.isfinite(thr) or sd == 0.0:
        return Spots.empty(thr)
    mask = img > thr
    # 8-connectivity labelling (scipy.ndimage is what skimage.measure.label calls; (row, col) arrays)
    labels, n = ndimage.label(mask, structure=np.ones((3, 3), dtype=bool))
    if n == 0:
        return Spots.empty(thr)
    bg = mu if background == "mean" else float(np.median(img))
    slices = ndimage.find_objects(labels)
    H, W = img.shape
    npix_all = np.bincount(labels.ravel(), minlength=n + 1)[1:]
    keep = np.flatnonzero(npix_all >= min_pixels)
    if len(keep) > max_regions:
        peaks = ndimage.maximum(img, labels, keep + 1)
        keep = keep[np.argsort(-np.asarray(peaks))[:max_regions]]
    xy = np.empty((len(keep), 2))
    flux = np.empty(len(keep))
    peak = np.empty(len(keep))
    sat = np.zeros(len(keep), dtype=bool)
    elong = np.ones(len(keep))
    size = np.empty(len(keep))
    for m, k in enumerate(keep):
        sr, sc = slices[k]
        # square ROI with a one-pixel margin (paper 000 step 2), clipped to the image
        h, w = sr.stop - sr.start, sc.stop - sc.start
        side = max(h, w) + 2
        r0 = sr.start - 1 - (side - 2 - h) // 2
        c0 = sc.start - 1 - (side - 2 - w) // 2
        r0, c0 = max(r0, 0), max(c0, 0)
        r1, c1 = min(r0 + side, H), min(c0 + side, W)
        roi = img[r0:r1, c0:c1] - bg
        lab = labels[r0:r1, c0:c1]
        # pixels of other regions inside the ROI do not belong to this spot
        roi = np.where((lab == 0) | (lab == k + 1), roi, 0.0)
        roi = np.clip(roi, 0.0, None)
        imax = float(roi.max())
        peak[m] = float(img[sr, sc].max())
        size[m] = max(h, w)
        if imax <= 0.0:
            xy[m] = ((sc.start + sc.stop - 1) / 2.0, (sr.start + sr.stop - 1) / 2.0)
            flux[m] = 0.0
            continue
        wI = roi * (roi / imax)  # I * w with w = I / I_max (Eq. 7)
        i00 = float(wI.sum())
        rows = np.arange(r0, r1, dtype=float)[:, None]
        cols = np.arange(c0, c1, dtype=float)[None, :]
        xc = float((wI * cols).sum() / i00)
        yc = float((wI * rows).sum() / i00)
        xy[m] = (xc, yc)  # Eq. 8
        flux[m] = float(roi.sum())
        if max_dn is not None and peak[m] >= max_dn:
            sat[m] = True
        if npix_all[k] >= 3:
            dx = cols - xc
            dy = rows - yc
            cxx = float((wI * dx * dx).sum() / i00)
            cyy = float((wI * dy * dy).sum() / i00)
            cxy = float((wI * dx * dy).sum() / i00)
            tr, det = cxx + cyy, cxx * cyy - cxy * cxy
            disc = np.sqrt(max(tr * tr / 4 - det, 0.0))
            l1, l2 = tr / 2 + disc, max(tr / 2 - disc, 1e-6)
            elong[m] = float(np.sqrt(l1 / l2))
    order = np.argsort(-flux, kind="stable")
    return Spots(xy_px=xy[order], flux_dn=flux[order], peak_dn=peak[order], n_pixels=npix_all[keep][order],
                 saturated=sat[order], elongation=elong[order], size_px=size[order], threshold_dn=thr)
