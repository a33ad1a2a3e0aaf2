"""The speed/accuracy trade-offs of :func:`~skynav.pipeline.process.process_frame`, one object."""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["ProcessOptions"]


@dataclass(frozen=True, kw_only=True)
class ProcessOptions:
    """Speed/accuracy trade-offs of :func:`process_frame` (one object; vary with ``replace``).

    "paper" and "improved" are the two modes of :func:`process_frame`; a parameter marked
    improved is used by that mode only.

    Parameters
    ----------
    T : float
        Threshold of the spot detection, in sigmas of the background (paper Eq. 6; improved: on
        the robust sigma).
    T_step : float
        Increase of ``T`` after a failed identification.
    T_max_iterations : int
        Tries of the identification with increasing ``T``.
    eps_px : float
        Range error of the k-vector search, px of the field (converted to an angle).
    eps_max_arcsec : float
        Largest range error of the k-vector search, arcsec (bounds the false pairs with coarse
        pixels).
    inlier_px : float
        RANSAC and association tolerance, px.
    n_max : int
        Brightest spots used for the votes.
    n_ransac : int
        Paper mode: random triples tried.
    min_matches : int
        Improved: stars needed to accept an attitude.
    max_spots : int
        More regions than this: status ``too_many_spots``.
    saturated_fraction : float
        More saturated pixels than this fraction: status ``saturated``.
    sigma_qv : float
        Attitude measurement noise of the vector part of the quaternion (paper Eq. 22), no unit.
    mag_sigma : float
        Improved: standard deviation of the beacon brightness prior, mag.
    deep_star_radius_px : float
        Improved: spots this close to a deep-catalogue star are stars, px.
    refine_v_mag : float
        Improved: catalogue depth of the final attitude, V mag (5.5: off).
    refine_px : float
        Improved: association radius of the final attitude, px.
    refine_max_spots : int
        Improved: brightest spots offered to the final association.
    variance_weights : bool
        Improved: the final Wahba problem weighted by each star's centroid variance.
    psf_fit : bool
        Improved: the matched stars' final centroids by a least-squares fit of a pixel-integrated
        Gaussian of the frame's own width (:mod:`~skynav.pipeline.psf_fit`); False (default): Eq. 7-8's.
    psf_fit_max_sigma_px : float
        Improved: the fit is used on frames whose fitted Gaussian width is below this, px (wider
        PSFs leave Eq. 7-8 no pull towards the pixel centre).
    blend_px : float
        Improved: beacons predicted closer than this may share a spot, px.
    track_window_px : float
        Improved tracking: half-size of the windows around predicted stars and beacons, px
        (0: full-frame tracking).
    track_window_max_px : float
        Largest window (a beacon's 3-sigma reach), px; beyond it the full frame is used.
    track_coarse_stars : int
        Windowed tracking, first pass: the brightest predicted stars measured.
    seed : int
        Seed of the paper mode's RANSAC draws.

    References
    ----------
    Andreis et al. (2023a), Eq. 6 (threshold), Sec. III.A.2 (k-vector), Eq. 22 (attitude noise).

    Examples
    --------
    >>> import dataclasses
    >>> from skynav.pipeline import ProcessOptions
    >>> fast = dataclasses.replace(ProcessOptions(), refine_v_mag=5.5, track_window_px=0.0)
    >>> fast.T, fast.refine_v_mag
    (5.0, 5.5)
    """

    T: float = 5.0                      # Eq. 6 tuning parameter (improved: on the robust sigma)
    T_step: float = 2.0                 # paper: T increase after a failed ID
    T_max_iterations: int = 5
    eps_px: float = 0.6                 # k-vector range error, in pixels of the field
    # ... and at most this angle: the false catalog pairs in the window grow with its angle, and
    # with coarse pixels 0.6 px drowns the true stars' votes (20 deg over 256 px, 284"/px: 170"
    # windows, ~750 catalog pairs per spot pair, the true star outvoted at every spot, lost in
    # space 0/8 frames; 384 px 3/8, 448 px 6/8). Capped at 70" (0.6 px of a 640 px camera; the
    # 1024 px paper camera's 42" is below it): 256, 384 and 448 px 8/8, 192 px (379"/px) 5/8.
    eps_max_arcsec: float = 70.0
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
    variance_weights: bool = True       # improved: the final Wahba weighted by each star's centroid variance
    psf_fit: bool = False               # improved, opt-in: the matched stars' final centroids by a fitted pixel-integrated Gaussian
    psf_fit_max_sigma_px: float = 1.0   # ... on frames whose fitted Gaussian width is below this (wider: Eq. 7-8 has no pull)
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
