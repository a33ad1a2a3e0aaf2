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
from dataclasses import dataclass

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

    fr = _frame(observation, catalog, predicted_state, how, opt, ephemeris, body_states)
    if isinstance(fr, str):
        return fail(fr)
    found = _identify(fr, previous_attitude, timings)
    if found.match is None:
        return fail(found.status, found.spots.xy_px)

    ta0 = time.perf_counter()
    att, match, centroids, ref = _final_attitude(fr, found)
    timings["attitude"] = (time.perf_counter() - ta0) * 1e3

    tb0 = time.perf_counter()
    beacons = () if predicted_state is None else _beacons(fr, found, att, match, mode, np.asarray(ref.v_mag))
    timings["beacons"] = (time.perf_counter() - tb0) * 1e3
    timings["total"] = (time.perf_counter() - t0) * 1e3
    return FrameResult(status="ok", attitude=att, centroids_xy_px=centroids, beacons=beacons, timings_ms=timings,
                       mode=mode, star_id_method=found.method, matched_star_ids=np.asarray(ref.hip)[match.star_index],
                       matched_spot_index=np.asarray(match.spot_index))


def _frame(observation, catalog, predicted_state, how, opt, ephemeris, body_states):
    """The :class:`_Frame` of one call, or the status of a frame that cannot be processed
    (``"bad_image"``, ``"saturated"``)."""
    cam = observation.camera
    img = _readable_image(observation.dn, cam)
    if img is None:
        return "bad_image"
    max_dn = float(2 ** cam.sensor.bit_depth - 1)
    # the saturated fraction from every 8th row and column (a 1024^2 frame: 16384 pixels, +-0.4 %
    # at 1 sigma near the 50 % limit)
    levels = Levels(img, histogram=how.histogram_levels)
    if levels.count_at_least(max_dn) > opt.saturated_fraction * levels.sub.size:
        return "saturated"
    v_km_s = None if predicted_state is None else np.asarray(predicted_state.velocity_km_s, float)
    r_km = np.zeros(3) if predicted_state is None else np.asarray(predicted_state.position_km, float)
    if predicted_state is not None and body_states is None:
        body_states = BodyStates(default_ephemeris() if ephemeris is None else ephemeris, observation.epoch_tdb_s)
    star_dirs = StarDirections(catalog, lambda src, idx: how.star_directions(catalog, src, idx,
                                                                          observation.epoch_tdb_s, r_km, v_km_s))
    return _Frame(observation=observation, img=img, max_dn=max_dn, levels=levels, catalog=catalog,
                  star_dirs=star_dirs, predicted_state=predicted_state, v_km_s=v_km_s, body_states=body_states,
                  how=how, opt=opt)


def _readable_image(dn, cam):
    """The frame's counts as an array of the camera's shape, or None (unreadable, of another shape,
    or a float frame with a non-finite sample on its 64-px grid: a bad image)."""
    try:
        img = np.asarray(dn)
        if img.ndim != 2 or img.shape != (cam.height, cam.width) or not (
                np.issubdtype(img.dtype, np.integer) or np.all(np.isfinite(np.asarray(img[::64, ::64], dtype=float)))):
            return None
    except Exception:  # noqa: BLE001 - anything unreadable is a bad image
        return None
    return img


@dataclass(frozen=True, kw_only=True, eq=False)
class _Frame:
    """What every step of one :func:`process_frame` call reads: the frame, its levels, the catalogue,
    the predicted state and the mode."""

    observation: object
    img: np.ndarray
    max_dn: float
    levels: Levels
    catalog: object
    star_dirs: StarDirections
    predicted_state: object
    v_km_s: np.ndarray | None
    body_states: object
    how: object
    opt: ProcessOptions

    @property
    def cam(self):
        return self.observation.camera


@dataclass(kw_only=True, eq=False)
class _Found:
    """The outcome of the centroids and the star ID: the spots, their lines of sight ``b``, the
    match (None: ``status`` says why), how it was found, and what windowed tracking measured."""

    spots: Spots
    b: np.ndarray | None = None
    match: object = None
    method: str = ""
    status: str = "id_failed"
    windowed_source: object = None
    windowed_preds: object = None


def _identify(fr: _Frame, previous_attitude, timings) -> _Found:
    """Centroids and star ID: windowed tracking from ``previous_attitude`` (improved mode), else
    spots over the whole frame, association from the previous attitude, then lost in space, with
    ``T`` raised after each failed try (paper mode); ``timings`` gets ``centroids`` and ``star_id``."""
    how, opt = fr.how, fr.opt
    found = _Found(spots=Spots.empty())
    t_c = t_id = 0.0
    if previous_attitude is not None and how.windowed_tracking and opt.track_window_px > 0:
        tc0 = time.perf_counter()
        got = track_windowed(fr.img, fr.observation, fr.catalog, np.asarray(previous_attitude, float), fr.star_dirs,
                             fr.predicted_state, opt, fr.max_dn, fr.body_states, level=fr.levels.level(opt.T))
        if got is not None:
            found.spots, found.b, found.match, found.windowed_source, found.windowed_preds = got
            found.method, found.status = "tracking", "ok"
        t_c += time.perf_counter() - tc0
    T = opt.T
    for _ in range(0 if found.match is not None else how.id_iterations(opt)):
        tc0 = time.perf_counter()
        found.spots = how.detect(fr.img, T=T, max_dn=fr.max_dn, opt=opt, levels=fr.levels)
        t_c += time.perf_counter() - tc0
        if len(found.spots) > opt.max_spots:
            found.status = "too_many_spots"
            if how.retry_too_many_spots:
                T += opt.T_step
                continue
            break
        if len(found.spots) < 3:
            found.status = "no_stars"
            break
        ti0 = time.perf_counter()
        found.b = fr.cam.line_of_sight(found.spots.xy_px)
        found.match, found.method = _identify_spots(fr, found.spots, found.b, previous_attitude)
        t_id += time.perf_counter() - ti0
        if found.match is not None:
            found.status = "ok"
            break
        found.status = "id_failed"
        T += opt.T_step
    timings["centroids"] = t_c * 1e3
    timings["star_id"] = t_id * 1e3
    return found


def _identify_spots(fr: _Frame, spots, b, previous_attitude):
    """``(match or None, method)`` of one detection: the stars re-associated from the previous
    attitude (tracking, >= ``min_matches``), else lost in space over the mode's tries."""
    how, opt, catalog = fr.how, fr.opt, fr.catalog
    ifov, half_fov = fr.cam.ifov_rad, fr.cam.half_diagonal_fov_rad
    if previous_attitude is not None:
        m = refine(np.asarray(previous_attitude, float), b, fr.star_dirs, half_fov_rad=half_fov,
                   tol_rad=10 * opt.inlier_px * ifov, iterations=1)
        if m is not None:
            m = refine(m.R_cam_icrs, b, fr.star_dirs, half_fov_rad=half_fov, tol_rad=opt.inlier_px * ifov)
        if m is not None and len(m.spot_index) >= opt.min_matches:
            return m, "tracking"
    # the k-vector's relative angle tolerance: aberration changes angles by up to |v| / c
    rel_eps = (np.linalg.norm(fr.v_km_s) / C_KM_S if fr.v_km_s is not None else 2e-4) + 2e-5
    eps_rad = min(opt.eps_px * ifov, np.radians(opt.eps_max_arcsec / 3600.0))
    order = how.star_order(spots)
    for n_max, random_triples, max_triples in how.lost_in_space_tries(opt):
        sol = lost_in_space(b[order], catalog, eps_rad=eps_rad, rel_eps=rel_eps, n_max=n_max,
                            inlier_rad=opt.inlier_px * ifov, rng=np.random.default_rng(opt.seed),
                            random_triples=random_triples, max_triples=max_triples)
        if sol is None:
            continue
        A, sp, st = sol
        match = how.accept(A, order[sp], st, b, catalog, fr.star_dirs, half_fov=half_fov, opt=opt, ifov=ifov)
        if match is not None:
            return match, "lost_in_space"
    return None, ""


def _final_attitude(fr: _Frame, found: _Found):
    """``(AttitudeResult, match, centroids (N, 2), ref)``: the final association (windowed tracking
    made it already), the matched stars' final centroids (improved: measured again by a PSF fit),
    and the attitude from their lines of sight; ``ref`` the catalogue the match indexes."""
    how, opt, cam, spots = fr.how, fr.opt, fr.cam, found.spots
    ifov, half_fov = cam.ifov_rad, cam.half_diagonal_fov_rad
    match = found.match
    if found.windowed_source is not None:  # windowed tracking associated every catalog star to refine_v_mag
        ref = source = found.windowed_source
    else:
        match, source = how.deepen(match, found.b, spots, fr.catalog, fr.star_dirs, half_fov=half_fov, opt=opt,
                                   ifov=ifov)
        ref = fr.catalog if source is None else source
    xy_matched, apart = how.final_centroids(fr.img, spots, match, max_dn=fr.max_dn, opt=opt)
    att, match = how.final_attitude(match, cam.line_of_sight(xy_matched), spots.flux_dn[match.spot_index],
                                    fr.star_dirs, source, half_fov=half_fov, opt=opt, ifov=ifov, apart=apart)
    centroids = spots.xy_px.copy()
    centroids[match.spot_index] = xy_matched
    return att, match, centroids, ref


def _beacons(fr: _Frame, found: _Found, att, match, mode, ref_vmag):
    """The beacons predicted with the solved attitude (windowed tracking predicted them already,
    without the attitude's covariance) and identified by the mode."""
    A, P = match.R_cam_icrs, att.covariance_rad2
    if found.windowed_preds is not None:
        preds = add_attitude_covariance(found.windowed_preds, P)
    else:
        preds = predict_beacons(fr.observation.epoch_tdb_s, fr.predicted_state, A, fr.cam, attitude_cov_rad2=P,
                                mode=mode, sigma_qv=fr.opt.sigma_qv, body_states=fr.body_states)
    return fr.how.identify_beacons(preds, fr.cam, A, found.spots, match, fr.catalog, fr.opt, ref_vmag)
