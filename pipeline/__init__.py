"""skynav.pipeline: the on-board image processing (Andreis et al. (2023a)): centroids, star ID, attitude, beacons.

Public API: :func:`process_frame` (one frame in, a :class:`FrameResult` out, never raising for a
bad image), :class:`OnboardCatalog` (built once, cached on disk), :class:`PredictedState`,
:class:`ProcessOptions` and the result classes; :class:`ImageProcessor`, the contract anyone's
image processing fulfils to be benchmarked (:mod:`skynav.pipeline.protocols`).
"""

from .catalog import OnboardCatalog
from .process import ProcessOptions, process_frame
from .protocols import BeaconSighting, ImageProcessor, ImageResult
from .results import AttitudeResult, BeaconResult, FrameResult, PredictedState

__all__ = ["AttitudeResult", "BeaconResult", "BeaconSighting", "FrameResult", "ImageProcessor", "ImageResult",
           "OnboardCatalog", "PredictedState", "ProcessOptions", "process_frame"]

# Navigation filter: measurement model, EKF, optimal pair.
from .ekf import NavFilter, initial_covariance  # noqa: E402
from .filter_dynamics import FilterDynamics  # noqa: E402
from .measurement import CASES, LightCorrections, planet_pixel  # noqa: E402
from .pairs import optimal_pair  # noqa: E402

__all__ += ["CASES", "FilterDynamics", "LightCorrections", "NavFilter", "initial_covariance", "optimal_pair",
            "planet_pixel"]
