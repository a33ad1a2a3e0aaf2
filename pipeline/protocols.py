"""The contract a benchmarked image processor fulfils: :class:`ImageProcessor` and its result.

Core module (no truth). Anyone's star tracker or beacon finder is benchmarked through one
call, ``processor.process(observation, prediction) -> ImageResult``:

- ``observation`` is the reader's :class:`skynav.datasets.observation.Observation`: the digital
  counts ``dn`` (H, W), the mid-exposure epoch ``epoch_tdb_s`` (TDB seconds past J2000), the
  exposure ``exposure_s`` and the camera *as calibrated* (``camera.K``, ``camera.line_of_sight``,
  ``camera.width`` ...). Nothing in it leads to the truth.
- ``prediction`` is the on-board predicted state, a :class:`~skynav.pipeline.results.PredictedState`
  (``position_km``, ``velocity_km_s``, ``position_cov_km2``; ICRS, barycentric), or None when the
  spacecraft has none (lost in space).
- the :class:`ImageResult` carries at least ``R_cam_icrs`` (the passive attitude,
  ``v_cam = R_cam_icrs @ v_icrs``, shape (3, 3), or None when the frame was not solved), and
  optionally the centroids, the matched stars, the beacons found (:class:`BeaconSighting`: a
  pixel centroid with its covariance, and so a line of sight in the calibrated camera) and a
  status.

A processor is made by a *factory* called with the calibrated camera of the dataset's first frame,
``FACTORY(camera) -> ImageProcessor``; ``skynav bench ip DIR --pipeline MODULE:FACTORY`` imports
it (:mod:`skynav.pipeline.plugins`). A processor may keep state between calls (the previous
attitude, for tracking); the benchmark calls it on one frame at a time, in frame order.

Conventions (docs/conventions.md): pixel ``(x, y)`` with the centre of the top-left pixel at
``(0, 0)``; camera frame +z boresight, +x along columns, +y along rows.

Examples
--------
A processor that never solves, and one that returns a fixed attitude:

>>> import numpy as np
>>> from skynav.pipeline.protocols import ImageProcessor, ImageResult
>>> class Blind:
...     def process(self, observation, prediction):
...         return ImageResult(R_cam_icrs=None, status="no_stars")
>>> isinstance(Blind(), ImageProcessor)
True
>>> ImageResult(R_cam_icrs=np.eye(3)).solved, Blind().process(None, None).solved
(True, False)
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Protocol, runtime_checkable

import numpy as np

if TYPE_CHECKING:  # the types of the signatures only; the pipeline sees observations, never opens them
    from skynav.datasets.observation import Observation

    from .filter_dynamics import FilterDynamics
    from .results import PredictedState

__all__ = ["BeaconMeasurement", "BeaconSighting", "FilterSetup", "FilterUpdate", "ImageProcessor", "ImageProcessorFactory",
           "ImageResult", "NavigationFilter", "NavigationFilterFactory"]


@dataclass(frozen=True, kw_only=True, eq=False)
class BeaconSighting:
    """One beacon (a planet, the Moon) looked for in one frame.

    Attributes
    ----------
    name : str
        Body name as in the ephemeris (``"mars"``, ``"jupiter"``, ...).
    xy_px : ndarray, shape (2,) or None
        The beacon's measured centroid, px (None: looked for, not found).
    xy_cov_px2 : ndarray, shape (2, 2) or None
        The covariance of ``xy_px``, px^2, when the processor has one.
    predicted_xy_px : ndarray, shape (2,) or None
        Where the processor predicted it, px (from the predicted state and the attitude).
    predicted_cov_px2 : ndarray, shape (2, 2) or None
        The covariance of that prediction, px^2 (the search ellipse).
    status : str
        ``"found"`` or ``"not_found"``.

    Examples
    --------
    >>> from skynav.pipeline import BeaconSighting
    >>> from skynav.scenes import paper_camera
    >>> cam = paper_camera()
    >>> b = BeaconSighting(name="mars", xy_px=np.array([cam.K[0, 2], cam.K[1, 2]]))
    >>> b.status, b.line_of_sight_cam(cam).round(6).tolist()
    ('found', [0.0, 0.0, 1.0])
    """

    name: str
    xy_px: np.ndarray | None
    xy_cov_px2: np.ndarray | None = None
    predicted_xy_px: np.ndarray | None = None
    predicted_cov_px2: np.ndarray | None = None
    status: str = "found"

    def __post_init__(self):
        for key, shape in (("xy_px", (2,)), ("xy_cov_px2", (2, 2)), ("predicted_xy_px", (2,)),
                           ("predicted_cov_px2", (2, 2))):
            v = getattr(self, key)
            if v is not None:
                a = np.array(v, dtype=float)
                if a.shape != shape:
                    raise ValueError(f"BeaconSighting.{key} has shape {a.shape}; expected {shape}")
                a.setflags(write=False)
                object.__setattr__(self, key, a)
        if self.status not in ("found", "not_found"):
            raise ValueError(f"BeaconSighting.status {self.status!r}: give 'found' or 'not_found'")

    def line_of_sight_cam(self, camera) -> np.ndarray | None:
        """The unit line of sight of ``xy_px`` in the camera frame (None when not found).

        Parameters
        ----------
        camera : skynav.scenes.camera.Camera
            The calibrated camera (the observation's).

        Returns
        -------
        ndarray, shape (3,) or None
        """
        if self.xy_px is None:
            return None
        return np.asarray(camera.line_of_sight(self.xy_px.reshape(1, 2)), dtype=float).reshape(3)


@dataclass(frozen=True, kw_only=True, eq=False)
class ImageResult:
    """What an image processor made of one frame; only ``R_cam_icrs`` is required.

    Attributes
    ----------
    R_cam_icrs : ndarray, shape (3, 3) or None
        The passive attitude, ``v_cam = R_cam_icrs @ v_icrs`` (None: not solved). The benchmark
        checks it (finite, (3, 3), a proper rotation) before it scores it.
    status : str
        ``"ok"`` when solved; otherwise the processor's own word for why not (``"no_stars"``,
        ``"id_failed"``, ...). Default: ``"ok"`` with an attitude, ``"unsolved"`` without.
    attitude_cov_rad2 : ndarray, shape (3, 3) or None
        Covariance of the small-angle attitude error in the camera frame, rad^2.
    centroids_xy_px : ndarray, shape (N, 2)
        The spots' centroids, px.
    matched_star_ids : ndarray, shape (M,), int
        Catalogue ids (HIP numbers for skynav) of the stars identified.
    matched_spot_index : ndarray, shape (M,), int
        Rows of ``centroids_xy_px`` matched to ``matched_star_ids``.
    beacons : tuple of BeaconSighting
        The beacons looked for.
    method : str
        How the stars were identified (``"lost_in_space"``, ``"tracking"``, ...), free text.
    error_estimate_arcsec : float
        The processor's own 1-sigma attitude error, arcsec (nan: none given).
    timings_ms : dict
        Wall time per stage, ms, as the processor measured it (the benchmark times the call
        itself).

    Examples
    --------
    >>> from skynav.pipeline import ImageResult
    >>> r = ImageResult(R_cam_icrs=None)
    >>> r.status, r.n_stars, r.centroids_xy_px.shape
    ('unsolved', 0, (0, 2))
    """

    R_cam_icrs: np.ndarray | None
    status: str = ""
    attitude_cov_rad2: np.ndarray | None = None
    centroids_xy_px: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    matched_star_ids: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))
    matched_spot_index: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))
    beacons: tuple = ()
    method: str = ""
    error_estimate_arcsec: float = float("nan")
    timings_ms: dict = field(default_factory=dict)

    def __post_init__(self):
        if not self.status:
            object.__setattr__(self, "status", "unsolved" if self.R_cam_icrs is None else "ok")
        object.__setattr__(self, "beacons", tuple(self.beacons))

    @property
    def solved(self) -> bool:
        """An attitude was returned (``R_cam_icrs`` is not None)."""
        return self.R_cam_icrs is not None

    @property
    def n_stars(self) -> int:
        """The number of stars identified (``len(matched_star_ids)``)."""
        return len(self.matched_star_ids)


@runtime_checkable
class ImageProcessor(Protocol):
    """Anyone's image processing: one frame and the on-board prediction in, an :class:`ImageResult` out.

    ``process`` should not raise for a bad image (say so in ``status``); when it raises anyway, or
    returns a matrix that is not a rotation, or runs past the benchmark's per-frame time limit,
    the benchmark counts the frame as failed with that reason and goes on.

    Examples
    --------
    Any object with such a ``process`` method is one (a structural type, no base class):

    >>> from skynav.pipeline import ImageProcessor, ImageResult
    >>> class Fixed:
    ...     def process(self, observation, prediction):
    ...         return ImageResult(R_cam_icrs=np.eye(3), method="fixed")
    >>> isinstance(Fixed(), ImageProcessor), isinstance(object(), ImageProcessor)
    (True, False)
    """

    def process(self, observation: Observation, prediction: PredictedState | None) -> ImageResult:
        """The result of one frame (``prediction`` None: lost in space)."""
        ...


class ImageProcessorFactory(Protocol):
    """``FACTORY(camera) -> ImageProcessor``: what ``--pipeline MODULE:FACTORY`` names.

    Called once per benchmark with the calibrated camera of the first frame
    (:class:`skynav.scenes.camera.Camera`), before any frame is processed: build catalogues and
    databases here, not in ``process``.
    """

    def __call__(self, camera) -> ImageProcessor:
        ...


# ----------------------------------------------------------------------------- navigation filters
# The contract a benchmarked navigation filter fulfils (``bench nav --filter MODULE:FACTORY``,
# ``bench loop --filter``): skynav's flight loop (:mod:`skynav.pipeline.flight`) calls it.


@dataclass(frozen=True, kw_only=True, eq=False)
class FilterSetup:
    """What a filter factory is given: the on-board ephemeris, the span it will be propagated over,
    skynav's force model and the measurement-model case (a filter may ignore what it does not use).

    Attributes
    ----------
    ephemeris : skynav.scenes.ephemeris_jpl.Ephemeris
        On-board ephemeris (``position(name, t_tdb_s)``, ``position_velocity``, ``gm_km3_s2`` ...).
    t_start_tdb_s, t_end_tdb_s : float
        The flight's first and last epochs, TDB s past J2000.
    case : int
        Light-effect case of the measurement model (Andreis et al. (2024), Sec. 5.2; 1..5).
    dynamics : skynav.pipeline.filter_dynamics.FilterDynamics
        skynav's force and process-noise model (Andreis et al. (2023b), Eqs. 1-7); ``bind`` it to
        the ephemeris over the span for its batched ``acceleration(t, r)``.
    """

    ephemeris: object
    t_start_tdb_s: float
    t_end_tdb_s: float
    case: int = 1
    dynamics: FilterDynamics


@dataclass(frozen=True, kw_only=True, eq=False)
class BeaconMeasurement:
    """One planet's centroid as the filter receives it: the pixel and the line of sight it gives.

    Attributes
    ----------
    t_tdb_s : float
        Epoch of the frame (mid-exposure), TDB s past J2000.
    body : str
        The planet (ephemeris name).
    xy_px : ndarray, shape (2,)
        The measured centroid, px (docs/conventions.md pixel convention).
    sigma_px : float
        Its noise per axis, px (1 sigma); ``xy_cov_px2 = sigma_px^2 I``.
    line_of_sight_icrs : ndarray, shape (3,)
        The observed (apparent: light-time delayed and aberrated) unit direction to the planet's
        centre of light, ICRS: ``R_cam_icrs.T @ camera.line_of_sight(xy_px)``.
    line_of_sight_cov_rad2 : ndarray, shape (3, 3)
        Its covariance, rad^2: ``xy_cov_px2`` through the camera's back projection (rank 2; the
        attitude's own error is not added: ``sigma_px`` is measured with the frame's attitude).
    R_cam_icrs : ndarray, shape (3, 3)
        The frame's attitude from the image processing (``v_cam = R_cam_icrs @ v_icrs``).
    camera : skynav.scenes.camera.Camera
        The calibrated camera.
    body_position_km, body_velocity_km_s : ndarray, shape (3,)
        The planet's geometric barycentric ICRS state at ``t_tdb_s`` (on-board ephemeris).
    sun_position_km : ndarray, shape (3,)
        The Sun's, for the photocentre.
    body_radius_km : float
        The planet's radius (0 when the benchmark models the planet's centre, ``--no-phase-offset``).
    photocentre : str
        ``"lambert"`` or ``"saturated"``: which centre of light the image shows
        (:func:`skynav.pipeline.measurement.planet_pixel`).
    """

    t_tdb_s: float
    body: str
    xy_px: np.ndarray
    sigma_px: float
    line_of_sight_icrs: np.ndarray
    line_of_sight_cov_rad2: np.ndarray
    R_cam_icrs: np.ndarray
    camera: object
    body_position_km: np.ndarray
    body_velocity_km_s: np.ndarray
    sun_position_km: np.ndarray
    body_radius_km: float
    photocentre: str = "lambert"

    @property
    def xy_cov_px2(self) -> np.ndarray:
        """Covariance of ``xy_px``, px^2, shape (2, 2)."""
        return np.eye(2) * self.sigma_px**2


@dataclass(frozen=True, kw_only=True, eq=False)
class FilterUpdate:
    """What :meth:`NavigationFilter.update` returns for the N runs.

    Attributes
    ----------
    accepted : ndarray of bool, shape (N,)
        The measurement corrected that run (False: rejected by the filter's own gate).
    residual_px : ndarray, shape (N, 2), optional
        Pre-fit innovation in px (NaN or None: the filter has none in px).
    """

    accepted: np.ndarray
    residual_px: np.ndarray | None = None


@runtime_checkable
class NavigationFilter(Protocol):
    """Anyone's navigation filter for N Monte Carlo runs that share epochs and measurements.

    State layout: ``x[:, :3]`` barycentric ICRS position (km), ``x[:, 3:6]`` velocity (km/s);
    further components are the filter's own (skynav's EKF: two Gauss-Markov accelerations, km/s^2).

    Examples
    --------
    >>> class Coast:          # propagates nothing, measures nothing
    ...     def initialise(self, t_tdb_s, x0, P0):
    ...         self.x, self.P = x0[:, :6].copy(), np.broadcast_to(P0[:6, :6], (len(x0), 6, 6)).copy()
    ...     def propagate(self, t_tdb_s):
    ...         pass
    ...     def update(self, measurement):
    ...         return FilterUpdate(accepted=np.zeros(len(self.x), bool))
    ...     def state(self):
    ...         return self.x, self.P
    >>> isinstance(Coast(), NavigationFilter)
    True
    """

    def initialise(self, t_tdb_s: float, x0: np.ndarray, P0: np.ndarray) -> None:
        """Start at ``t_tdb_s`` from ``x0`` (N, 12): position km, velocity km/s and two
        accelerations km/s^2 (Andreis et al. (2023b), Table 2), with covariance ``P0`` (12, 12).
        A filter with fewer states takes the leading block."""
        ...

    def propagate(self, t_tdb_s: float) -> None:
        """Propagate every run to the epoch ``t_tdb_s`` (TDB s past J2000)."""
        ...

    def update(self, measurement: BeaconMeasurement) -> FilterUpdate:
        """Correct every run with one planet's centroid."""
        ...

    def state(self) -> tuple[np.ndarray, np.ndarray]:
        """``(x (N, n), P (N, n, n))``, n >= 6, in the layout above."""
        ...


class NavigationFilterFactory(Protocol):
    """``FACTORY(setup) -> NavigationFilter``: what ``--filter MODULE:FACTORY`` names; called once
    per flight (per worker of a campaign) with a :class:`FilterSetup`."""

    def __call__(self, setup: FilterSetup) -> NavigationFilter:
        ...
