"""Wahba's problem by SVD (Andreis et al. (2023a), Eq. 10-12) and its covariance.

Core module. With body (camera) unit vectors ``b_i``, reference (ICRS) unit vectors ``r_i`` and
weights ``w_i``: ``B = sum w_i b_i r_i^T`` (Eq. 10), ``B = U S V^T`` (Eq. 11) and
``A = U diag(1, 1, det U det V) V^T`` (Eq. 12, Markley 1988) minimises
``sum w_i |b_i - A r_i|^2``; ``A`` is the passive ``R_cam_icrs``.

Covariance (Shuster's QUEST measurement model, Markley & Crassidis 2014 eq. 5.93): for
isotropic direction errors of standard deviation ``sigma_i`` rad,
``P = (sum (I - b_i b_i^T) / sigma_i^2)^-1`` of the small rotation error in the camera frame.
"""

from __future__ import annotations

import math

import numpy as np

from scipy.optimize import nnls

from skynav.scenes.constants import ARCSEC_RAD

from .results import AttitudeResult

__all__ = ["wahba_svd", "attitude_covariance", "attitude_result", "rotation_angle_rad", "centroid_variance_px2", "flux_design",
           "weighted_attitude_result"]


def wahba_svd(b_cam, r_icrs, weights=None) -> np.ndarray:
    """Attitude ``A`` (3, 3) with ``b ~ A r``; Eq. 10-12.

    Parameters
    ----------
    b_cam, r_icrs : ndarray, shape (N, 3)
        Unit vectors, N >= 2 (not all parallel).
    weights : ndarray, shape (N,), optional

    Examples
    --------
    >>> A = wahba_svd(np.eye(3), np.eye(3))
    >>> bool(np.allclose(A, np.eye(3)))
    True
    """
    b = np.asarray(b_cam, dtype=float)
    r = np.asarray(r_icrs, dtype=float)
    B = b.T @ r if weights is None else (b * np.asarray(weights, dtype=float)[:, None]).T @ r
    U, _, Vt = np.linalg.svd(B)
    # det(U) det(V) is +-1 exactly in theory; its sign, from the triple products in Python floats
    # (|det| = 1 +- 1e-15, never near 0 for orthogonal factors), picks diag(1, 1, +-1) of Eq. 12
    if _det3(U.tolist()) * _det3(Vt.tolist()) < 0.0:
        U = U * _FLIP
    return U @ Vt  # U diag(1, 1, d) V^T


_FLIP = np.array([1.0, 1.0, -1.0])


def _det3(m) -> float:
    """Determinant of a 3 x 3 matrix given as nested lists (cofactor expansion)."""
    (a, b, c), (d, e, f), (g, h, i) = m
    return a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g)


def attitude_covariance(b_cam, sigma_rad) -> np.ndarray:
    """Covariance (3, 3), rad^2, of the attitude error (camera frame) from N directions."""
    b = np.asarray(b_cam, dtype=float)
    if np.ndim(sigma_rad) == 0:  # one sigma: sum (I - b b^T) / s^2 = (n I - B^T B) / s^2
        F = (len(b) * np.eye(3) - b.T @ b) / float(sigma_rad) ** 2
    else:
        w = 1.0 / np.broadcast_to(np.asarray(sigma_rad, dtype=float), (len(b),)) ** 2
        F = w.sum() * np.eye(3) - (b * w[:, None]).T @ b
    return np.linalg.inv(F)


def rotation_angle_rad(A, B) -> float:
    """Angle of the rotation ``A B^T``, rad (the attitude error between two DCMs)."""
    M = np.asarray(A, dtype=float) @ np.asarray(B, dtype=float).T
    c = (np.trace(M) - 1.0) / 2.0
    s = 0.5 * np.linalg.norm([M[2, 1] - M[1, 2], M[0, 2] - M[2, 0], M[1, 0] - M[0, 1]])
    return float(np.arctan2(s, c))  # atan2: accurate at small angles, where arccos(trace) is not


def attitude_result(match, b_matched, *, floor_rad, min_sigma_rad):
    """The :class:`~skynav.pipeline.results.AttitudeResult` of a star match: the attitude, and its
    covariance (:func:`attitude_covariance`) from the per-axis sigma of the residuals' RMS
    (3 degrees of freedom taken by the fit; a 2-D residual has sqrt(2) axes), floored at
    ``min_sigma_rad``; with 3 stars or fewer the RMS is ``floor_rad``. ``b_matched``: the matched
    spots' lines of sight (N, 3)."""
    n = len(match.spot_index)
    rms = math.sqrt(float(np.mean(match.residual_rad ** 2))) if n > 3 else floor_rad
    sigma = max(rms * math.sqrt(n / max(n - 3, 1)) / math.sqrt(2.0), min_sigma_rad)
    P = attitude_covariance(b_matched, sigma)
    return AttitudeResult(R_cam_icrs=match.R_cam_icrs, covariance_rad2=P, n_stars=n,
                          error_estimate_arcsec=float(np.sqrt(np.trace(P)) / ARCSEC_RAD))


#: Fewest matched stars from which :func:`centroid_variance_px2` fits its model (fewer: equal weights).
MIN_STARS_VARIANCE_FIT = 12


def flux_design(flux_dn) -> np.ndarray:
    """The columns ``1, 1/F, 1/F^2`` of :func:`centroid_variance_px2`'s fit, each scaled by its
    mean (N, 3); ``F`` floored at 1e-9 DN. It depends on the fluxes only: a caller that refits on
    new residuals of the same stars computes it once."""
    F = np.maximum(np.asarray(flux_dn, float), 1e-9)
    X = np.stack([np.ones_like(F), 1.0 / F, 1.0 / F ** 2], axis=1)
    return X / X.mean(axis=0)


def centroid_variance_px2(residual_px, flux_dn, design=None):
    """Per-axis centroid variance of each matched star, px^2, from the frame's own residuals.

    A centroid's error has three parts: a floor independent of the flux (the PSF's sampling on
    the pixel grid, blends, catalogue errors), the photon noise of the star (variance
    proportional to 1 / F) and the background's noise (variance proportional to 1 / F^2; Howell
    2006 sec. 5.3, King 1983). ``sigma^2 = a + c / F + d / F^2`` with ``a, c, d >= 0`` is fitted
    by non-negative least squares to ``|r|^2 / 2`` (a 2-D residual has two axes), so the weights
    follow any PSF, noise model and gain without knowing them. With fewer than
    :data:`MIN_STARS_VARIANCE_FIT` stars (or a degenerate fit) every star gets the mean
    ``|r|^2 / 2``: equal weights.

    Parameters
    ----------
    residual_px : ndarray, shape (N,)
        Angle between each star's predicted and measured direction, in pixels.
    flux_dn : ndarray, shape (N,)
        Background-subtracted flux of each star's spot, DN (> 0).
    design : ndarray, shape (N, 3), optional
        :func:`flux_design` of ``flux_dn``, when the caller has it already.
    """
    r2 = np.asarray(residual_px, float) ** 2 / 2.0
    if len(r2) < MIN_STARS_VARIANCE_FIT:
        return np.full(len(r2), float(r2.mean()) if len(r2) else 0.0)
    Xs = flux_design(flux_dn) if design is None else design
    coef, _ = nnls(Xs, r2)
    var = Xs @ coef
    if not np.all(np.isfinite(var)) or var.max() <= 0.0:
        return np.full(len(r2), float(r2.mean()))
    # a star the fit gives ~zero variance would take all the weight: floor at 1 % of the median
    return np.maximum(var, 0.01 * float(np.median(var)))


def _variance_px2(residual_px, flux_dn, design, apart):
    """:func:`centroid_variance_px2` of the stars, where the stars of the mask ``apart`` (measured
    by another method) get at least their own group's mean ``|r|^2 / 2``, and are left out of the
    flux fit when the others are enough for it."""
    if apart is None or not apart.any():
        return centroid_variance_px2(residual_px, flux_dn, design)
    main = ~apart
    if main.sum() < MIN_STARS_VARIANCE_FIT:
        return centroid_variance_px2(residual_px, flux_dn, design)
    var = np.empty(len(residual_px))
    var[main] = centroid_variance_px2(residual_px[main], flux_dn[main])
    own = float(np.mean(residual_px[apart] ** 2 / 2.0))
    var[apart] = np.maximum(centroid_variance_px2(residual_px, flux_dn, design)[apart], own)
    return var


def weighted_attitude_result(b_matched, u_icrs, flux_dn, A, *, ifov_rad, min_sigma_rad, iterations=2, apart=None):
    """``(AttitudeResult, residual_rad)``: Wahba weighted by ``1 / sigma_i^2`` of each star's
    centroid variance (:func:`centroid_variance_px2`, refitted on each pass's residuals), and the
    covariance of those sigmas (:func:`attitude_covariance`), the per-star sigma floored at
    ``min_sigma_rad``. ``A``: the unweighted solution the residuals start from. ``apart`` (N,)
    bool, optional: stars whose centroids come from another method (a saturated star the PSF fit
    leaves to Eq. 7-8): their variance is fitted apart (no less than their own mean squared
    residual), so that a bright star's flux does not lend them the fitted stars' precision."""
    b = np.asarray(b_matched, float)
    u = np.asarray(u_icrs, float)
    flux_dn = np.asarray(flux_dn, float)
    apart = None if apart is None else np.asarray(apart, bool)
    Xs = flux_design(flux_dn) if len(b) >= MIN_STARS_VARIANCE_FIT else None
    for _ in range(iterations):
        res = np.arccos(np.clip(np.einsum("ij,ij->i", u @ A.T, b), -1.0, 1.0))
        var = _variance_px2(res / ifov_rad, flux_dn, Xs, apart)
        A = wahba_svd(b, u, 1.0 / var)
    res = np.arccos(np.clip(np.einsum("ij,ij->i", u @ A.T, b), -1.0, 1.0))
    n = len(b)
    # the fit takes 3 degrees of freedom from 2 n residual components
    sigma = np.maximum(np.sqrt(_variance_px2(res / ifov_rad, flux_dn, Xs, apart) * n / max(n - 1.5, 1.0)) * ifov_rad,
                       min_sigma_rad)
    P = attitude_covariance(b, sigma)
    return AttitudeResult(R_cam_icrs=A, covariance_rad2=P, n_stars=n,
                          error_estimate_arcsec=float(np.sqrt(np.trace(P)) / ARCSEC_RAD)), res
