"""One frame in, one :class:`~skynav.pipeline.results.FrameResult` out (the pipeline's driver).

``process_frame`` never raises for a bad image: every failure is an outcome class. The steps:
the saturated fraction and background levels (:mod:`~skynav.pipeline.levels`); tracking from
``previous_attitude`` in windows (:mod:`~skynav.pipeline.tracking`), else spots over the whole
frame (:mod:`~skynav.pipeline.centroids`), association from the previous attitude and, failing
that, lost in space (:mod:`~skynav.pipeline.star_id`; Andreis et al. (2023b), Fig. 4); the attitude and its
covariance (:mod:`~skynav.pipeline.attitude`); the beacons predicted (:mod:`~skynav.pipeline.beacons`)
and identified (:mod:`~skynav.pipeline.beacon_id`). Where the paper's method and the improved
one differ, the mode object decides (:mod:`~skynav.pipeline.modes`: ``"paper"`` and
``"improved"``).
"""

from __future__ import annotations

import time

import numpy as np

from skynav.scenes.ephemeris_jpl import default_ephemeris

from .beacon_id import add_attitude_covariance
from .beacons import BodyStates, predict_beacons
from .centroids import Spots
from .levels import Levels
from .modes import MODES
from .options import ProcessOptions
from .results import AttitudeResult, FrameResult
from .star_id import C_KM_S, StarDirections, lost_in_space, refine
from .tracking import track_windowed

__all__ = ["ProcessOptions", "process_frame"]

_DEFAULT_OPTIONS = ProcessOptions()


def process_frame(observation, *, catalog, predicted_state=None, previous_attitude=None, mode="improved",
                  options: ProcessOptions | None = None, ephemeris=None, body_states=None) -> FrameResult:
    """Centroids, star ID, attitude and beacons of one frame.

    Parameters
    ----------
    observation : skynav.datasets.observation.Observation
        ``dn`` (H, W), ``epoch_tdb_s``, ``exposure_s``, ``camera`` (as calibrated).
    catalog : skynav.pipeline.OnboardCatalog
        The on-board star catalogue and its k-vector.
    predicted_state : skynav.pipeline.PredictedState, optional
        Needed for beacons (and for aberration and parallax in the improved mode).
    previous_attitude : ndarray, shape (3, 3), optional
        ``R_cam_icrs`` of the previous frame: tracking mode first.
    mode : {"paper", "improved"}
        The paper's pipeline (Andreis et al. (2023a)) or skynav's improved one.
    options : ProcessOptions, optional
        Thresholds and tolerances (default ``ProcessOptions()``).
    ephemeris : optional
        The body ephemeris (default DE421, :func:`skynav.scenes.ephemeris_jpl.default_ephemeris`).
    body_states : skynav.pipeline.beacons.BodyStates, optional
        The body states at this frame's epoch, to share between calls on one frame (else made here).

    Returns
    -------
    FrameResult
        Never raises for a bad image; ``status`` says what happened.

    Raises
    ------
    ValueError
        An unknown ``mode``.

    References
    ----------
    Andreis et al. (2023a): the detection threshold (Eq. 6), star identification with the
    k-vector (Sec. III.A.2), the attitude's noise (Eq. 22), the beacons' predicted projection
    and covariance (Eqs. 13-22).

    Examples
    --------
    A rendered 256 x 256 px frame: the attitude, against the truth's:

    >>> import tempfile
    >>> from skynav.datasets import generate, open, preset_recipe
    >>> from skynav.pipeline import OnboardCatalog, PredictedState, process_frame
    >>> from skynav.renderer import RenderOptions
    >>> recipe = preset_recipe("montecarlo")
    >>> recipe.update(frames=1, camera={"preset": "paper", "width": 256, "height": 256, "fov_deg": 20})
    >>> tmp = tempfile.TemporaryDirectory()
    >>> _ = generate(recipe, tmp.name + "/ds", workers=1, progress=False,
    ...              render_options=RenderOptions(backend="numpy"))
    >>> ds = open(tmp.name + "/ds")
    >>> obs, truth = ds.observation(0), ds.truth(0)
    >>> catalog = OnboardCatalog.load(camera=obs.camera)
    >>> state = PredictedState(position_km=truth.position_km, velocity_km_s=truth.velocity_km_s,
    ...                        position_cov_km2=np.eye(3) * 100.0**2)
    >>> result = process_frame(obs, catalog=catalog, predicted_state=state)
    >>> result.status
    'ok'
    >>> import dataclasses
    >>> dR = result.attitude.R_cam_icrs @ truth.R_cam_icrs.T
    >>> bool(np.degrees(np.arccos((np.trace(dR) - 1) / 2)) * 3600 < 140)   # arcsec, < 0.5 px
    True
    >>> black = dataclasses.replace(obs, dn=np.zeros_like(obs.dn))
    >>> process_frame(black, catalog=catalog).status   # never raises for a bad image
    'no_stars'
    >>> tmp.cleanup()
    """
    if mode not in MODES:
        raise ValueError(f"mode must be 'paper' or 'improved', got {mode!r}")
    how = MODES[mode]
    opt = options or _DEFAULT_OPTIONS
    t0 = time.perf_counter()
    timings = {}

    def fail(status, spots_xy=np.zeros((0, 2))):
        timings["total"] = (time.perf_counter() - t0) * 1e3
        return FrameResult(status=status, attitude=AttitudeResult(), timings_ms=timings, mode=mode,
                           centroids_xy_px=np.asarray(spots_xy, float).reshape(-1, 2))

    cam = observation.camera
    try:
        img = np.asarray(observation.dn)
        if img.ndim != 2 or img.shape != (cam.height, cam.width) or not (np.issubdtype(img.dtype, np.integer) or np.all(np.isfinite(np.asarray(img[::64, ::64], dtype=float)))):
            return fail("bad_image")
    except Exception:  # noqa: BLE001 - anything unreadable is a bad image
        return fail("bad_image")
    max_dn = float(2 ** cam.sensor.bit_depth - 1)
    # the saturated fraction from every 8th row and column (a 1024^2 frame: 16384 pixels, +-0.4 %
    # at 1 sigma near the 50 % limit)
    levels = Levels(img, histogram=how.histogram_levels)
    if levels.count_at_least(max_dn) > opt.saturated_fraction * levels.sub.size:
        return fail("saturated")

    v_km_s = None if predicted_state is None else np.asarray(predicted_state.velocity_km_s, float)
    r_km = np.zeros(3) if predicted_state is None else np.asarray(predicted_state.position_km, float)
    if predicted_state is not None and body_states is None:
        body_states = BodyStates(default_ephemeris() if ephemeris is None else ephemeris, observation.epoch_tdb_s)
    ifov = cam.ifov_rad
    half_fov = cam.half_diagonal_fov_rad
    star_dirs = StarDirections(catalog, lambda src, idx: how.star_directions(catalog, src, idx,
                                                                          observation.epoch_tdb_s, r_km, v_km_s))

    # ------------------------------------------------------------------ centroids + star ID
    T = opt.T
    match, method, status = None, "", "id_failed"
    # the k-vector's relative angle tolerance: aberration changes angles by up to |v| / c
    rel_eps = (np.linalg.norm(v_km_s) / C_KM_S if v_km_s is not None else 2e-4) + 2e-5
    eps_rad = min(opt.eps_px * ifov, np.radians(opt.eps_max_arcsec / 3600.0))
    spots = Spots.empty()
    t_c = t_id = 0.0
    windowed_source = windowed_preds = None
    if previous_attitude is not None and how.windowed_tracking and opt.track_window_px > 0:
        tc0 = time.perf_counter()
        got = track_windowed(img, observation, catalog, np.asarray(previous_attitude, float), star_dirs,
                             predicted_state, opt, max_dn, body_states, level=levels.level(opt.T))
        if got is not None:
            spots, b, match, windowed_source, windowed_preds = got
            method, status = "tracking", "ok"
        t_c += time.perf_counter() - tc0
    for _ in range(0 if match is not None else how.id_iterations(opt)):
        tc0 = time.perf_counter()
        spots = how.detect(img, T=T, max_dn=max_dn, opt=opt, levels=levels)
        t_c += time.perf_counter() - tc0
        if len(spots) > opt.max_spots:
            status = "too_many_spots"
            if how.retry_too_many_spots:
                T += opt.T_step
                continue
            break
        if len(spots) < 3:
            status = "no_stars"
            break
        ti0 = time.perf_counter()
        b = cam.line_of_sight(spots.xy_px)
        if previous_attitude is not None:
            m = refine(np.asarray(previous_attitude, float), b, star_dirs, half_fov_rad=half_fov,
                       tol_rad=10 * opt.inlier_px * ifov, iterations=1)
            if m is not None:
                m = refine(m.R_cam_icrs, b, star_dirs, half_fov_rad=half_fov, tol_rad=opt.inlier_px * ifov)
            if m is not None and len(m.spot_index) >= opt.min_matches:
                match, method = m, "tracking"
        if match is None:
            order = how.star_order(spots)
            for n_max, random_triples, max_triples in how.lost_in_space_tries(opt):
                sol = lost_in_space(b[order], catalog, eps_rad=eps_rad, rel_eps=rel_eps, n_max=n_max,
                                    inlier_rad=opt.inlier_px * ifov, rng=np.random.default_rng(opt.seed),
                                    random_triples=random_triples, max_triples=max_triples)
                if sol is None:
                    continue
                A, sp, st = sol
                match = how.accept(A, order[sp], st, b, catalog, star_dirs, half_fov=half_fov, opt=opt, ifov=ifov)
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
        return fail(status, spots.xy_px)

    # ------------------------------------------------------------------ attitude + covariance
    ta0 = time.perf_counter()
    ref = catalog
    if windowed_source is not None:  # windowed tracking associated every catalog star to refine_v_mag
        ref = source = windowed_source
    else:
        match, source = how.deepen(match, b, spots, catalog, star_dirs, half_fov=half_fov, opt=opt, ifov=ifov)
        ref = catalog if source is None else source
    ref_hip, ref_vmag = np.asarray(ref.hip), np.asarray(ref.v_mag)
    # the matched stars' final centroids (improved: measured again by a PSF fit) and their lines of sight
    xy_matched, apart = how.final_centroids(img, spots, match, max_dn=max_dn, opt=opt)
    att, match = how.final_attitude(match, cam.line_of_sight(xy_matched), spots.flux_dn[match.spot_index], star_dirs,
                                    source, half_fov=half_fov, opt=opt, ifov=ifov, apart=apart)
    centroids = spots.xy_px.copy()
    centroids[match.spot_index] = xy_matched
    A = match.R_cam_icrs
    P = att.covariance_rad2
    timings["attitude"] = (time.perf_counter() - ta0) * 1e3

    # ------------------------------------------------------------------ beacons
    tb0 = time.perf_counter()
    beacons = ()
    if predicted_state is not None:
        if windowed_preds is not None:  # predicted with A already, without its covariance
            preds = add_attitude_covariance(windowed_preds, P)
        else:
            preds = predict_beacons(observation.epoch_tdb_s, predicted_state, A, cam, attitude_cov_rad2=P, mode=mode,
                                    sigma_qv=opt.sigma_qv, body_states=body_states)
        beacons = how.identify_beacons(preds, cam, A, spots, match, catalog, opt, ref_vmag)
    timings["beacons"] = (time.perf_counter() - tb0) * 1e3
    timings["total"] = (time.perf_counter() - t0) * 1e3
    return FrameResult(status="ok", attitude=att, centroids_xy_px=centroids, beacons=beacons, timings_ms=timings,
                       mode=mode, star_id_method=method, matched_star_ids=ref_hip[match.star_index],
                       matched_spot_index=np.asarray(match.spot_index))
