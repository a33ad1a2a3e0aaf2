"""Tracking: the stars and beacons of a frame measured in windows around their predictions.

From the previous frame's attitude, the catalog stars (and the beacons) are predicted on the
sensor and measured only in small windows around them (Andreis et al. (2023b), Fig. 4: tracking, falling back
to lost in space), with residual clipping of the association (:func:`clip_residuals`).
"""

from __future__ import annotations

import math

import numpy as np

from .attitude import wahba_svd
from .beacons import CHI2_2DOF_3SIGMA, max_eig_2x2, predict_beacons
from .centroids import Spots
from .windows import spots_in_boxes, window_centroids, window_peaks
from .levels import robust_level
from .star_id import StarMatch

__all__ = ["track_windowed", "clip_residuals", "clip_outliers", "concat_spots"]


def track_windowed(img, observation, catalog, R_prev, star_dirs, predicted_state, opt, max_dn, body_states,
                   level=None):
    """Tracking without a full-frame pass (improved mode).

    Pass 1: the ``track_coarse_stars`` brightest ID-catalog stars (V < the catalog's limit)
    predicted from ``R_prev``, each located at the brightest pixel within ``track_window_px`` of
    its prediction, refined by its 3 x 3 neighbourhood (:func:`~skynav.pipeline.windows.window_peaks`:
    ~0.1 px, enough to re-predict every star within a pixel; the Eq. 7-8 centroids are pass 2's); Wahba with one residual clip; the
    attitude check (>= ``min_matches`` stars within ``inlier_px`` after the fit, and the solution
    within the windows' capture range of the prior). Pass 2: every catalog star to
    ``refine_v_mag`` predicted from the pass-1 attitude, measured within 1 px of its prediction,
    kept within ``refine_px``; Wahba, residual clip (:func:`clip_residuals`). Pass 3: the beacons'
    windows (``track_window_px`` + their 3-sigma reach; beyond ``track_window_max_px`` the full
    frame is needed) through :func:`~skynav.pipeline.windows.spots_in_boxes`, so a planet
    gets the same region and centroid as in a full-frame pass. Returns ``(spots, b, match, source, beacon predictions)``
    (``b``: the lines of sight of the star spots, the first rows of ``spots``) or None (the caller
    then runs the full frame: tracking, then lost in space).
    """
    cam = observation.camera
    half_fov = cam.half_diagonal_fov_rad
    hw = int(np.ceil(opt.track_window_px))
    source = catalog.deep_stars(opt.refine_v_mag) if opt.refine_v_mag > catalog.limiting_v_mag else catalog.stars
    idx, u = star_dirs(R_prev[2], half_fov, source)
    if len(idx) < opt.min_matches:
        return None
    vmag = np.asarray(source.v_mag).take(idx)
    med, thr = robust_level(img, opt.T) if level is None else level
    A = _coarse_attitude(img, cam, u, vmag, R_prev, catalog.limiting_v_mag, opt, hw, med, thr)
    if A is None:
        return None
    fine = _fine_stars(img, cam, u, A, opt, med, thr, max_dn)
    if fine is None:
        return None
    star_spots, star_rows, b, A, keep = fine
    beacons = _beacon_windows(img, observation, predicted_state, A, opt, hw, med, thr, max_dn, body_states)
    if beacons is None:
        return None
    beacon_spots, preds = beacons
    spots = concat_spots(star_spots, beacon_spots)
    sp = keep.nonzero()[0]
    rows = star_rows.take(sp)
    st = idx.take(rows)
    residual = np.arccos(np.minimum(np.maximum(np.einsum("ij,ij->i", u.take(rows, axis=0) @ A.T, b.take(sp, axis=0)),
                                               -1.0), 1.0))
    match = StarMatch(R_cam_icrs=A, spot_index=sp, star_index=st, residual_rad=residual)
    return spots, b, match, source, preds


def _coarse_attitude(img, cam, u, vmag, R_prev, id_limit_v_mag, opt, hw, med, thr):
    """Pass 1: the attitude from the brightest ID-catalog stars (``vmag`` <= ``id_limit_v_mag``)
    predicted from ``R_prev``, located by :func:`~skynav.pipeline.windows.window_peaks`, with one
    residual clip; None unless ``min_matches`` stars agree and the solution lies within the
    windows' capture range of the prior."""
    ifov = cam.ifov_rad
    sel = (vmag <= id_limit_v_mag).nonzero()[0]
    xy = cam.project(u.take(sel, axis=0) @ R_prev.T)
    inside = cam.in_image(xy, -float(hw))  # NaN (behind the camera) compares False: not inside
    sel, xy = sel.compress(inside), xy.compress(inside, axis=0)
    if len(sel) > opt.track_coarse_stars:  # the brightest suffice for the coarse attitude
        b_ord = np.argsort(vmag.take(sel), kind="stable")[:opt.track_coarse_stars]
        sel, xy = sel.take(b_ord), xy.take(b_ord, axis=0)
    xy1, ok1 = window_peaks(img, xy, threshold_dn=thr, background_dn=med, search_half_px=hw)
    sel = sel.compress(ok1)
    if len(sel) < opt.min_matches:
        return None
    b1 = cam.line_of_sight(xy1.compress(ok1, axis=0))
    u1 = u.take(sel, axis=0)
    A, keep = clip_residuals(b1, u1, wahba_svd(b1, u1), floor_rad=opt.inlier_px * ifov)
    if keep.sum() < opt.min_matches:
        return None
    dR = A @ R_prev.T
    if math.acos(min(max((dR[0, 0] + dR[1, 1] + dR[2, 2] - 1.0) / 2.0, -1.0), 1.0)) > max(hw - 4.0, 1.0) * ifov:
        return None
    return A


def _fine_stars(img, cam, u, A, opt, med, thr, max_dn):
    """Pass 2: every catalog star to ``refine_v_mag`` predicted from the pass-1 attitude ``A``,
    measured within 1 px (:func:`~skynav.pipeline.windows.window_centroids`), kept within
    ``refine_px``, one spot per star; Wahba with the residual clip. ``(star_spots, star_rows, b,
    A, keep)`` (``star_rows``: the stars' rows of ``u``; ``b``: their spots' lines of sight), or
    None with fewer than ``min_matches`` stars."""
    ua = u @ A.T
    xy = cam.project(ua)
    inside = cam.in_image(xy, -2.0).nonzero()[0]
    w2 = window_centroids(img, xy.take(inside, axis=0), threshold_dn=thr, background_dn=med, search_half_px=1)
    b2 = cam.line_of_sight(np.where(w2.valid[:, None], w2.xy_px, 0.0))
    res = np.arccos(np.minimum(np.maximum(np.einsum("ij,ij->i", ua.take(inside, axis=0), b2), -1.0), 1.0))
    got_i = _one_spot_per_star(w2.valid & (res <= opt.refine_px * cam.ifov_rad), w2.xy_px, cam.width)
    if len(got_i) < opt.min_matches:
        return None
    star_rows = inside.take(got_i)
    b = b2.take(got_i, axis=0)
    u2 = u.take(star_rows, axis=0)
    A, keep = clip_residuals(b, u2, wahba_svd(b, u2), floor_rad=0.0)
    if keep.sum() < opt.min_matches:
        return None
    n_st = len(got_i)
    npx = w2.n_pixels.take(got_i)
    peak = w2.peak_dn.take(got_i)
    star_spots = Spots(xy_px=w2.xy_px.take(got_i, axis=0), flux_dn=w2.flux_dn.take(got_i), peak_dn=peak,
                       n_pixels=npx, saturated=peak >= max_dn, elongation=np.ones(n_st),
                       size_px=np.sqrt(np.maximum(npx, 1.0)), threshold_dn=thr)
    return star_spots, star_rows, b, A, keep


def _one_spot_per_star(got, xy_px, width):
    """The indices where ``got`` holds, less the predictions landing on the same peak pixel as
    another (a close pair: both drop), so that each spot has one star and each star one spot."""
    got_i = got.nonzero()[0]
    if len(got_i) > 1:
        pk = np.rint(xy_px.take(got_i, axis=0)).astype(np.intp)
        key = pk[:, 1] * width + pk[:, 0]
        order = np.argsort(key, kind="stable")
        same = key[order[1:]] == key[order[:-1]]  # neighbours in sorted order sharing a pixel
        if same.any():
            dup = np.zeros(len(key), dtype=bool)
            dup[order[1:][same]] = True
            dup[order[:-1][same]] = True
            got = got.copy()
            got[got_i[dup]] = False
            got_i = got.nonzero()[0]
    return got_i


def _beacon_windows(img, observation, predicted_state, A, opt, hw, med, thr, max_dn, body_states):
    """Pass 3: ``(beacon_spots, predictions)``: the beacons predicted with ``A`` and their windows
    (``track_window_px`` + the 3-sigma reach) through
    :func:`~skynav.pipeline.windows.spots_in_boxes`; no predicted state: no beacons. None when a
    window would pass ``track_window_max_px`` or no ephemeris answers (the full frame decides)."""
    if predicted_state is None:
        return Spots.empty(thr), None
    cam = observation.camera
    try:
        preds = predict_beacons(observation.epoch_tdb_s, predicted_state, A, cam, mode="improved",
                                sigma_qv=opt.sigma_qv, body_states=body_states)
    except Exception:  # noqa: BLE001 - no ephemeris: the full-frame path decides
        return None
    win, half = [], []
    for p in preds:
        reach = math.sqrt(CHI2_2DOF_3SIGMA * max(max_eig_2x2(p.cov_px2), 0.0))
        if reach + hw > opt.track_window_max_px:
            return None
        win.append(p.xy_px)
        half.append(reach + hw)
    if not win:
        return Spots.empty(thr), preds
    return spots_in_boxes(img, np.asarray(win), np.asarray(half), threshold_dn=thr, background_dn=med,
                          max_dn=max_dn), preds


def clip_residuals(b, u, A, *, floor_rad):
    """``(A, keep)``: one pass of the residual clip of :func:`clip_outliers` (residuals above
    3.5 x their median, and above ``floor_rad``, are blends or wrong neighbours), re-solved."""
    res = np.arccos(np.minimum(np.maximum(np.einsum("ij,ij->i", u @ A.T, b), -1.0), 1.0))
    keep = res <= max(3.5 * float(np.median(res)), floor_rad)
    n_keep = int(np.count_nonzero(keep))
    if n_keep == len(keep) or n_keep < 3:
        return A, keep if n_keep >= 3 else np.ones(len(b), bool)
    return wahba_svd(b.compress(keep, axis=0), u.compress(keep, axis=0)), keep


def clip_outliers(match, b, source, star_dirs, half_fov):
    """One pass of residual clipping on the final association: a 2-D Gaussian residual has its
    median at 1.18 sigma and its 99.9 % point at 3.7 sigma, so residuals above 3.5 x the median
    are blends or wrong neighbours; the attitude is re-solved without them."""
    r = match.residual_rad
    if len(r) < 10:
        return match
    keep = r <= 3.5 * float(np.median(r))
    if keep.all() or keep.sum() < 5:
        return match
    sp, st = match.spot_index[keep], match.star_index[keep]
    idx, u_all = star_dirs(match.R_cam_icrs[2], half_fov, source)
    pos = {s: k for k, s in enumerate(idx)}
    u = u_all[[pos[s] for s in st]]
    A = wahba_svd(b[sp], u)
    res = np.arccos(np.clip(np.einsum("ij,ij->i", u @ A.T, b[sp]), -1.0, 1.0))
    return StarMatch(R_cam_icrs=A, spot_index=sp, star_index=st, residual_rad=res)


def concat_spots(a, b):
    """The spots of ``a`` followed by those of ``b`` (``a``'s threshold)."""
    if len(b) == 0:
        return a
    cat = lambda f: np.concatenate([getattr(a, f), getattr(b, f)])  # noqa: E731
    return Spots(xy_px=cat("xy_px"), flux_dn=cat("flux_dn"), peak_dn=cat("peak_dn"), n_pixels=cat("n_pixels"),
                 saturated=cat("saturated"), elongation=cat("elongation"), size_px=cat("size_px"),
                 threshold_dn=a.threshold_dn)
