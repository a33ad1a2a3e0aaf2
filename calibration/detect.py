"""Sub-pixel detection of dots in a camera capture (scikit-image labelling + windowed centroids).

Blobs are found above a threshold halfway between the background and the bright dots, labelled
(scikit-image, (row, col) order flipped to (x, y) here), then each centroid is the first moment of
the background-subtracted signal in a square window around the blob (all pixels, negative ones
too, so the estimate is unbiased), re-centred twice. Blobs much smaller than the typical dot (hot
pixels, cosmic-ray hits) or touching the image edge are dropped.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Blobs:
    xy_px: np.ndarray      # (N, 2) centroids, CONVENTIONS pixel coordinates
    flux: np.ndarray       # (N,) background-subtracted sum, DN
    area_px: np.ndarray    # (N,) pixels above the threshold


def detect_dots(image, *, background=None, window_px: int | None = None) -> Blobs:
    """Dots of a capture.

    Parameters
    ----------
    image : ndarray, shape (H, W), DN
    background : ndarray or float, optional
        Dark frame (its median is the level: a per-pixel subtraction would add the dark's own
        noise and rounding) or a level; default: the image median.
    window_px : int, optional
        Half-size of the centroid window; default from the blob sizes.
    """
    from skimage import measure

    img = np.asarray(image, dtype=float)
    bg = float(np.median(img if background is None else background))
    sig = img - bg
    noise = 1.4826 * np.median(np.abs(sig - np.median(sig))) + 0.5
    bright = np.percentile(sig, 99.9)
    thr = max(0.3 * bright, 6.0 * noise)
    labels = measure.label(sig > thr, connectivity=2)
    props = measure.regionprops(labels)
    if not props:
        return Blobs(np.zeros((0, 2)), np.zeros(0), np.zeros(0))
    areas = np.array([p.area for p in props], dtype=float)
    typical = np.median(areas)
    H, W = img.shape
    xy, flux, area = [], [], []
    for p, a in zip(props, areas):
        if a < 0.25 * typical:  # hot pixel, cosmic ray
            continue
        r0, c0, r1, c1 = p.bbox
        if r0 == 0 or c0 == 0 or r1 == H or c1 == W:
            continue
        h = window_px if window_px is not None else int(np.ceil(np.sqrt(a / np.pi) + 1.0))
        cy, cx = p.centroid
        ok = True
        for _ in range(3):
            y0, y1 = int(round(cy)) - h, int(round(cy)) + h + 1
            x0, x1 = int(round(cx)) - h, int(round(cx)) + h + 1
            if y0 < 0 or x0 < 0 or y1 > H or x1 > W:
                ok = False
                break
            s = sig[y0:y1, x0:x1]
            tot = s.sum()
            if tot <= 0:
                ok = False
                break
            yy, xx = np.mgrid[y0:y1, x0:x1]
            cy, cx = (s * yy).sum() / tot, (s * xx).sum() / tot
        if ok:
            xy.append((cx, cy))
            flux.append(tot)
            area.append(a)
    return Blobs(np.array(xy, dtype=float).reshape(-1, 2), np.array(flux), np.array(area))
