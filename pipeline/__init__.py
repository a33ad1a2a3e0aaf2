"""skynav.pipeline: the on-board image processing (paper 000): centroids, star ID, attitude, beacons.

Public API: :func:`process_frame` (one frame in, a :class:`FrameResult` out, never raising for a
bad image), :class:`OnboardCatalog` (built once, cached on disk), :class:`PredictedState`,
:class:`ProcessOptions` and the result classes.
"""

from .catalog import OnboardCatalog
from .process import ProcessOptions, process_frame
from .results import AttitudeResult, BeaconResult, FrameResult, PredictedState

__all__ = ["AttitudeResult", "BeaconResult", "FrameResult", "OnboardCatalog", "PredictedState", "ProcessOptions",
           "process_frame"]
