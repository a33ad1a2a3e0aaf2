"""Centroids measured in windows around predicted positions (tracking; Andreis et al. (2023a), Eq. 7-8).

Beside the full-frame detection (:mod:`~skynav.pipeline.centroids`): the same weights (``w = I /
I_max`` over the pixels above the threshold and their 8-neighbours, i.e. ``I^2`` moments) and the
same pixel convention (x along columns, the centre of the top-left pixel at (0, 0)), evaluated
only in small boxes around the stars and beacons predicted from a previous attitude.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from .centroids import Spots

__all__ = ["WindowCentroids", "window_centroids", "window_peaks", "spots_in_boxes"]


@dataclass(frozen=True)
class WindowCentroids:
    """Eq. 7-8 centroids measured in small windows around predicted positions (tracking).

    ``valid`` marks windows whose peak is above the threshold, lies inside the search box and
    whose ROI (the pixels above the threshold plus their 8-neighbours) does not touch the ROI's
    border (a spot larger than the ROI is remeasured with a larger ROI, else dropped)."""

    xy_px: np.ndarray        # (N, 2)
    flux_dn: np.ndarray      # (N,) sum of background-subtracted DN over the ROI
    peak_dn: np.ndarray      # (N,)
    n_pixels: np.ndarray     # (N,) pixels above the threshold in the ROI
    valid: np.ndarray        # (N,) bool


def window_centroids(image, xy_px, *, threshold_dn: float, background_dn: float, search_half_px: int = 0,
                     roi_half_px: int = 3, max_roi_half_px: int = 8) -> WindowCentroids:
    """Eq. 7-8 centroids of the spots near predicted positions, without a full-frame pass.

    For each predicted position (x = column, CONVENTIONS pixel centres): the brightest pixel
    within ``search_half_px`` of the rounded position is the spot's peak; the ROI is the
    ``(2 roi_half_px + 1)^2`` box around the peak, and in it the pixels above ``threshold_dn``
    and their 8-neighbours are weighted by ``I^2`` (``w = I / I_max`` of Eq. 7, ``I`` above
    ``background_dn``), as :func:`detect_spots` weights a region and its one-pixel margin. A ROI
    whose above-threshold pixels reach its border is widened (up to ``max_roi_half_px``) so a
    bright or saturated spot is not truncated. Every window is one vectorised gather (speed: docs/pipeline.md).
    """
    # the brightest pixel of the search box: each box is one row of a (n, (2s + 1)^2) gather of
    # flat indices. Below, every per-window array is compact (the windows still measured),
    # scattered once.
    s = int(search_half_px)
    flat, (H, W), n, idx, c = _search_windows(image, xy_px, s)
    out_xy = np.full((n, 2), np.nan)
    flux, peak, npx = np.zeros(n), np.zeros(n), np.zeros(n, dtype=int)
    valid = np.zeros(n, dtype=bool)
    if not len(idx):
        return WindowCentroids(xy_px=out_xy, flux_dn=flux, peak_dn=peak, n_pixels=npx, valid=valid)
    cx, cy = c[:, 0], c[:, 1]
    if s > 0:
        box = flat.take((cy * W + cx)[:, None] + _box_offsets(s, W))
        k = box.argmax(axis=1)
        ky, kx = np.divmod(k, 2 * s + 1)
        cy = cy + (ky - s)
        cx = cx + (kx - s)
        pk0 = box[np.arange(len(idx)), k]
    else:
        pk0 = flat.take(cy * W + cx)
    # a peak at or below the threshold is no spot: only the others are measured
    sel = (pk0.astype(np.float64) > threshold_dn).nonzero()[0]
    pending, cx, cy = idx.take(sel), cx.take(sel), cy.take(sel)
    c0 = cy * W + cx
    # distance of each peak to the image's edge: a ROI plus its ring must fit inside
    edge = np.minimum(np.minimum(cx, W - 1 - cx), np.minimum(cy, H - 1 - cy))
    r = int(roi_half_px)
    bg32 = np.float32(background_dn)
    zero32 = np.float32(0.0)
    # the test "float32(I) > threshold" (the threshold rounded to float32) on integer counts is
    # "I > floor(float32 threshold)": compared in the image's own dtype, without a float copy
    int_thr = _int_threshold(flat.dtype, threshold_dn)
    while len(pending):
        inb = (edge >= r + 1).nonzero()[0]
        i, ci, edge = pending.take(inb), c0.take(inb), edge.take(inb)
        cxi, cyi = cx.take(inb), cy.take(inb)
        # the ROI plus a one-pixel ring, so the 8-neighbour dilation sees past the ROI's edge:
        # one (2r + 3)^2 row per window (row-major). The 3 x 3 dilation is two ORs of shifted
        # copies of the whole row (horizontal, then vertical by one box row); element j of the
        # result is the dilation at box position j + wb + 1, so the box's middle slice lines up
        # with it. Ring positions in that slice carry zero weights (wrap-around is harmless).
        box = flat.take(ci[:, None] + _box_offsets(r + 1, W))
        if int_thr is None:
            box = box.astype(np.float32)
            above = box > threshold_dn
        else:
            above = box > int_thr
        wb = 2 * r + 3
        h = above[:, :-2] | above[:, 1:-1] | above[:, 2:]
        dil = h[:, :-2 * wb] | h[:, wb:-wb] | h[:, 2 * wb:]
        mid = slice(wb + 1, wb * wb - wb - 1)
        weights, in_roi, on_border = _roi_weights(r)
        above_mid = above[:, mid]
        grow = (above_mid & on_border).any(axis=1)
        I = np.maximum(box[:, mid].astype(np.float32) - bg32, zero32) * dil     # float32, as detect_spots
        mom = (I * I).astype(np.float64) @ weights                               # (ni, 3): sum I^2 x, y, 1
        m0 = mom[:, 2]
        ok = (m0 > 0) & ~grow
        m0 = np.where(ok, m0, 1.0)
        out_xy[i, 0] = cxi + mom[:, 0] / m0
        out_xy[i, 1] = cyi + mom[:, 1] / m0
        flux[i] = I.astype(np.float64) @ weights[:, 2]
        peak[i] = flat.take(ci)
        npx[i] = (above_mid & in_roi).sum(axis=1)
        valid[i] = ok
        g = grow.nonzero()[0]
        pending, c0, edge, cx, cy = i.take(g), ci.take(g), edge.take(g), cxi.take(g), cyi.take(g)
        if r >= max_roi_half_px:
            break
        r = min(2 * r, int(max_roi_half_px))
    out_xy[~valid] = np.nan
    return WindowCentroids(xy_px=out_xy, flux_dn=flux, peak_dn=peak, n_pixels=npx, valid=valid)


def window_peaks(image, xy_px, *, threshold_dn: float, background_dn: float, search_half_px: int):
    """Coarse spot positions near predicted positions: ``(xy (N, 2), valid (N,))``.

    The brightest pixel within ``search_half_px`` of each rounded position (the box must lie in
    the image, as in :func:`window_centroids`), valid when above ``threshold_dn``, refined to the
    ``I^2``-weighted centre (``I`` above ``background_dn``) of the 3 x 3 pixels around it, read
    from the same search box (a peak on the box's edge: the 3 x 3 just inside). Good to ~0.1 px
    for a star: what windowed tracking's first pass needs to re-predict the stars within a
    pixel, at a fraction of :func:`window_centroids`' cost (no ROI, no growth).
    """
    s = int(search_half_px)
    m = 2 * s + 1
    flat, (_, W), n, idx, c = _search_windows(image, xy_px, s)
    out = np.full((n, 2), np.nan)
    valid = np.zeros(n, dtype=bool)
    if not len(idx) or m < 3:
        return out, valid
    box = flat.take((c[:, 1] * W + c[:, 0])[:, None] + _box_offsets(s, W))
    k = box.argmax(axis=1)
    rows = np.arange(len(idx))
    ok = (box[rows, k].astype(np.float64) > threshold_dn).nonzero()[0]
    if not len(ok):
        return out, valid
    box, k, c, idx = box.take(ok, axis=0), k.take(ok), c.take(ok, axis=0), idx.take(ok)
    ky, kx = np.divmod(k, m)
    cy3 = np.minimum(np.maximum(ky, 1), m - 2)
    cx3 = np.minimum(np.maximum(kx, 1), m - 2)
    nb = box[np.arange(len(ok))[:, None], (cy3 * m + cx3)[:, None] + _box_offsets(1, m)]   # (n, 9)
    w = np.maximum(nb.astype(np.float64) - background_dn, 0.0)
    w *= w
    w0 = w.sum(axis=1)
    d = np.arange(-1.0, 2.0)
    dx = (w.reshape(-1, 3, 3).sum(axis=1) @ d) / np.where(w0 > 0, w0, 1.0)
    dy = (w.reshape(-1, 3, 3).sum(axis=2) @ d) / np.where(w0 > 0, w0, 1.0)
    out[idx, 0] = c[:, 0] - s + cx3 + dx
    out[idx, 1] = c[:, 1] - s + cy3 + dy
    valid[idx] = True
    return out, valid


def _search_windows(image, xy_px, s: int):
    """``(flat image, (H, W), N, idx, c)``: of the N predicted positions (x = column), those whose
    rounded position's (2s + 1)^2 box lies in the image (NaN positions fail every comparison),
    as indices ``idx`` and integer centres ``c`` (len(idx), 2)."""
    img = np.asarray(image)
    H, W = img.shape
    xy = np.asarray(xy_px, float).reshape(-1, 2)
    c = np.rint(xy)
    idx = ((c[:, 0] >= s) & (c[:, 0] < W - s) & (c[:, 1] >= s) & (c[:, 1] < H - s)).nonzero()[0]
    return img.ravel(), (H, W), len(xy), idx, c.take(idx, axis=0).astype(np.intp)


@functools.lru_cache(maxsize=32)
def _box_offsets(h: int, W: int) -> np.ndarray:
    """Flat-index offsets (row-major) of the (2h + 1)^2 box around a pixel of a W-wide image."""
    d = np.arange(-h, h + 1)
    return (d[:, None] * W + d[None, :]).ravel()


@functools.lru_cache(maxsize=8)
def _roi_weights(r: int):
    """Tables of a ROI of half-size ``r`` inside its (2r + 3)^2 box (the ROI plus a one-pixel
    ring), over the box's middle slice ``[wb + 1, wb^2 - wb - 1)`` (``wb = 2r + 3``, row-major):
    weights (n, 3) with the pixel's x and y offsets from the centre and 1 on ROI pixels, 0 on
    the ring; the ROI mask; the mask of the ROI's border pixels."""
    wb = 2 * r + 3
    pos = np.arange(wb + 1, wb * wb - wb - 1)
    by, bx = np.divmod(pos, wb)
    in_roi = (by >= 1) & (by <= wb - 2) & (bx >= 1) & (bx <= wb - 2)
    border = in_roi & ((by == 1) | (by == wb - 2) | (bx == 1) | (bx == wb - 2))
    w = np.zeros((len(pos), 3))
    w[in_roi, 0] = bx[in_roi] - (r + 1)
    w[in_roi, 1] = by[in_roi] - (r + 1)
    w[in_roi, 2] = 1.0
    return w, in_roi, border


@functools.lru_cache(maxsize=16)
def _int_threshold_cached(dtype, t32: float):
    info = np.iinfo(dtype)
    if info.min <= np.floor(t32) < info.max:
        return dtype.type(np.floor(t32))
    return None


def _int_threshold(dtype, threshold_dn):
    """The test ``float32(I) > threshold`` (the threshold rounded to float32) on integer counts
    is ``I > floor(float32 threshold)``: the threshold in the image's own dtype (no float copy of
    the pixels), or None for float images and thresholds outside the dtype's range."""
    t32 = float(np.float32(threshold_dn))
    if dtype.kind not in "ui" or not np.isfinite(t32):
        return None
    return _int_threshold_cached(dtype, t32)


def spots_in_boxes(image, centres_xy, half_px, *, threshold_dn: float, background_dn: float,
                   max_dn: float | None = None) -> Spots:
    """Spots (Eq. 6-8 regions and centroids, as :func:`detect_spots` finds them) inside a few
    square boxes, each labelled on its own crop: the beacons' windows in tracking, where a
    full-frame pass costs ~10x more. A region touching its box's edge (not the image's) is
    dropped: it may continue outside the box, and a truncated region has a biased centroid.
    Spots found in two overlapping boxes are kept once."""
    img = np.asarray(image)
    H, W = img.shape
    xy = np.asarray(centres_xy, float).reshape(-1, 2)
    half = np.ceil(np.asarray(half_px, float))
    if half.ndim == 0:
        half = np.full(len(xy), float(half))
    parts = []
    thr = float(threshold_dn)
    bg = float(background_dn)
    for (x, y), h in zip(xy.tolist(), half.tolist()):
        if not (np.isfinite(x) and np.isfinite(y)):
            continue
        x0, x1 = max(int(round(x - h)), 0), min(int(round(x + h)) + 1, W)
        y0, y1 = max(int(round(y - h)), 0), min(int(round(y + h)) + 1, H)
        if x1 <= x0 or y1 <= y0:
            continue
        crop = img[y0:y1, x0:x1]
        above = crop > thr
        lab, n = ndimage.label(above, structure=_EIGHT)
        if n == 0:
            continue
        # the ROI: each region plus its 8-neighbours (a margin pixel shared by two regions goes
        # to the higher label; detect_spots gives it to the first, a sub-threshold pixel either
        # way): a 3x3 grey dilation of the labels, as two separable 1-D maxima (zero outside)
        h_, w_ = lab.shape
        pad = np.zeros((h_ + 2, w_ + 2), dtype=lab.dtype)
        pad[1:-1, 1:-1] = lab
        rowmax = np.maximum(np.maximum(pad[:, :-2], pad[:, 1:-1]), pad[:, 2:])
        roi = np.maximum(np.maximum(rowmax[:-2], rowmax[1:-1]), rowmax[2:])
        f = roi.ravel().nonzero()[0]
        l = roi.ravel().take(f)
        I1 = np.maximum(crop.ravel().take(f).astype(np.float64) - bg, 0.0)
        I2 = I1 * I1
        rr, cc = np.divmod(f, w_)
        m0 = np.bincount(l, I2, minlength=n + 1)[1:]
        # regions cut by a box edge that is not the image's edge
        edges = [e for e, inside in ((lab[0, :], y0 > 0), (lab[-1, :], y1 < H), (lab[:, 0], x0 > 0),
                                     (lab[:, -1], x1 < W)) if inside]
        cut = np.zeros(n + 1, dtype=bool)
        if edges:
            cut[np.concatenate(edges)] = True
        keep = (~cut[1:] & (m0 > 0)).nonzero()[0]
        if not len(keep):
            continue
        m0k = m0[keep]
        xc = x0 + np.bincount(l, I2 * cc, minlength=n + 1)[1:][keep] / m0k
        yc = y0 + np.bincount(l, I2 * rr, minlength=n + 1)[1:][keep] / m0k
        flux = np.bincount(l, I1, minlength=n + 1)[1:][keep]
        fa = above.ravel().nonzero()[0]
        la = lab.ravel().take(fa)
        npix = np.bincount(la, minlength=n + 1)[1:][keep]
        peak = np.zeros(n + 1)
        np.maximum.at(peak, la, crop.ravel().take(fa))
        objs = ndimage.find_objects(lab)
        size = np.array([max(objs[k][0].stop - objs[k][0].start, objs[k][1].stop - objs[k][1].start)
                         for k in keep.tolist()], dtype=float)
        part = np.empty((len(keep), 6))
        part[:, 0], part[:, 1], part[:, 2], part[:, 3], part[:, 4], part[:, 5] = xc, yc, flux, peak[1:][keep], npix, size
        parts.append(part)
    a = np.concatenate(parts) if len(parts) > 1 else (parts[0] if parts else np.zeros((0, 6)))
    if len(a) > 1:  # a spot found in two overlapping boxes is kept once (first occurrence, 1/16 px)
        k = np.rint(a[:, :2] * 16).astype(np.int64)
        _, first = np.unique((k[:, 0] << 32) + k[:, 1], return_index=True)
        if len(first) < len(a):
            a = a[np.sort(first)]
    if not len(a):
        return Spots.empty(float(threshold_dn))
    a = a.take(np.argsort(-a[:, 2], kind="stable"), axis=0)
    sat = a[:, 3] >= max_dn if max_dn is not None else np.zeros(len(a), bool)
    return Spots(xy_px=a[:, :2].copy(), flux_dn=a[:, 2].copy(), peak_dn=a[:, 3].copy(), n_pixels=a[:, 4].astype(int),
                 saturated=sat, elongation=np.ones(len(a)), size_px=a[:, 5].copy(), threshold_dn=float(threshold_dn))


_EIGHT = np.ones((3, 3), dtype=bool)
