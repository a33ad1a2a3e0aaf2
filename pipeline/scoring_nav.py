"""The navigation benchmark's campaign: Monte Carlo EKF runs along a ``sequence`` dataset, scored
against its truth (``skynav bench nav``).

Scoring module (it reads ground truth; ``tests/test_architecture.py`` lets only ``pipeline/scor*``
do that). What each part sees:

- the filter (:mod:`skynav.pipeline.ekf`) sees the images through
  :func:`skynav.pipeline.process_frame` (attitude and planet centroid), the calibrated camera, the
  on-board DE421 and the commanded pointing plan (which planet each frame was pointed at: the
  dataset's leg plan, ``legs.csv`` / the frame's ``dataset.target``), never the truth;
- the truth is read here for: the Monte Carlo initial states (Andreis et al. (2024), Eq. 45-46: nominal state
  plus ``sqrt(P0)`` times a standard normal draw), the measurement-noise calibration (below), and
  the scores (errors, NEES, measured centroid errors).

Measurement noise ``R = sigma_px^2 I``: measured, not guessed (Andreis et al. (2024), Sec. 5.1 did the same
with its image-processing Monte Carlo): before the filter runs, the image processing is run on
every ``calibration_stride``-th frame (default: every frame; with every 4th the per-class sigmas
came out 10-15 % low on the reference campaign, e.g. Mars 0.061 against 0.070 px from all frames,
within their sampling error but enough to show in the NEES) with a predicted state drawn from P0
about the truth, and
the target's centroid minus the measurement model at the true state gives the errors
(:class:`CentroidNoise`): per class of measurement (target and photocentre law) with at least
:data:`MIN_CLASS_FRAMES` frames, the class's mean square per axis and the part of it constant over
a track (:func:`track_bias_sigma`); otherwise ``sigma0^2 + (kappa D)^2`` with ``D`` the planet's
apparent diameter in px, fitted on all frames by non-negative least squares. Both with iterated
99.7 % clipping of outliers such as a star blended with the planet, which the filter's innovation
gate rejects; the filter evaluates ``D`` from its own estimate. ``--sigma-px`` gives a constant
instead.

Phase: the renderer draws planets as lit discs, whose centre of light sits up to ~0.4 diameter
from the centre towards the Sun (1.8 px for the Earth early in the cruise, 0.2 px for Venus). By
default the measurement model aims at the photocentre: the Lambert one
(:func:`skynav.pipeline.measurement.lambert_photocentre_offset`), or for a resolved disc whose
spot is saturated the lit area's centroid
(:func:`skynav.pipeline.measurement.saturated_photocentre_offset`; :func:`centroid_usable`
decides from the image); ``phase_offset=False`` keeps the centre-of-planet model of Andreis et al. (2024). A
centroid with another body predicted within :data:`BLEND_PX` is not used (the Earth and the Moon
in one spot).

Three rooms: the plan (:mod:`~skynav.pipeline.scoring_nav_plan`), the noise calibration
(:mod:`~skynav.pipeline.scoring_nav_noise`) and the campaign
(:mod:`~skynav.pipeline.scoring_nav_campaign`); this module gathers their public names.
"""

from __future__ import annotations

from .scoring_nav_campaign import (UPDATE_ITERATIONS, CampaignResult, check_realisations, run_campaign,
                                   run_realisations)
from .planet_centroid import BLEND_PX, CentroidNoise, centroid_usable, diameter_px
from .scoring_nav_noise import MIN_CLASS_FRAMES, calibrate_sigma_px, track_bias_sigma
from .scoring_nav_plan import NavInputError, NavPlan, icrs_to_ecliptic, load_plan

__all__ = ["NavInputError", "NavPlan", "CampaignResult", "CentroidNoise", "load_plan", "calibrate_sigma_px",
           "run_campaign", "run_realisations", "check_realisations", "icrs_to_ecliptic", "centroid_usable",
           "track_bias_sigma", "diameter_px", "BLEND_PX", "MIN_CLASS_FRAMES", "UPDATE_ITERATIONS"]
