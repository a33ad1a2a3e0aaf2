"""The two image-processing modes of :func:`~skynav.pipeline.process.process_frame`, as strategies.

Both have one interface; the driver asks the mode at each step that differs:

- :class:`PaperMode` (Andreis et al. (2023a) as published): Eq. 6 threshold with the image mean and standard
  deviation, the iterative increase of T when the ID fails, reference-star votes, RANSAC over
  random 3-star Wahba solutions, the attitude from the RANSAC inliers, catalog directions at the
  catalog epoch without aberration, beacons by the closest spike in the Eq. 23 ellipse with ``S``
  of Eq. 22.
- :class:`ImprovedMode`: a robust threshold (:mod:`~skynav.pipeline.levels`), star-like spots
  first, deterministic vote-ordered triples, every catalog star predicted in the field
  re-associated and the attitude re-solved from all of them with stellar aberration removed
  (Andreis et al. (2024), Sec. 3.2: catalog directions aberrated with the predicted velocity), an acceptance
  test (>= ``min_matches`` stars), windowed tracking (:mod:`~skynav.pipeline.tracking`), beacons
  assigned jointly by Mahalanobis distance plus predicted brightness
  (:func:`~skynav.pipeline.beacon_id.identify_joint`).
"""

from __future__ import annotations

import abc

import numpy as np

from .attitude import MIN_STARS_VARIANCE_FIT, attitude_result, weighted_attitude_result
from .beacon_id import identify_closest, identify_joint
from .centroids import Spots, detect_spots
from .levels import detect_robust
from .psf_fit import fit_gaussian_xy, frame_psf_sigma_px
from .star_id import C_KM_S, StarMatch, refine
from .tracking import clip_outliers

__all__ = ["Mode", "PaperMode", "ImprovedMode", "MODES"]


class Mode(abc.ABC):
    """The interface of a mode: what :func:`~skynav.pipeline.process.process_frame` asks it."""

    name: str
    histogram_levels: bool       # background levels from a histogram of the [::8, ::8] sample
    windowed_tracking: bool      # tracking measures stars and beacons in windows (tracking.py)
    retry_too_many_spots: bool   # more regions than max_spots: raise T and detect again

    @abc.abstractmethod
    def id_iterations(self, opt) -> int:
        """Detections tried, T raised by ``T_step`` after each failed ID."""

    @abc.abstractmethod
    def star_directions(self, catalog, source, idx, t_epoch, r_km, v_km_s):
        """ICRS unit vectors (N, 3) of the stars ``idx`` of ``source`` as this mode uses them."""

    @abc.abstractmethod
    def detect(self, img, *, T, max_dn, opt, levels) -> Spots:
        """The frame's spots at threshold parameter ``T``."""

    @abc.abstractmethod
    def star_order(self, spots: Spots) -> np.ndarray:
        """Spots in the order star ID tries them."""

    @abc.abstractmethod
    def lost_in_space_tries(self, opt):
        """``(n_max, random_triples, max_triples)`` of each lost-in-space attempt."""

    @abc.abstractmethod
    def accept(self, A, sp, st, b, catalog, star_dirs, *, half_fov, opt, ifov):
        """The star match of a lost-in-space solution, or None (rejected)."""

    @abc.abstractmethod
    def deepen(self, match, b, spots, catalog, star_dirs, *, half_fov, opt, ifov):
        """The final association: ``(match, source)``, ``source`` None for the ID catalog."""

    @abc.abstractmethod
    def final_centroids(self, img, spots: Spots, match, *, max_dn, opt):
        """``(xy (N, 2), apart (N,) bool or None)``: the matched spots' centroids the final
        attitude uses, and those measured otherwise than the rest (their variance fitted apart)."""

    @abc.abstractmethod
    def final_attitude(self, match, b_matched, flux_dn, star_dirs, source, *, half_fov, opt, ifov, apart=None):
        """``(AttitudeResult, match)`` of the final association; ``b_matched``: the matched spots'
        lines of sight, ``flux_dn`` their fluxes, ``source`` the stars' source (None: the ID
        catalog), ``apart`` the stars of :meth:`final_centroids` measured otherwise."""

    @abc.abstractmethod
    def identify_beacons(self, preds, cam, A, spots, match, catalog, opt, ref_vmag):
        """:class:`~skynav.pipeline.results.BeaconResult` per predicted beacon."""


class PaperMode(Mode):
    """Andreis et al. (2023a) as published (module docstring)."""

    name = "paper"
    histogram_levels = False
    windowed_tracking = False
    retry_too_many_spots = True

    def id_iterations(self, opt) -> int:
        return opt.T_max_iterations

    def star_directions(self, catalog, source, idx, t_epoch, r_km, v_km_s):
        """ICRS unit vectors of catalog stars ``idx`` as the paper uses them: the catalog epoch."""
        return catalog.u_icrs[idx]

    def detect(self, img, *, T, max_dn, opt, levels) -> Spots:
        return detect_spots(img, T=T, max_dn=max_dn, max_regions=opt.max_spots + 1, stats_stride=2)

    def star_order(self, spots: Spots) -> np.ndarray:
        """Spots in the order star ID tries them: brightest first."""
        return np.arange(len(spots))

    def lost_in_space_tries(self, opt):
        return ((opt.n_max, True, opt.n_ransac),)

    def accept(self, A, sp, st, b, catalog, star_dirs, *, half_fov, opt, ifov):
        """The RANSAC solution's inliers as the match (>= 3 stars), or None."""
        if len(sp) < 3:
            return None
        res = np.arccos(np.clip(np.einsum("ij,ij->i", catalog.u_icrs[st] @ A.T, b[sp]), -1, 1))
        return StarMatch(R_cam_icrs=A, spot_index=sp, star_index=st, residual_rad=res)

    def deepen(self, match, b, spots, catalog, star_dirs, *, half_fov, opt, ifov):
        """The final association (paper: the ID's inliers as they are): ``(match, source)``,
        ``source`` None for the ID catalog."""
        return match, None

    def final_centroids(self, img, spots: Spots, match, *, max_dn, opt):
        """Eq. 7-8's centroids, as detected."""
        return spots.xy_px[match.spot_index], None

    def final_attitude(self, match, b_matched, flux_dn, star_dirs, source, *, half_fov, opt, ifov, apart=None):
        """The paper's attitude (Eq. 10-12, equal weights) and its covariance from the residuals' RMS."""
        return attitude_result(match, b_matched, floor_rad=opt.inlier_px * ifov / 2, min_sigma_rad=0.05 * ifov), match

    def identify_beacons(self, preds, cam, A, spots, match, catalog, opt, ref_vmag):
        return identify_closest(preds, spots, match, opt)


class ImprovedMode(Mode):
    """The improved pipeline (module docstring)."""

    name = "improved"
    histogram_levels = True
    windowed_tracking = True
    retry_too_many_spots = False

    def id_iterations(self, opt) -> int:
        return 1

    def star_directions(self, catalog, source, idx, t_epoch, r_km, v_km_s):
        """Catalog directions at the epoch seen from ``r_km`` (proper motion and parallax), with
        stellar aberration of the predicted velocity ``v_km_s`` (first order in v / c)."""
        u = source.directions(idx, t_epoch, r_km)
        if v_km_s is not None:
            beta = v_km_s / C_KM_S
            u = u + beta - (u @ beta)[:, None] * u
            u /= np.linalg.norm(u, axis=1)[:, None]
        return u

    def detect(self, img, *, T, max_dn, opt, levels) -> Spots:
        return detect_robust(img, T=T, max_dn=max_dn, max_regions=opt.max_spots + 1, level=levels.level(T))

    def star_order(self, spots: Spots) -> np.ndarray:
        """Star-like spots first (>= 2 pixels, <= 12 px across, elongation < 4: no single hot
        pixels, no resolved bodies), brightest first within each group."""
        starlike = (spots.n_pixels >= 2) & (spots.size_px <= 12) & (spots.elongation < 4.0)
        return np.concatenate([np.flatnonzero(starlike), np.flatnonzero(~starlike)])

    def lost_in_space_tries(self, opt):
        return ((opt.n_max, False, 200), (2 * opt.n_max, False, 200))

    def accept(self, A, sp, st, b, catalog, star_dirs, *, half_fov, opt, ifov):
        """Every catalog star the ID's attitude predicts in the field re-associated, the attitude
        re-solved; accepted with >= ``min_matches`` stars."""
        m = refine(A, b, star_dirs, half_fov_rad=half_fov, tol_rad=opt.inlier_px * ifov)
        return m if m is not None and len(m.spot_index) >= opt.min_matches else None

    def deepen(self, match, b, spots, catalog, star_dirs, *, half_fov, opt, ifov):
        """The final attitude from every catalog star to ``refine_v_mag`` that the identified
        attitude predicts next to a spot (mutual nearest within ``refine_px``): ~5x the stars of
        the ID catalog, then one residual clip."""
        if opt.refine_v_mag <= catalog.limiting_v_mag:
            return match, None
        deep = catalog.deep_stars(opt.refine_v_mag)
        bright = np.argsort(-spots.flux_dn, kind="stable")[:opt.refine_max_spots]
        m2 = refine(match.R_cam_icrs, b[bright], lambda c, r: star_dirs(c, r, deep), half_fov_rad=half_fov,
                    tol_rad=opt.refine_px * ifov, iterations=1)
        if m2 is None or len(m2.spot_index) < len(match.spot_index):
            return match, None
        match = StarMatch(R_cam_icrs=m2.R_cam_icrs, spot_index=bright[m2.spot_index], star_index=m2.star_index,
                          residual_rad=m2.residual_rad)
        return clip_outliers(match, b, deep, star_dirs, half_fov), deep

    def final_centroids(self, img, spots: Spots, match, *, max_dn, opt):
        """Each matched star measured again by a least-squares fit of a pixel-integrated Gaussian of
        the frame's own width (:mod:`~skynav.pipeline.psf_fit`); Eq. 7-8's centroid where the fit
        does not hold (a saturated or clipped stamp: those are ``apart``). Eq. 7-8's ``I^2``
        weights pull a centroid towards its pixel's centre when the PSF is narrow (~0.05-0.1 px on
        a 0.5 px Gaussian or a 1 px Airy, whatever the star's flux); from a width of
        ``psf_fit_max_sigma_px`` (1 px) on, a Gaussian's power at one cycle per pixel,
        ``exp(-2 pi^2 sigma^2)`` < 3e-9, leaves them no pull to remove, and Eq. 7-8's centroids
        are kept (on a 1.5 px Gaussian under a bright sky they gave the better attitudes)."""
        xy = spots.xy_px[match.spot_index]
        if not opt.psf_fit or len(xy) < MIN_STARS_VARIANCE_FIT:
            return xy, None
        sigma = frame_psf_sigma_px(img, xy, spots.flux_dn[match.spot_index], max_dn=max_dn)
        if not sigma < opt.psf_fit_max_sigma_px:
            return xy, None
        xy_fit, fitted = fit_gaussian_xy(img, xy, sigma_px=sigma, max_dn=max_dn)
        return xy_fit, (~fitted if fitted.any() else None)

    def final_attitude(self, match, b_matched, flux_dn, star_dirs, source, *, half_fov, opt, ifov, apart=None):
        """Wahba weighted by each star's centroid variance, fitted on the frame's own residuals
        against the flux (:func:`~skynav.pipeline.attitude.weighted_attitude_result`): a bright
        star's centroid is ~10x better than a faint one's, and equal weights let the faint stars
        of the deep association set the error (with another renderer's PSF and noise as with ours)."""
        if len(match.spot_index) < 4 or not opt.variance_weights:
            return attitude_result(match, b_matched, floor_rad=opt.inlier_px * ifov / 2, min_sigma_rad=0.05 * ifov), match
        idx, u_all = star_dirs(match.R_cam_icrs[2], half_fov, source)
        pos = {s: k for k, s in enumerate(idx.tolist())}
        u = u_all.take([pos[s] for s in np.asarray(match.star_index).tolist()], axis=0)
        att, res = weighted_attitude_result(b_matched, u, flux_dn, match.R_cam_icrs, ifov_rad=ifov,
                                            min_sigma_rad=0.01 * ifov, apart=apart)
        return att, StarMatch(R_cam_icrs=att.R_cam_icrs, spot_index=match.spot_index, star_index=match.star_index,
                              residual_rad=res)

    def identify_beacons(self, preds, cam, A, spots, match, catalog, opt, ref_vmag):
        return identify_joint(preds, cam, A, spots, match, catalog, opt, ref_vmag)


MODES = {"paper": PaperMode(), "improved": ImprovedMode()}
