"""One frame in, one :class:`~skynav.pipeline.results.FrameResult` out (the pipeline's driver).

``process_frame`` never raises for a bad image: every failure is an outcome class. Two modes:

- ``"paper"`` (paper 000 as published): Eq. 6 threshold with the image mean and standard
  deviation, the iterative increase of T when the ID fails, reference-star votes, RANSAC over
  random 3-star Wahba solutions, the attitude from the RANSAC inliers, no aberration correction,
  beacons by the closest spike in the Eq. 23 ellipse with ``S`` of Eq. 22.
- ``"improved"``: a robust threshold (median + T x 1.4826 MAD, so a resolved planet or a bright
  frame does not lift it above the stars), star-like spots first (no single hot pixels, no huge
  regions), deterministic vote-ordered triples, every catalog star predicted in the field
  re-associated and the attitude re-solved from all of them with stellar aberration removed
  (paper 002 section 3.2: catalog directions aberrated with the predicted velocity), an
  acceptance test (>= ``min_matches`` stars), a covariance from the residuals, beacons by
  Mahalanobis distance plus predicted brightness among spots not matched to catalog stars.
- Tracking (``previous_attitude`` given): association from the previous attitude, falling back to
  lost in space (paper 001 Fig. 4).
"""

from __future__ import annotations

import functools
import math
import time
from dataclasses import dataclass, replace

import numpy as np

try:  # the gufunc behind numpy.linalg.inv (numpy's private module: _inv_2x2_stack falls back without it)
    from numpy.linalg import _umath_linalg
except ImportError:  # pragma: no cover
    _umath_linalg = None

from .attitude import attitude_covariance
from .beacons import CHI2_2DOF_3SIGMA, _max_eig_2x2, predict_beacons, select_spot
from .centroids import Spots, detect_spots
from .results import AttitudeResult, BeaconResult, FrameResult
from .star_id import C_KM_S, lost_in_space, refine

__all__ = ["ProcessOptions", "process_frame"]

ARCSEC = np.pi / 180.0 / 3600.0


@dataclass(frozen=True, kw_only=True)
class ProcessOptions:
    """Speed/accuracy trade-offs of :func:`process_frame` (one object; vary with ``replace``)."""

    T: float = 5.0                      # Eq. 6 tuning parameter (improved: on the robust sigma)
    T_step: float = 2.0                 # paper: T increase after a failed ID
    T_max_iterations: int = 5
    eps_px: float = 0.6                 # k-vector range error, in pixels of the field
    inlier_px: float = 2.0              # RANSAC / association tolerance, px
    n_max: int = 12                     # spots used for the votes
    n_ransac: int = 100                 # paper mode: random triples
    min_matches: int = 5                # improved: stars needed to accept an attitude
    max_spots: int = 3000               # more regions than this: "too_many_spots"
    saturated_fraction: float = 0.5     # more saturated pixels than this: "saturated"
    sigma_qv: float = 1e-4              # paper Eq. 22
    mag_sigma: float = 1.0              # improved beacon brightness prior, mag
    deep_star_radius_px: float = 1.5    # improved: spots this close to a deep-catalog star are stars
    refine_v_mag: float = 7.5           # improved: catalog depth of the final attitude (5.5: off)
    refine_px: float = 1.5              # improved: association radius of the final attitude, px
    refine_max_spots: int = 400         # improved: brightest spots offered to the final association
    blend_px: float = 8.0               # improved: beacons predicted closer than this may share a spot
    # tracking, improved mode: spots only in windows around the stars (to refine_v_mag) and beacons
    # predicted from previous_attitude; window half-size = track_window_px (covers a prior
    # attitude error plus the rotation since the previous frame of up to ~(track_window_px - 4) px,
    # i.e. (track_window_px - 4) x IFOV: 8 px x 70"/px ~ 9' for the paper camera), beacons' plus
    # their 3-sigma reach (capped at track_window_max_px, beyond which the full frame is used).
    # 0 turns windows off (full-frame tracking).
    track_window_px: float = 12.0
    track_window_max_px: float = 96.0
    track_coarse_stars: int = 24        # windowed tracking, pass 1: the brightest predicted stars measured
    seed: int = 0                       # paper RANSAC draws


_DEFAULT_OPTIONS = ProcessOptions()


def _fail(status, spots_xy, t0, timings, mode, beacons=()):
    timings["total"] = (time.perf_counter() - t0) * 1e3
    return FrameResult(status=status, attitude=AttitudeResult(), centroids_xy_px=np.asarray(spots_xy, float).reshape(-1, 2),
                       beacons=tuple(beacons), timings_ms=timings, mode=mode)


def _star_order(spots: Spots, mode: str) -> np.ndarray:
    """Spots in the order star ID should try them (brightest first; improved: star-like first)."""
    n = len(spots)
    if mode == "paper":
        return np.arange(n)
    starlike = (spots.n_pixels >= 2) & (spots.size_px <= 12) & (spots.elongation < 4.0)
    return np.concatenate([np.flatnonzero(starlike), np.flatnonzero(~starlike)])


def process_frame(observation, *, catalog, predicted_state=None, previous_attitude=None, mode="improved",
                  options: ProcessOptions | None = None, ephemeris=None) -> FrameResult:
    """Centroids, star ID, attitude and beacons of one frame.

    Parameters
    ----------
    observation : skynav.datasets.observation.Observation
        ``dn`` (H, W), ``epoch_tdb_s``, ``exposure_s``, ``camera`` (as calibrated).
    catalog : skynav.pipeline.OnboardCatalog
    predicted_state : skynav.pipeline.PredictedState, optional
        Needed for beacons (and for aberration and parallax in the improved mode).
    previous_attitude : ndarray, shape (3, 3), optional
        ``R_cam_icrs`` of the previous frame: tracking mode first.
    mode : {"paper", "improved"}

    Returns
    -------
    FrameResult
        Never raises for a bad image; ``status`` says what happened.
    """
    if mode not in ("paper", "improved"):
        raise ValueError(f"mode must be 'paper' or 'improved', got {mode!r}")
    opt = options or _DEFAULT_OPTIONS
    t0 = time.perf_counter()
    timings = {}
    cam = observation.camera
    try:
        img = np.asarray(observation.dn)
        if img.ndim != 2 or img.shape != (cam.height, cam.width) or not (np.issubdtype(img.dtype, np.integer) or np.all(np.isfinite(np.asarray(img[::64, ::64], dtype=float)))):
            return _fail("bad_image", np.zeros((0, 2)), t0, timings, mode)
    except Exception:  # noqa: BLE001 - anything unreadable is a bad image
        return _fail("bad_image", np.zeros((0, 2)), t0, timings, mode)
    max_dn = float(2 ** cam.sensor.bit_depth - 1)
    # the saturated fraction from 1 pixel in 64, the rows and columns the robust level reads next
    # (a 1024^2 frame: 16384 pixels, +-0.4 % at 1 sigma near the 50 % limit; the frame is cold
    # in memory here, so every pixel read costs)
    levels = _Levels(img, histogram=(mode == "improved"))
    if levels.count_at_least(max_dn) > opt.saturated_fraction * levels.sub.size:
        return _fail("saturated", np.zeros((0, 2)), t0, timings, mode)

    v_km_s = None if predicted_state is None else np.asarray(predicted_state.velocity_km_s, float)
    r_km = np.zeros(3) if predicted_state is None else np.asarray(predicted_state.position_km, float)
    aberr = mode == "improved" and v_km_s is not None
    ifov = cam.ifov_rad
    half_fov = cam.half_diagonal_fov_rad
    stars = catalog.stars
    t_epoch = observation.epoch_tdb_s

    dirs_cache = {}
    REUSE_RAD = 5e-3  # a cone computed 5 mrad wider serves every boresight within 5 mrad of its axis

    def star_dirs(boresight, radius, source=None):
        # the stars of a cone with a 2 mrad margin; within one frame the boresight moves by a
        # few pixels between calls, so one wider cone per catalog serves them all (the extra
        # stars lie outside the image by >= 2 mrad, beyond every association tolerance)
        src = stars if source is None else source
        key = (id(src), float(radius))
        hit = dirs_cache.get(key)
        if hit is not None and float(np.dot(hit[0], boresight)) >= np.cos(REUSE_RAD) * _norm(boresight):
            return hit[1], hit[2]
        idx = src.cone(boresight, radius, margin_rad=2e-3 + REUSE_RAD)
        if mode == "paper":
            u = catalog.u_icrs[idx]
        else:
            u = src.directions(idx, t_epoch, r_km)
            if aberr:
                beta = v_km_s / C_KM_S
                u = u + beta - (u @ beta)[:, None] * u
                u /= np.sqrt(np.add.reduce(u * u, axis=1))[:, None]  # numpy.linalg.norm's operations
        dirs_cache[key] = (np.asarray(boresight, float) / _norm(boresight), idx, u)
        return idx, u

    # ------------------------------------------------------------------ centroids + star ID loop
    T = opt.T
    match = None
    method = ""
    rel_eps = (_norm(v_km_s) / C_KM_S if v_km_s is not None else 2e-4) + 2e-5
    spots = Spots.empty()
    status = "id_failed"
    t_c = t_id = 0.0
    windowed_source = windowed_preds = None
    if previous_attitude is not None and mode == "improved" and opt.track_window_px > 0:
        tc0 = time.perf_counter()
        got = _track_windowed(img, observation, catalog, np.asarray(previous_attitude, float), star_dirs,
                              predicted_state, opt, max_dn, ephemeris, level=levels.level(opt.T))
        if got is not None:
            spots, b, match, windowed_source, windowed_preds = got
            method = "tracking"
            status = "ok"
        t_c += time.perf_counter() - tc0
    for it in range(0 if match is not None else (opt.T_max_iterations if mode == "paper" else 1)):
        tc0 = time.perf_counter()
        if mode == "paper":
            spots = detect_spots(img, T=T, max_dn=max_dn, max_regions=opt.max_spots + 1, stats_stride=2)
        else:
            spots = _detect_robust(img, T=T, max_dn=max_dn, max_regions=opt.max_spots + 1, level=levels.level(T))
        t_c += time.perf_counter() - tc0
        if len(spots) > opt.max_spots:
            status = "too_many_spots"
            if mode == "paper":
                T += opt.T_step
                continue
            break
        if len(spots) < 3:
            status = "no_stars"
            break
        ti0 = time.perf_counter()
        order = _star_order(spots, mode)
        b = cam.line_of_sight(spots.xy_px)
        if previous_attitude is not None:
            m = refine(np.asarray(previous_attitude, float), b, star_dirs, half_fov_rad=half_fov,
                       tol_rad=10 * opt.inlier_px * ifov, iterations=1)
            if m is not None:
                m = refine(m.R_cam_icrs, b, star_dirs, half_fov_rad=half_fov, tol_rad=opt.inlier_px * ifov)
            if m is not None and len(m.spot_index) >= opt.min_matches:
                match, method = m, "tracking"
        if match is None:
            for n_max in ((opt.n_max,) if mode == "paper" else (opt.n_max, 2 * opt.n_max)):
                sol = lost_in_space(b[order], catalog, eps_rad=opt.eps_px * ifov, rel_eps=rel_eps, n_max=n_max,
                                    inlier_rad=opt.inlier_px * ifov, rng=np.random.default_rng(opt.seed),
                                    random_triples=(mode == "paper"), max_triples=opt.n_ransac if mode == "paper" else 200)
                if sol is None:
                    continue
                A, sp, st = sol
                sp = order[sp]
                if mode == "paper":
                    if len(sp) >= 3:
                        from .star_id import StarMatch
                        res = np.arccos(np.clip(np.einsum("ij,ij->i", catalog.u_icrs[st] @ A.T, b[sp]), -1, 1))
                        match = StarMatch(R_cam_icrs=A, spot_index=sp, star_index=st, residual_rad=res)
                else:
                    m = refine(A, b, star_dirs, half_fov_rad=half_fov, tol_rad=opt.inlier_px * ifov)
                    if m is not None and len(m.spot_index) >= opt.min_matches:
                        match = m
                if match is not None:
                    method = "lost_in_space"
                    break
        t_id += time.perf_counter() - ti0
        if match is not None:
            status = "ok"
            break
        status = "id_failed"
        T += opt.T_step
    timings["centroids"] = t_c * 1e3
    timings["star_id"] = t_id * 1e3
    if match is None:
        res = _fail(status, spots.xy_px, t0, timings, mode)
        return replace(res, beacons=_beacons_without_attitude(observation, predicted_state))

    # ------------------------------------------------------------------ attitude + covariance
    ta0 = time.perf_counter()
    ref_hip, ref_vmag = np.asarray(catalog.hip), catalog.v_mag
    if windowed_source is not None:
        # windowed tracking already associated every catalog star to refine_v_mag
        ref_hip, ref_vmag = np.asarray(windowed_source.hip), np.asarray(windowed_source.v_mag)
    elif mode == "improved" and opt.refine_v_mag > catalog.limiting_v_mag:
        # the final attitude from every catalog star to refine_v_mag that the identified attitude
        # predicts next to a spot (mutual nearest within 1.5 px): ~5x the stars of the ID catalog
        deep = catalog.deep_stars(opt.refine_v_mag)
        bright = np.argsort(-spots.flux_dn, kind="stable")[:opt.refine_max_spots]
        m2 = refine(match.R_cam_icrs, b[bright], lambda c, r: star_dirs(c, r, deep), half_fov_rad=half_fov,
                    tol_rad=opt.refine_px * ifov, iterations=1)
        if m2 is not None and len(m2.spot_index) >= len(match.spot_index):
            from .star_id import StarMatch

            match = StarMatch(R_cam_icrs=m2.R_cam_icrs, spot_index=bright[m2.spot_index], star_index=m2.star_index,
                              residual_rad=m2.residual_rad)
            match = _clip_outliers(match, b, deep, star_dirs, half_fov)
            ref_hip, ref_vmag = np.asarray(deep.hip), np.asarray(deep.v_mag)
    A = match.R_cam_icrs
    # windowed tracking: b holds the star spots' lines of sight already (row by row the same)
    bm = b[match.spot_index] if windowed_source is not None else cam.line_of_sight(spots.xy_px[match.spot_index])
    n_st = len(match.spot_index)
    rms = math.sqrt(float(np.add.reduce(match.residual_rad * match.residual_rad)) / n_st) if n_st > 3 else opt.inlier_px * ifov / 2
    sigma = max(rms * np.sqrt(n_st / max(n_st - 3, 1)) / np.sqrt(2.0), 0.05 * ifov)
    P = attitude_covariance(bm, sigma)
    att = AttitudeResult(R_cam_icrs=A, covariance_rad2=P, n_stars=n_st,
                         error_estimate_arcsec=float(np.sqrt(np.trace(P)) / ARCSEC))
    timings["attitude"] = (time.perf_counter() - ta0) * 1e3

    # ------------------------------------------------------------------ beacons
    tb0 = time.perf_counter()
    beacons = ()
    if predicted_state is not None:
        beacons = _identify_beacons(observation, predicted_state, A, P, spots, match, catalog, mode, opt, ephemeris,
                                    ref_vmag, preds=windowed_preds)
    timings["beacons"] = (time.perf_counter() - tb0) * 1e3
    timings["total"] = (time.perf_counter() - t0) * 1e3
    star_ids = ref_hip[match.star_index]
    return FrameResult(status="ok", attitude=att, centroids_xy_px=spots.xy_px, beacons=beacons, timings_ms=timings,
                       mode=mode, star_id_method=method, matched_star_ids=star_ids,
                       matched_spot_index=np.asarray(match.spot_index))


def _clip_outliers(match, b, source, star_dirs, half_fov):
    """One pass of residual clipping on the final association: a 2-D Gaussian residual has its
    median at 1.18 sigma and its 99.9 % point at 3.7 sigma, so residuals above 3.5 x the median
    are blends or wrong neighbours; the attitude is re-solved without them."""
    from .attitude import wahba_svd
    from .star_id import StarMatch

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


class _Levels:
    """The frame's sample of every 8th row and column, read once: the saturated fraction and the
    robust level (:func:`_robust_level`) of one frame from the same histogram of its counts
    (integer frames; ``histogram=False`` or other frames: counted directly)."""

    def __init__(self, img, *, histogram: bool):
        self.img = img
        self.sub = img[::8, ::8]
        self.counts = _sample_histogram(self.sub) if histogram else None
        self._levels = {}

    def count_at_least(self, value: float) -> int:
        """Number of sample pixels >= ``value`` (``np.count_nonzero(sub >= value)``)."""
        if self.counts is None:
            return int(np.count_nonzero(self.sub >= value))
        return int(self.counts[max(int(np.ceil(value)), 0):].sum())

    def level(self, T: float):
        if T not in self._levels:
            self._levels[T] = _robust_level(self.img, T, counts=self.counts)
        return self._levels[T]


def _sample_histogram(sub):
    """``np.bincount`` of an integer sample with counts in [0, 2^17), else None."""
    counts_ok = np.issubdtype(sub.dtype, np.integer) and sub.size > 0
    if counts_ok and not (sub.dtype.kind == "u" and sub.dtype.itemsize <= 2):  # 8/16-bit: 0 <= counts < 2^16
        counts_ok = int(sub.min()) >= 0 and int(sub.max()) < 1 << 17
    return np.bincount(sub.ravel()) if counts_ok else None


def _robust_level(img, T, *, counts=None):
    """(background, threshold) of the improved mode: median + T x robust sigma (1.4826 MAD,
    floored at 0.5 DN for 8-bit frames whose dark background is one or two DN), from every 8th
    row and column. Integer frames (every camera's) take the same statistics from a histogram
    of the counts (``counts``, :func:`_sample_histogram` of that sample, when already made): the
    same median and MAD as :func:`numpy.median`, ~5x faster."""
    sub = img[::8, ::8]
    if counts is None:
        counts = _sample_histogram(sub)
    if counts is not None:
        values = counts.nonzero()[0]
        counts = counts[values]
        values = values.astype(np.float64)
        med = _weighted_median(values, counts, ascending=True)
        dev = np.abs(values - med)
        mad = _weighted_median(dev, counts) * 1.4826
        inl = counts * (values <= med + 5 * max(mad, 0.5))
        n = inl.sum()
        mean = float((inl * values).sum() / n)
        sd = max(mad, float(np.sqrt((inl * (values - mean) ** 2).sum() / n)), 0.5)
        return med, med + T * sd
    sub = np.asarray(sub, dtype=np.float32)
    med = float(np.median(sub))
    mad = float(np.median(np.abs(sub - med))) * 1.4826
    sd = max(mad, float(np.std(sub[sub <= med + 5 * max(mad, 0.5)])), 0.5)
    return med, med + T * sd


def _weighted_median(values, counts, *, ascending=False) -> float:
    """:func:`numpy.median` of the sample holding ``counts[i]`` copies of ``values[i]`` (the mean
    of the two middle order statistics when the sample size is even); ``ascending``: the values
    are sorted already."""
    if not ascending:
        order = np.argsort(values, kind="stable")
        values, counts = values.take(order), counts.take(order)
    cum = np.cumsum(counts)
    n = int(cum[-1])
    lo = values[np.searchsorted(cum, (n - 1) // 2, side="right")]
    hi = values[np.searchsorted(cum, n // 2, side="right")]
    return float(0.5 * (lo + hi))


def _detect_robust(img, *, T, max_dn, max_regions, windows_xy=None, window_half_px=0, level=None):
    """Improved threshold (:func:`_robust_level`, or ``level`` = its result), so a resolved body
    does not lift it."""
    med, thr = _robust_level(img, T) if level is None else level
    return detect_spots(img, T=T, max_dn=max_dn, max_regions=max_regions, background="median",
                        threshold_dn=thr, background_dn=med, stats_stride=8, windows_xy=windows_xy,
                        window_half_px=window_half_px)


def _track_windowed(img, observation, catalog, R_prev, star_dirs, predicted_state, opt, max_dn, ephemeris, level=None):
    """Tracking without a full-frame pass (improved mode).

    Pass 1: the ``track_coarse_stars`` brightest ID-catalog stars (V < the catalog's limit)
    predicted from ``R_prev``, each located at the brightest pixel within ``track_window_px`` of
    its prediction, refined by its 3 x 3 neighbourhood (:func:`~skynav.pipeline.centroids.window_peaks`:
    ~0.1 px, enough to re-predict every star within a pixel; the Eq. 7-8 centroids are pass 2's); Wahba with one residual clip; the
    attitude check (>= ``min_matches`` stars within ``inlier_px`` after the fit, and the solution
    within the windows' capture range of the prior). Pass 2: every catalog star to
    ``refine_v_mag`` predicted from the pass-1 attitude, measured within 1 px of its prediction,
    kept within ``refine_px``; Wahba, residual clip (:func:`_clip_residuals`). Pass 3: the beacons'
    windows (``track_window_px`` + their 3-sigma reach; beyond ``track_window_max_px`` the full
    frame is needed) through :func:`~skynav.pipeline.centroids.spots_in_boxes`, so a planet
    gets the same region and centroid as in a full-frame pass. Returns ``(spots, b, match, source, beacon predictions)``
    (``b``: the lines of sight of the star spots, the first rows of ``spots``) or None (the caller
    then runs the full frame: tracking, then lost in space).
    """
    from .attitude import wahba_svd
    from .centroids import spots_in_boxes, window_centroids, window_peaks
    from .star_id import StarMatch

    cam = observation.camera
    half_fov = cam.half_diagonal_fov_rad
    ifov = cam.ifov_rad
    hw = int(np.ceil(opt.track_window_px))
    source = catalog.deep_stars(opt.refine_v_mag) if opt.refine_v_mag > catalog.limiting_v_mag else catalog.stars
    idx, u = star_dirs(R_prev[2], half_fov, source)
    if len(idx) < opt.min_matches:
        return None
    vmag = np.asarray(source.v_mag).take(idx)
    med, thr = _robust_level(img, opt.T) if level is None else level
    # (rows of small 2-D arrays are selected with take / compress throughout: the same rows,
    # several times faster than fancy or boolean indexing on (N, 3) arrays)

    # pass 1: bright stars, wide search
    sel = (vmag <= catalog.limiting_v_mag).nonzero()[0]
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
    A, keep = _clip_residuals(b1, u1, wahba_svd(b1, u1), floor_rad=opt.inlier_px * ifov)
    if keep.sum() < opt.min_matches:
        return None
    dR = A @ R_prev.T
    if math.acos(min(max((dR[0, 0] + dR[1, 1] + dR[2, 2] - 1.0) / 2.0, -1.0), 1.0)) > max(hw - 4.0, 1.0) * ifov:
        return None

    # pass 2: every catalog star to refine_v_mag, from the pass-1 attitude
    ua = u @ A.T
    xy = cam.project(ua)
    inside = cam.in_image(xy, -2.0).nonzero()[0]
    w2 = window_centroids(img, xy.take(inside, axis=0), threshold_dn=thr, background_dn=med, search_half_px=1)
    b2 = cam.line_of_sight(np.where(w2.valid[:, None], w2.xy_px, 0.0))
    res = np.arccos(np.minimum(np.maximum(np.einsum("ij,ij->i", ua.take(inside, axis=0), b2), -1.0), 1.0))
    got = w2.valid & (res <= opt.refine_px * ifov)
    # one spot per star and one star per spot: two predictions landing on the same peak
    # (a close pair) both drop
    got_i = got.nonzero()[0]
    if len(got_i) > 1:
        pk = np.rint(w2.xy_px.take(got_i, axis=0)).astype(np.intp)
        key = pk[:, 1] * cam.width + pk[:, 0]
        order = np.argsort(key, kind="stable")
        same = key[order[1:]] == key[order[:-1]]  # neighbours in sorted order sharing a pixel
        if same.any():
            dup = np.zeros(len(key), dtype=bool)
            dup[order[1:][same]] = True
            dup[order[:-1][same]] = True
            got[got_i[dup]] = False
            got_i = got.nonzero()[0]
    if len(got_i) < opt.min_matches:
        return None
    star_rows = inside.take(got_i)
    b = b2.take(got_i, axis=0)
    u2 = u.take(star_rows, axis=0)
    A, keep = _clip_residuals(b, u2, wahba_svd(b, u2), floor_rad=0.0)
    if keep.sum() < opt.min_matches:
        return None
    n_st = len(got_i)
    npx = w2.n_pixels.take(got_i)
    peak = w2.peak_dn.take(got_i)
    star_spots = Spots(xy_px=w2.xy_px.take(got_i, axis=0), flux_dn=w2.flux_dn.take(got_i), peak_dn=peak,
                       n_pixels=npx, saturated=peak >= max_dn, elongation=np.ones(n_st),
                       size_px=np.sqrt(np.maximum(npx, 1.0)), threshold_dn=thr)

    # pass 3: the beacons' windows
    beacon_spots = Spots.empty(thr)
    preds = None
    if predicted_state is not None:
        try:
            preds = predict_beacons(observation.epoch_tdb_s, predicted_state, A, cam, mode="improved",
                                    sigma_qv=opt.sigma_qv, ephemeris=ephemeris)
        except Exception:  # noqa: BLE001 - no ephemeris: the full-frame path decides
            return None
        win, half = [], []
        for p in preds:
            reach = math.sqrt(CHI2_2DOF_3SIGMA * max(_max_eig_2x2(p["cov_px2"]), 0.0))
            if reach + hw > opt.track_window_max_px:
                return None
            win.append(p["xy_px"])
            half.append(reach + hw)
        if win:
            beacon_spots = spots_in_boxes(img, np.asarray(win), np.asarray(half), threshold_dn=thr, background_dn=med,
                                          max_dn=max_dn)
    spots = _concat_spots(star_spots, beacon_spots)
    sp = keep.nonzero()[0]
    rows = star_rows.take(sp)
    st = idx.take(rows)
    residual = np.arccos(np.minimum(np.maximum(np.einsum("ij,ij->i", u.take(rows, axis=0) @ A.T, b.take(sp, axis=0)),
                                               -1.0), 1.0))
    match = StarMatch(R_cam_icrs=A, spot_index=sp, star_index=st, residual_rad=residual)
    return spots, b, match, source, preds


def _clip_residuals(b, u, A, *, floor_rad):
    """``(A, keep)``: one pass of the residual clip of :func:`_clip_outliers` (residuals above
    3.5 x their median, and above ``floor_rad``, are blends or wrong neighbours), re-solved."""
    from .attitude import wahba_svd

    res = np.arccos(np.minimum(np.maximum(np.einsum("ij,ij->i", u @ A.T, b), -1.0), 1.0))
    keep = res <= max(3.5 * _median(res), floor_rad)
    n_keep = int(np.count_nonzero(keep))
    if n_keep == len(keep) or n_keep < 3:
        return A, keep if n_keep >= 3 else np.ones(len(b), bool)
    return wahba_svd(b.compress(keep, axis=0), u.compress(keep, axis=0)), keep


def _norm(v) -> float:
    """``numpy.linalg.norm`` of a vector, as it computes it (``sqrt(v . v)``), without its wrapper."""
    v = np.asarray(v, dtype=float)
    return math.sqrt(float(v.dot(v)))


def _median(a) -> float:
    """:func:`numpy.median` of a 1-D float array (the same partition; the mean of the two middle
    values written out: numpy's ``mean`` of two floats is their sum divided by 2.0), without its
    wrapper's overhead. Tested within 1 ulp of the middle values, not for identical bits."""
    n = len(a)
    h = n // 2
    if n % 2:
        return float(np.partition(a, h)[h])
    lo, hi = np.partition(a, (h - 1, h))[h - 1:h + 1].tolist()
    return (lo + hi) / 2.0


def _concat_spots(a, b):
    if len(b) == 0:
        return a
    cat = lambda f: np.concatenate([getattr(a, f), getattr(b, f)])  # noqa: E731
    return Spots(xy_px=cat("xy_px"), flux_dn=cat("flux_dn"), peak_dn=cat("peak_dn"), n_pixels=cat("n_pixels"),
                 saturated=cat("saturated"), elongation=cat("elongation"), size_px=cat("size_px"),
                 threshold_dn=a.threshold_dn)


def _beacons_without_attitude(observation, predicted_state):
    return ()


def _identify_beacons(observation, predicted_state, A, P_att, spots, match, catalog, mode, opt, ephemeris, ref_vmag,
                      preds=None):
    """``preds``: the beacons already predicted with the attitude ``A`` but without its covariance
    (windowed tracking), which is added here."""
    cam = observation.camera
    if preds is None:
        preds = predict_beacons(observation.epoch_tdb_s, predicted_state, A, cam, attitude_cov_rad2=P_att, mode=mode,
                                sigma_qv=opt.sigma_qv, ephemeris=ephemeris)
    else:
        preds = [dict(p, cov_px2=p["cov_px2"] + p["attitude_jacobian_px_rad"] @ P_att @ p["attitude_jacobian_px_rad"].T)
                 for p in preds]
    n = len(spots)
    candidate = np.ones(n, dtype=bool)
    candidate[match.spot_index] = False  # spots matched to catalog stars are not beacons
    if mode != "improved":
        out = []
        for p in preds:
            k = select_spot(p, spots.xy_px, candidate, mode=mode, spot_mag=None, mag_sigma=opt.mag_sigma)
            if k is not None:
                candidate[k] = False
            out.append(_beacon_result(p, spots, k))
        return tuple(out)
    if not preds:
        return ()
    # the deep stars that may lie on a spot a beacon can take: those within each beacon's
    # 3-sigma reach plus the exclusion radius (from its covariance before the blend widening)
    deep_cones = []
    if n:
        los = _lines_of_sight(cam, [p["xy_px"] for p in preds]) @ A  # rows: A^T b
        ifov = cam.ifov_rad
        deep_cones = [(los[k], (math.sqrt(CHI2_2DOF_3SIGMA * max(_max_eig_2x2(p["cov_px2"]), 0.0)) + opt.deep_star_radius_px + 2.0)
                       * ifov * 1.5) for k, p in enumerate(preds)]
    # blends: two beacons predicted within a few pixels (the Earth and the Moon) make one spot
    # whose centroid lies between them; widen both gates by half the separation, and predict
    # the blend's total brightness
    for i in range(len(preds)):
        for j in range(i + 1, len(preds)):
            sep = float(np.hypot(*(preds[i]["xy_px"] - preds[j]["xy_px"])))
            if sep < opt.blend_px:
                for a in (i, j):
                    preds[a] = dict(preds[a], cov_px2=preds[a]["cov_px2"] + np.eye(2) * (0.5 * sep) ** 2)
                mi, mj = preds[i]["v_mag"], preds[j]["v_mag"]
                if np.isfinite(mi) and np.isfinite(mj):
                    m = -2.5 * np.log10(10 ** (-0.4 * mi) + 10 ** (-0.4 * mj))
                    preds[i] = dict(preds[i], v_mag=m)
                    preds[j] = dict(preds[j], v_mag=m)
    # only the candidates inside some beacon's 3-sigma ellipse can be chosen: the deep-star test
    # and the brightness model are evaluated for those alone
    cand = np.flatnonzero(candidate)
    m2 = _mahalanobis2(preds, spots.xy_px.take(cand, axis=0))
    cand_in = m2[0] <= CHI2_2DOF_3SIGMA if len(m2) == 1 else np.logical_or.reduce(m2 <= CHI2_2DOF_3SIGMA, axis=0)
    cand, m2 = cand.compress(cand_in), m2.compress(cand_in, axis=1)
    if len(cand):
        # ... nor spots on fainter catalog stars (the deep catalog, V < deep_v_mag), predicted
        # with the solved attitude: the field's faint stars are the usual wrong beacons
        deep = catalog.deep_stars()
        cones = [deep.cone(c, r, margin_rad=2e-3) for c, r in deep_cones]
        # a cone's indices are ascending and unique already (StarCatalog.cone sorts them)
        idx = cones[0] if len(cones) == 1 else np.unique(np.concatenate(cones))
        xy = np.zeros((0, 2))
        if len(idx):  # no deep star near any beacon (the usual case): nothing to project
            xy = cam.project(deep.u_icrs.take(idx, axis=0) @ A.T)
            xy = xy.compress(np.logical_and.reduce(np.isfinite(xy), axis=1), axis=0)
        if len(xy):
            on_star = _near_any(spots.xy_px[cand], xy, opt.deep_star_radius_px)
            cand, m2 = cand[~on_star], m2[:, ~on_star]
    spot_mag = None
    if len(cand):
        # photometric zero point from the matched, unsaturated stars: m = zp - 2.5 log10(flux)
        ms = match.spot_index
        flux_ms = spots.flux_dn.take(ms)
        good = (~spots.saturated.take(ms)) & (flux_ms > 0)
        vm = np.asarray(ref_vmag).take(match.star_index)
        # every log10 argument is > 0 (NaN fluxes are not good; the rest clipped at 1e-9): no
        # division by zero to silence
        zp = _median(vm.compress(good) + 2.5 * np.log10(flux_ms.compress(good))) if np.count_nonzero(good) >= 3 else np.nan
        spot_mag = zp - 2.5 * np.log10(np.maximum(spots.flux_dn.take(cand), 1e-9))
        # saturated spots are at least as bright as measured: no penalty for a brighter prediction
        spot_mag = np.where(spots.saturated.take(cand), np.nan, spot_mag)
    chosen = _assign_from_m2(preds, m2, spot_mag, opt.mag_sigma)
    return tuple(_beacon_result(p, spots, None if k is None else int(cand[k])) for p, k in zip(preds, chosen))


def _clearly_invertible(a) -> bool:
    """True when every 2 x 2 matrix of the stack ``a`` (k, 2, 2) is finite, with entries 0 or of
    magnitude in [1e-30, 1e30], and ``|ad - bc| > 1e-8 (|ad| + |bc|)``: LU with partial pivoting
    (LAPACK gesv) then meets no zero pivot (the second pivot is ``det / p`` within a relative
    rounding far below 1e-8) and no product, quotient or inverse entry leaves [1e-130, 1e130], so
    no overflow, underflow, division by zero or invalid operation is raised."""
    if a.ndim != 3 or a.shape[1:] != (2, 2):
        return False
    for (p, q), (r, t) in a.tolist():
        for x in (p, q, r, t):
            ax = abs(x)
            if not (ax == 0.0 or 1e-30 <= ax <= 1e30):  # NaN fails too
                return False
        ad, bc = p * t, q * r
        if not abs(ad - bc) > 1e-8 * (abs(ad) + abs(bc)):
            return False
    return True


def _lines_of_sight(cam, xys):
    """``cam.line_of_sight(np.array(xys))`` for a few pixel positions: without lens distortion,
    :meth:`~skynav.scenes.camera.Camera.back_project`'s operations in Python floats (``(x - cx) /
    fx``, ``(y - cy) / fy``, 1, divided by the square root of their sum of squares, in order;
    tested within 4 ulps of 1 per component); with distortion, ``line_of_sight`` itself."""
    if not cam.distortion.is_identity:
        return cam.line_of_sight(np.array(xys))
    cx, cy, fx, fy = float(cam.cx), float(cam.cy), float(cam.fx_px), float(cam.fy_px)
    rows = []
    for x, y in (xy.tolist() for xy in xys):
        a, b = (x - cx) / fx, (y - cy) / fy
        n = math.sqrt(a * a + b * b + 1.0)  # 1.0 * 1.0
        rows.append((a / n, b / n, 1.0 / n))
    return np.array(rows)


def _beacon_result(p, spots, k):
    if k is None:
        return BeaconResult(name=p["name"], xy_px=None, predicted_xy_px=p["xy_px"], predicted_cov_px2=p["cov_px2"],
                            status="not_found")
    return BeaconResult(name=p["name"], xy_px=spots.xy_px[k].copy(), predicted_xy_px=p["xy_px"],
                        predicted_cov_px2=p["cov_px2"], status="found")


def _near_any(xy, ref, radius):
    """True where a point of ``xy`` (M, 2) has a point of ``ref`` (K, 2) closer than ``radius``
    (strictly, squared distances compared as :class:`scipy.spatial.cKDTree` with
    ``distance_upper_bound`` does)."""
    d0 = xy[:, None, 0] - ref[None, :, 0]
    d1 = xy[:, None, 1] - ref[None, :, 1]
    return np.any(d0 * d0 + d1 * d1 < radius * radius, axis=1)


def _mahalanobis2(preds, xy):
    """``m2[i, j] = d^T P_i^-1 d`` with ``d = xy[j] - preds[i]["xy_px"]``, shape (nb, M); a row
    of ``inf`` where ``P_i`` is singular (that beacon can take no spot)."""
    nb, m = len(preds), len(xy)
    if m == 0 or nb == 0:
        return np.zeros((nb, m))
    out = np.empty((nb, m))
    for i, (p, Pinv) in enumerate(zip(preds, _inv_2x2_stack([p["cov_px2"] for p in preds]))):
        if Pinv is None:
            out[i] = np.inf
            continue
        d = xy - p["xy_px"][None]
        out[i] = np.einsum("ni,ij,nj->n", d, Pinv, d)
    return out


def _inv_2x2_stack(mats):
    """``[numpy.linalg.inv(M) for M in mats]`` with None where ``inv`` raises LinAlgError
    (singular), by one call of the gufunc behind ``numpy.linalg.inv`` on the stack (the same
    code: the same LAPACK ``gesv`` per matrix, so the same bits, without the wrapper's ~8 us a
    call). The gufunc
    fills a singular matrix's inverse with NaN and raises the invalid flag, which
    ``numpy.linalg.inv`` turns into LinAlgError."""
    a = np.asarray(mats, dtype=float)
    if _umath_linalg is None:  # pragma: no cover - numpy without the private module
        return [_inv_or_none(M) for M in a]
    if _clearly_invertible(a):
        # no zero pivot and no floating-point exception can occur: the gufunc's values are the
        # same under any error state, so it runs under the caller's (no errstate to enter)
        return list(_umath_linalg.inv(a, signature="d->d"))
    with np.errstate(invalid="raise", over="ignore", divide="ignore", under="ignore"):
        try:
            inv = _umath_linalg.inv(a, signature="d->d")
        except FloatingPointError:  # some matrix singular: each one alone, as numpy.linalg.inv
            inv = None
    if inv is None:
        return [_inv_or_none(M) for M in a]
    return list(inv)


def _inv_or_none(M):
    try:
        return np.linalg.inv(M)
    except np.linalg.LinAlgError:
        return None


@functools.lru_cache(maxsize=1)
def _linear_sum_assignment():
    """scipy's solver, imported once (``from scipy.optimize import ...`` costs ~20 us a call:
    scipy resolves its lazily loaded submodule every time)."""
    from scipy.optimize import linear_sum_assignment

    return linear_sum_assignment


def _assign_beacons(preds, spots_xy, candidate, spot_mag, mag_sigma):
    """Improved mode: one spot per beacon and one beacon per spot, jointly (a beacon with a huge
    ellipse must not take the spot of one with a small ellipse, as the paper's one-at-a-time
    closest-spike rule lets it). Cost of beacon i on spot j inside its 3-sigma ellipse:
    ``m2_ij + ((m_j - m_pred_i) / mag_sigma)^2``; "not found" costs the ellipse's edge plus a
    3-sigma brightness mismatch, so any spot inside the ellipse is preferred over none.
    Returns the chosen spot index (into ``spots_xy``) of each beacon, or None."""
    cand = np.flatnonzero(candidate)
    if len(preds) == 0:
        return []
    chosen = _assign_from_m2(preds, _mahalanobis2(preds, spots_xy[cand]), None if spot_mag is None else spot_mag[cand],
                             mag_sigma)
    return [None if k is None else int(cand[k]) for k in chosen]


def _assign_from_m2(preds, m2, spot_mag, mag_sigma):
    """:func:`_assign_beacons` on the candidates' Mahalanobis^2 ``m2`` (nb, M) and magnitudes
    ``spot_mag`` (M,) or None; returns column indices into ``m2`` or None. A spot outside every
    ellipse has only forbidden entries, so leaving it out does not change the assignment."""
    nb, m = m2.shape
    if nb == 0:
        return []
    chosen = [None] * nb
    inside = m2 <= CHI2_2DOF_3SIGMA
    if not inside.any():
        return chosen
    BIG = 1e9
    if nb == 1:
        # one row: scipy's shortest augmenting path takes, at its first step, the column of the
        # least cost and, among equal costs, the lowest index (it scans the columns from the
        # last, and an equal unassigned column replaces the one held): the first minimum over
        # the spots inside the ellipse and "not found" (test_beacon_assignment checks it
        # against linear_sum_assignment, ties included). Costs as below, in Python floats
        # (m2 + ((m - m_pred) / mag_sigma)^2, the square as numpy's x * x)
        vm = float(preds[0]["v_mag"])
        mags = spot_mag.tolist() if spot_mag is not None and math.isfinite(vm) else None
        best, j_best = CHI2_2DOF_3SIGMA + 9.0, None
        for j, (m2j, ok) in enumerate(zip(m2[0].tolist(), inside[0].tolist())):
            if not ok:
                continue  # BIG
            cj = m2j
            if mags is not None:
                dm = mags[j] - vm
                dm = dm / mag_sigma if math.isfinite(dm) else 0.0
                cj = m2j + dm * dm
            if cj < BIG and (cj < best or (cj == best and j_best is None)):
                best, j_best = cj, j
        chosen[0] = j_best
        return chosen
    c = m2
    if spot_mag is not None:
        vmag = np.array([p["v_mag"] for p in preds], dtype=float)
        dm = spot_mag[None, :] - vmag[:, None]
        c = c + np.where(np.isfinite(vmag)[:, None], np.where(np.isfinite(dm), dm / mag_sigma, 0.0) ** 2, 0.0)
    cost = np.full((nb, m + nb), BIG)
    cost[:, :m] = np.where(inside, c, BIG)
    cost[np.arange(nb), m + np.arange(nb)] = CHI2_2DOF_3SIGMA + 9.0
    rows, cols = _linear_sum_assignment()(cost)
    for i, j in zip(rows.tolist(), cols.tolist()):
        if j < m and cost[i, j] < BIG:
            chosen[i] = j
    return chosen
