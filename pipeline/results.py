"""The result objects of the image-processing pipeline (the contract with the EKF and the benchmark).

Core module: frozen value classes only. :func:`skynav.pipeline.process_frame` returns a
:class:`FrameResult` for every frame and never raises for a bad image; ``status`` says what
happened (one of :data:`FRAME_STATUSES`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["AttitudeResult", "BeaconResult", "FRAME_STATUSES", "BEACON_STATUSES", "FrameResult",
           "PredictedState"]

#: Outcome classes of a frame. "ok": attitude solved and verified; every other value means
#: ``attitude.R_cam_icrs`` is None.
FRAME_STATUSES = (
    "ok",            # attitude from >= 3 verified catalog matches
    "no_stars",      # fewer than 3 spots after thresholding (black, pure noise at high T, ...)
    "too_many_spots",  # the spot list is not a star field (hot pixels, noise, saturated frame)
    "id_failed",     # spots found but no star pattern verified (no wrong attitude reported)
    "saturated",     # most of the frame at the sensor maximum (blinded)
    "bad_image",     # the image cannot be processed (wrong shape, empty, not finite)
)

#: Outcome of one beacon: "found" (a spot inside the 3-sigma ellipse), "not_found" (none inside).
#: Only beacons predicted in the field (improved: or whose ellipse reaches it) are listed; a frame
#: without an attitude lists none (``beacons == ()``), since nothing can be projected.
BEACON_STATUSES = ("found", "not_found")


@dataclass(frozen=True, kw_only=True, eq=False)
class PredictedState:
    """The spacecraft's own prediction of its state (ICRS, barycentric), from the filter.

    Parameters
    ----------
    position_km : array_like, shape (3,)
        Position, km.
    velocity_km_s : array_like, shape (3,)
        Velocity, km/s.
    position_cov_km2 : array_like, shape (3, 3)
        Covariance of the position, km^2 (sizes the beacons' search ellipses).

    Raises
    ------
    ValueError
        An array of another shape.

    Examples
    --------
    >>> from skynav.pipeline import PredictedState
    >>> s = PredictedState(position_km=[1.5e8, 0, 0], velocity_km_s=[0, 30, 0],
    ...                    position_cov_km2=np.eye(3) * 1e4)
    >>> s.position_km.tolist(), s.position_km.flags.writeable
    ([150000000.0, 0.0, 0.0], False)
    """

    position_km: np.ndarray
    velocity_km_s: np.ndarray
    position_cov_km2: np.ndarray

    def __post_init__(self):
        for name, shape in (("position_km", (3,)), ("velocity_km_s", (3,)), ("position_cov_km2", (3, 3))):
            a = np.array(getattr(self, name), dtype=float)
            if a.shape != shape:
                raise ValueError(f"PredictedState.{name} has shape {a.shape}; expected {shape}")
            a.setflags(write=False)
            object.__setattr__(self, name, a)


@dataclass(frozen=True, kw_only=True, eq=False)
class AttitudeResult:
    """Attitude of one frame.

    Attributes
    ----------
    R_cam_icrs : ndarray, shape (3, 3) or None
        Passive attitude matrix, ``v_cam = R_cam_icrs @ v_icrs`` (None when not solved).
    covariance_rad2 : ndarray, shape (3, 3) or None
        Covariance of the small-angle attitude error (camera frame, rad^2).
    n_stars : int
        Number of catalog stars used in the final solution.
    error_estimate_arcsec : float
        1-sigma total pointing uncertainty estimate, arcsec (sqrt of the covariance trace; nan
        when not solved).

    Examples
    --------
    >>> from skynav.pipeline import AttitudeResult
    >>> unsolved = AttitudeResult()
    >>> unsolved.R_cam_icrs is None, unsolved.n_stars, unsolved.error_estimate_arcsec
    (True, 0, nan)
    """

    R_cam_icrs: np.ndarray | None = None
    covariance_rad2: np.ndarray | None = None
    n_stars: int = 0
    error_estimate_arcsec: float = float("nan")


@dataclass(frozen=True, kw_only=True, eq=False)
class BeaconResult:
    """Identification of one beacon (planet) in one frame.

    Attributes
    ----------
    name : str
        Body name as in the ephemeris ("mars", "jupiter", ...).
    xy_px : ndarray, shape (2,) or None
        Centroid of the spot identified as the beacon, px (None if not found).
    predicted_xy_px : ndarray, shape (2,)
        Predicted projection (first-order light-time and aberration), px.
    predicted_cov_px2 : ndarray, shape (2, 2)
        Covariance of the predicted projection (Andreis et al. (2023a), Eq. 13-22), px^2.
    status : str
        One of :data:`BEACON_STATUSES`.

    References
    ----------
    Andreis et al. (2023a), Eqs. 13-22 (the predicted projection and its covariance).

    Examples
    --------
    >>> from skynav.pipeline import BeaconResult
    >>> b = BeaconResult(name="mars", xy_px=None, predicted_xy_px=np.array([100.0, 80.0]),
    ...                  predicted_cov_px2=np.eye(2) * 4.0, status="not_found")
    >>> b.status, float(np.sqrt(b.predicted_cov_px2[0, 0]))   # 1-sigma, px
    ('not_found', 2.0)
    """

    name: str
    xy_px: np.ndarray | None
    predicted_xy_px: np.ndarray
    predicted_cov_px2: np.ndarray
    status: str


@dataclass(frozen=True, kw_only=True, eq=False)
class FrameResult:
    """What :func:`skynav.pipeline.process_frame` made of one frame.

    Attributes
    ----------
    status : str
        Outcome class, one of :data:`FRAME_STATUSES`.
    attitude : AttitudeResult
        The attitude (``R_cam_icrs`` None unless ``status == "ok"``).
    centroids_xy_px : ndarray, shape (N, 2), px
        All spot centroids (x = column, centre of the top-left pixel at (0, 0)).
    beacons : tuple of BeaconResult
        One per beacon predicted in or near the field (empty without a predicted state).
    timings_ms : dict
        Wall time per stage, ms ("centroids", "star_id", "attitude", "beacons", "total").
    mode : str
        "paper" or "improved".
    star_id_method : str
        How the attitude was found ("tracking", "lost_in_space", or "" when not solved).
    matched_star_ids : ndarray, shape (M,), int
        Catalog ids (HIP numbers) of the matched stars.
    matched_spot_index : ndarray, shape (M,), int
        Rows of ``centroids_xy_px`` matched to ``matched_star_ids``.

    Examples
    --------
    One 256 x 256 px frame of a 20 deg camera, rendered, then processed:

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
    >>> result.ok, result.mode, result.attitude.R_cam_icrs.shape
    (True, 'improved', (3, 3))
    >>> len(result.matched_star_ids) == len(result.matched_spot_index) == result.attitude.n_stars
    True
    >>> tmp.cleanup()
    """

    status: str
    attitude: AttitudeResult
    centroids_xy_px: np.ndarray
    beacons: tuple = ()
    timings_ms: dict = field(default_factory=dict)
    mode: str = "improved"
    star_id_method: str = ""
    matched_star_ids: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))
    matched_spot_index: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))

    @property
    def ok(self) -> bool:
        """``status == "ok"``: the attitude was solved and verified."""
        return self.status == "ok"
