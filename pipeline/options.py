"""The speed/accuracy trade-offs of :func:`~skynav.pipeline.process.process_frame`, one object."""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["ProcessOptions"]


@dataclass(frozen=True, kw_only=True)
class ProcessOptions:
    """Speed/accuracy trade-offs of :func:`process_frame` (one object; vary with ``replace``)."""

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
