"""The flight loop: one navigation step, written once, and the contract a navigation filter fulfils.

Core module (on-board knowledge only; never the truth). ``skynav bench nav`` (a dataset's frames),
the closed loop (``skynav bench loop``: frames asked of the render service) and the
measurement-noise calibration all fly through :class:`FlightComputer`:

1. propagate the filter to the frame's epoch;
2. predict: the runs' mean state, with the runs' mean covariance plus their spread, widened by the
   target's radius (the image processing predicts the planet's centre; its spot is the centre of
   light, up to 0.9 radius away, :func:`skynav.pipeline.measurement.lambert_photocentre_offset`);
3. process the frame with that prediction through the image processor
   (:class:`skynav.pipeline.protocols.ImageProcessor`, ``--pipeline MODULE:FACTORY``; by default
   skynav's pipeline, :func:`skynav.pipeline.process_frame`, given the previous frame's attitude);
   a fault of the processor is a failed measurement with its reason;
4. pick the pointed planet's centroid and decide whether it is usable
   (:func:`skynav.pipeline.planet_centroid.centroid_usable`) and with which photocentre law;
5. its noise ``sigma_px`` (:class:`~skynav.pipeline.planet_centroid.CentroidNoise`);
6. update the filter with a :class:`BeaconMeasurement`.

A navigation filter is anyone's: an object with ``initialise``, ``propagate``, ``update`` and
``state`` (:class:`skynav.pipeline.protocols.NavigationFilter`), made by a factory
``FACTORY(setup) -> NavigationFilter``
that ``--filter MODULE:FACTORY`` names. skynav's EKF is one through the same interface
(:func:`skynav_ekf`, the default). A filter holds the N Monte Carlo runs of a campaign at once
(they share the epochs and the frames; a filter of one run loops over them). A fault of the
filter (an exception, a non-finite state, a covariance that is not symmetric positive definite)
fails that step of those runs, with its reason (:attr:`FlightStep.fault`); the flight goes on.

The initial states are drawn once, here (:func:`initial_states`): Andreis et al. (2024), Eq. 45,
the nominal state plus ``sqrt(P0)`` times a standard normal draw, ``P0`` of Andreis et al.
(2023b), Table 2.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from skynav.infra.errors import SkynavError
from skynav.scenes.constants import SECONDS_PER_DAY
from skynav.scenes.ephemeris_jpl import BODY_RADII_KM

from .ekf import NavFilter, initial_covariance
from .measurement import CASES
from .pairs import candidates_from_state, optimal_pair
from .planet_centroid import CentroidNoise, centroid_usable, diameter_px, target_beacon
from .plugins import PluginError, call_processor, load_factory, load_image_processor
from .protocols import BeaconMeasurement, FilterSetup, FilterUpdate, ImageProcessor, ImageResult, NavigationFilter
from .results import PredictedState

__all__ = ["UPDATE_ITERATIONS", "DEFAULT_FILTER", "DEFAULT_PIPELINE", "FilterPluginError", "FlightComputer", "FlightStep",
           "SkynavEKF", "Sighting", "initial_states", "load_filter_factory", "make_filter", "measure_target",
           "pipeline_spec", "skynav_ekf"]

#: Iterated EKF update of skynav's filter: after the first 10-day propagation the position is known
#: to ~1e5 km only and the first Earth fix is nonlinear over that spread; with the one-step EKF 2 of
#: 6 runs (seed 3, synthetic centroids) were left 4 sigma off and then gated out every later
#: measurement (final error 4e6 km); 3 iterations keep them all (tests/pipeline/test_ekf_iterated.py).
UPDATE_ITERATIONS = 3

#: The filter ``--filter`` names by default: skynav's EKF, through the plug-in interface.
DEFAULT_FILTER = "skynav.pipeline.flight:skynav_ekf"

#: The image processor ``--pipeline`` names by default: skynav's pipeline, each solved attitude
#: passed to the next frame (:func:`skynav.pipeline.plugins.skynav_tracking`).
DEFAULT_PIPELINE = "skynav.pipeline.plugins:skynav_tracking"


class FilterPluginError(SkynavError, ValueError):
    """``--filter MODULE:FACTORY`` names nothing importable, or the factory gives no filter."""


class SkynavEKF:
    """skynav's extended Kalman filter (:class:`skynav.pipeline.ekf.NavFilter`) as a plug-in.

    Andreis et al. (2023b), Table 1 and Eqs. 1-7 (dynamics), Andreis et al. (2024), Eqs. 26-42
    (the planet-pixel measurement, the case's light corrections); the iterated update
    (:data:`UPDATE_ITERATIONS`) and the 4-sigma innovation gate.
    """

    def __init__(self, setup: FilterSetup, *, iterations: int = UPDATE_ITERATIONS, gate_k: float = 4.0):
        self.setup = setup
        self.iterations, self.gate_k = int(iterations), float(gate_k)
        self._dyn = setup.dynamics.bind(setup.ephemeris, setup.t_start_tdb_s - SECONDS_PER_DAY,
                                        setup.t_end_tdb_s + SECONDS_PER_DAY)
        self.kf = None

    def initialise(self, t_tdb_s, x0, P0):
        self.kf = NavFilter(self._dyn, x0, P0, t_tdb_s, corrections=CASES[self.setup.case],
                            iterations=self.iterations, gate_k=self.gate_k)

    def propagate(self, t_tdb_s):
        self.kf.propagate(t_tdb_s)

    def update(self, m: BeaconMeasurement) -> FilterUpdate:
        z = np.broadcast_to(m.xy_px, (self.kf.n_runs, 2))
        u = self.kf.update(z, m.body_position_km, m.body_velocity_km_s, m.R_cam_icrs, m.camera, m.sigma_px,
                           sun_position_km=m.sun_position_km, planet_radius_km=m.body_radius_km,
                           photocentre=m.photocentre)
        return FilterUpdate(accepted=u.accepted, residual_px=u.residual_px)

    def state(self):
        return self.kf.x, self.kf.P


def skynav_ekf(setup: FilterSetup) -> SkynavEKF:
    """The factory of skynav's EKF (:data:`DEFAULT_FILTER`)."""
    return SkynavEKF(setup)


def load_filter_factory(spec: str):
    """The factory ``MODULE:FACTORY`` or ``path/to/file.py:FACTORY`` names (a callable), or
    :class:`FilterPluginError` in one line (the plug-in loader, :func:`skynav.pipeline.plugins.load_factory`)."""
    return load_factory(spec, option="--filter", error=FilterPluginError, shortcuts={}, example=DEFAULT_FILTER,
                        makes="setup -> filter")


def pipeline_spec(given) -> str:
    """The one image processor of a flight from the ``--pipeline`` values (None or ``"skynav"``:
    :data:`DEFAULT_PIPELINE`), imported now so that a bad path is one line before any frame is read.

    Raises
    ------
    PluginError
        More than one processor (a flight has one image processing; compare processors with
        ``skynav bench ip``), or a bad import path.
    """
    specs = list(dict.fromkeys(given or ["skynav"]))
    if len(specs) > 1:
        raise PluginError(f"--pipeline {' '.join(specs)}: a flight has one image processor; give --pipeline once "
                          "(compare image processors side by side with 'skynav bench ip')")
    spec = DEFAULT_PIPELINE if specs[0] == "skynav" else specs[0]
    load_factory(spec)
    return spec


def make_filter(spec: str, setup: FilterSetup) -> NavigationFilter:
    """The filter of ``spec`` (``MODULE:FACTORY``) built for ``setup``."""
    try:
        nav = load_filter_factory(spec)(setup)
    except FilterPluginError:
        raise
    except Exception as exc:   # noqa: BLE001
        raise FilterPluginError(f"--filter {spec}: the factory failed ({type(exc).__name__}: {exc})") from None
    missing = [m for m in ("initialise", "propagate", "update", "state") if not callable(getattr(nav, m, None))]
    if missing:
        raise FilterPluginError(f"--filter {spec}: the factory's {type(nav).__name__} has no {', '.join(missing)} "
                                "(a filter has initialise, propagate, update, state)")
    return nav


def initial_states(position_km, velocity_km_s, runs: int, seed: int, P0=None):
    """The Monte Carlo initial states ``(x0 (runs, 12), P0 (12, 12))``: the nominal state plus
    ``sqrt(diag P0)`` times a standard normal draw (Andreis et al. (2024), Eq. 45; ``P0`` of Andreis
    et al. (2023b), Table 2, by default), from ``SeedSequence([seed, 45])``."""
    P0 = initial_covariance() if P0 is None else np.asarray(P0, dtype=float)
    rng = np.random.default_rng(np.random.SeedSequence([seed, 45]))
    nominal = np.concatenate([np.asarray(position_km, float), np.asarray(velocity_km_s, float), np.zeros(6)])
    return nominal + rng.standard_normal((int(runs), 12)) * np.sqrt(np.diag(P0)), P0


@dataclass(frozen=True, eq=False)
class Sighting:
    """The image processing's view of one frame's target: the processor's result (None: it
    faulted), the target's beacon (None: not found or no attitude), how the filter may use it
    (None: not at all) and the processor's fault (``""``: none; else its kind and reason)."""

    result: ImageResult | None
    beacon: object
    use: str | None
    fault: str = ""

    @property
    def R_cam_icrs(self):
        """The frame's attitude (None: not solved, or the processor faulted)."""
        return None if self.result is None else self.result.R_cam_icrs


def measure_target(obs, target: str, *, t: float, predicted_state, processor: ImageProcessor, ephemeris,
                   timeout_s: float | None = None) -> Sighting:
    """Process ``obs`` with ``processor`` (:func:`skynav.pipeline.plugins.call_processor`: its faults
    are a :attr:`Sighting.fault`, never an exception) and ``predicted_state`` (None: lost in space,
    no beacon); the target's centroid and its photocentre law
    (:func:`~skynav.pipeline.planet_centroid.centroid_usable` at the predicted position)."""
    result, fault, _ = call_processor(processor, obs, predicted_state, timeout_s=timeout_s)
    if fault is not None:
        return Sighting(None, None, None, str(fault))
    b = target_beacon(result, target)
    use = None if b is None or predicted_state is None else centroid_usable(
        obs, result, b, target, t=t, position_km=predicted_state.position_km, ephemeris=ephemeris)
    return Sighting(result, b, use)


@dataclass(frozen=True, kw_only=True, eq=False)
class FlightStep:
    """What one frame's step did, for the N runs (the filter's state after it: :meth:`FlightComputer.estimate`).

    ``status``: the image processing's (``"blended"``: the centroid was found but not usable;
    ``"processor fault (KIND: REASON)"``: the processor raised, returned no rotation or ran past
    the frame time limit: no measurement, the flight goes on);
    ``xy_px``: the target's centroid (None: not found); ``measurement``: what the filter was given
    (None: nothing, it only propagated); ``fault``: the filter's fault in this step, with its
    reason (``""``: none), ``failed`` (N,) the runs it hit.
    """

    status: str
    xy_px: np.ndarray | None
    measurement: BeaconMeasurement | None
    residual_px: np.ndarray
    accepted: np.ndarray
    fault: str
    failed: np.ndarray
    attitude: np.ndarray | None = None


def _line_of_sight(xy_px, sigma_px: float, R_cam_icrs, camera):
    """The ICRS unit line of sight of a pixel and its covariance (rad^2), by central differences
    of the camera's back projection over 0.5 px (its curvature over that step: ~1e-7 relative)."""
    xy = np.asarray(xy_px, dtype=float)
    h = 0.5
    pts = np.array([xy, xy + (h, 0.0), xy - (h, 0.0), xy + (0.0, h), xy - (0.0, h)])
    u = np.asarray(camera.line_of_sight(pts), dtype=float)
    J = np.column_stack([(u[1] - u[2]) / (2 * h), (u[3] - u[4]) / (2 * h)])    # (3, 2) per px
    R = np.asarray(R_cam_icrs, dtype=float)
    Ji = R.T @ J
    return R.T @ u[0], sigma_px**2 * (Ji @ Ji.T)


def _fault_check(x, P, n_runs):
    """Per run: ``""`` or why the state is unusable (shape, non-finite, covariance not symmetric
    positive definite). All runs at once; one run at a time only to name the bad ones."""
    x, P = np.asarray(x), np.asarray(P)
    if x.ndim != 2 or x.shape[0] != n_runs or x.shape[1] < 6 or P.shape != (n_runs, x.shape[1], x.shape[1]):
        return [f"state of shape {x.shape}, covariance {P.shape}; expected (N, n >= 6), (N, n, n)"] * n_runs
    finite = np.all(np.isfinite(x), 1) & np.all(np.isfinite(P), (1, 2))
    scale = np.maximum(np.abs(P).max((1, 2), initial=0.0), 1e-300)
    with np.errstate(invalid="ignore"):
        symmetric = np.abs(P - np.swapaxes(P, 1, 2)).max((1, 2), initial=0.0) <= 1e-6 * scale
    if finite.all() and symmetric.all():
        try:
            np.linalg.cholesky(P)
            return [""] * n_runs
        except np.linalg.LinAlgError:
            pass
    out = []
    for Pi, fin, sym in zip(P, finite, symmetric):
        if not fin:
            out.append("non-finite state or covariance")
        elif not sym:
            out.append("covariance not symmetric")
        else:
            try:
                np.linalg.cholesky(Pi)
                out.append("")
            except np.linalg.LinAlgError:
                out.append("covariance not positive definite")
    return out


class FlightComputer:
    """The flight software of one flight: a navigation filter, an image processor, the on-board
    ephemeris, the measurement noise. Sees images, never the truth.

    Parameters
    ----------
    nav : NavigationFilter
        The filter (:func:`make_filter`), not yet initialised (:meth:`start`).
    noise : CentroidNoise
        The filter's measurement noise.
    ephemeris : skynav.scenes.ephemeris_jpl.Ephemeris
        On-board ephemeris.
    track_frames : dict, optional
        Frames per ``(leg, phase)`` of the commanded observation plan (a class of measurement with
        a track-constant error gets ``n sigma_b^2``, :meth:`CentroidNoise.sigma_px`).
    phase_offset : bool
        Aim the measurement at the planet's centre of light (default) or at its centre.
    processor : ImageProcessor, optional
        The image processing (:class:`skynav.pipeline.protocols.ImageProcessor`); default: the one
        ``pipeline`` names, made with the first frame's calibrated camera.
    pipeline : str
        ``MODULE:FACTORY`` of the image processor when ``processor`` is None (default
        :data:`DEFAULT_PIPELINE`, skynav's pipeline).
    frame_timeout_s : float, optional
        The processor's time limit per frame (None: none); a frame over it is a failed measurement.
    """

    def __init__(self, nav, *, noise: CentroidNoise, ephemeris, track_frames: dict | None = None,
                 phase_offset: bool = True, processor: ImageProcessor | None = None, pipeline: str = DEFAULT_PIPELINE,
                 frame_timeout_s: float | None = None):
        self.nav, self.noise, self.eph = nav, noise, ephemeris
        self.track_frames = dict(track_frames or {})
        self.phase_offset = bool(phase_offset)
        self.processor, self.pipeline, self.frame_timeout_s = processor, pipeline, frame_timeout_s
        self.n_runs = 0
        self.ip_time_s = self.filter_time_s = 0.0
        self._faults: list = []
        self._estimate = None

    # ---- the filter's calls, each guarded: a fault is a result of the step, not a crash
    def _call(self, what: str, fn, *args):
        if what != "state":
            self._estimate = None    # the filter may change: its state is read (and checked) again
        try:
            return fn(*args)
        except Exception as exc:   # noqa: BLE001 - anyone's filter: any exception fails the step
            self._faults.append(f"{what} raised {type(exc).__name__}: {exc}".splitlines()[0][:200])
            return None

    def start(self, t_tdb_s: float, x0, P0) -> None:
        """Initialise the filter with the runs' initial states ``x0`` (N, 12) and ``P0`` (12, 12)."""
        x0 = np.atleast_2d(np.asarray(x0, dtype=float))
        self.n_runs = x0.shape[0]
        self._faults = []
        c0 = time.perf_counter()
        self._call("initialise", self.nav.initialise, float(t_tdb_s), x0.copy(), np.array(P0, dtype=float))
        self.filter_time_s += time.perf_counter() - c0

    def propagate(self, t_tdb_s: float) -> None:
        """Begin the step of the frame at ``t_tdb_s``: propagate the filter there."""
        self._faults = []
        c0 = time.perf_counter()
        self._call("propagate", self.nav.propagate, float(t_tdb_s))
        self.filter_time_s += time.perf_counter() - c0

    def estimate(self):
        """The filter's ``(x (N, n), P (N, n, n), reasons)``: per run ``""`` or why its state is
        unusable (its x and P are then NaN). Read once between two calls that may change the filter."""
        if self._estimate is None:
            self._estimate = self._read_estimate()
        return self._estimate

    def _read_estimate(self):
        got = self._call("state", self.nav.state)
        if got is None:
            reasons = [self._faults[-1]] * self.n_runs
            return np.full((self.n_runs, 6), np.nan), np.full((self.n_runs, 6, 6), np.nan), reasons
        try:
            x, P = (np.asarray(a, dtype=float) for a in got)
        except (TypeError, ValueError) as exc:
            return (np.full((self.n_runs, 6), np.nan), np.full((self.n_runs, 6, 6), np.nan),
                    [f"state() gave no (x, P) of numbers ({exc})"] * self.n_runs)
        reasons = _fault_check(x, P, self.n_runs)
        if any(reasons):
            bad = np.array([bool(r) for r in reasons])
            if x.ndim != 2 or P.ndim != 3 or x.shape[0] != self.n_runs:
                return np.full((self.n_runs, 6), np.nan), np.full((self.n_runs, 6, 6), np.nan), reasons
            x, P = x.copy(), P.copy()
            x[bad], P[bad] = np.nan, np.nan
        return x, P, reasons

    def predicted_state(self, target: str):
        """The image processing's prediction: the healthy runs' mean, their mean covariance plus
        their spread, widened by the target's radius (module docstring); None when no run is."""
        x, P, reasons = self.estimate()
        ok = np.array([not r for r in reasons])
        if not ok.any():
            return None
        xs, Ps = x[ok], P[ok]
        mean = xs.mean(0)
        spread = np.cov(xs[:, :3].T) if len(xs) > 1 else np.zeros((3, 3))
        radius = BODY_RADII_KM.get(target, 0.0)
        return PredictedState(position_km=mean[:3], velocity_km_s=mean[3:6],
                              position_cov_km2=Ps[:, :3, :3].mean(0) + spread + radius**2 * np.eye(3))

    def choose_pair(self, t_tdb_s: float):
        """The optimal beacon pair seen from the runs' mean estimate (Andreis et al. (2024), Sec. 3), or None."""
        x, _, reasons = self.estimate()
        ok = np.array([not r for r in reasons])
        if not ok.any():
            return None
        mean = x[ok].mean(0)
        choice = optimal_pair(candidates_from_state(t_tdb_s, mean[:3], mean[3:6], ephemeris=self.eph))
        return None if choice is None else (choice.first, choice.second)

    def step(self, obs, target: str, *, track: tuple = (), replace_xy=None) -> FlightStep:
        """Finish the frame's step (after :meth:`propagate` to its epoch): predict, process the
        image, pick the target's centroid, its sigma, update the filter.

        ``track``: the frame's ``(leg, phase)`` in the observation plan. ``replace_xy``: a callable
        ``(observation, image_result, photocentre, sigma_px) -> xy`` that replaces the centroid the filter is given
        (the benchmark's synthetic reference mode), or None.
        """
        t = float(obs.epoch_tdb_s)
        if self.processor is None:
            self.processor = load_image_processor(self.pipeline, obs.camera)
        c0 = time.perf_counter()
        ps = self.predicted_state(target)
        sight = measure_target(obs, target, t=t, predicted_state=ps, processor=self.processor, ephemeris=self.eph,
                               timeout_s=self.frame_timeout_s)
        res, b, use = sight.result, sight.beacon, sight.use
        c1 = time.perf_counter()
        self.ip_time_s += c1 - c0
        if sight.fault:
            status = f"processor fault ({sight.fault})"
        else:
            status = "blended" if b is not None and use is None else res.status
        residual = np.full((self.n_runs, 2), np.nan)
        accepted = np.zeros(self.n_runs, dtype=bool)
        xy = None if b is None else np.asarray(b.xy_px, dtype=float)
        meas = None
        if use is not None:
            meas = self._measurement(obs, res, xy, target, use, ps.position_km, track, replace_xy)
            xy = meas.xy_px
            u = self._call("update", self.nav.update, meas)
            if u is not None:
                residual, accepted = self._outcome(u, residual, accepted)
        x, P, reasons = self.estimate()
        reasons = [self._faults[0] if self._faults else r for r in reasons]
        self.filter_time_s += time.perf_counter() - c1
        failed = np.array([bool(r) for r in reasons])
        return FlightStep(status=status, xy_px=xy, measurement=meas, residual_px=residual, accepted=accepted & ~failed,
                          fault=next((r for r in reasons if r), ""), failed=failed, attitude=sight.R_cam_icrs)

    def _measurement(self, obs, res, xy, target, use, position_km, track, replace_xy) -> BeaconMeasurement:
        t = float(obs.epoch_tdb_s)
        rp, vp = self.eph.position_velocity(target, t)
        radius = BODY_RADII_KM[target]
        sigma_px = self.noise.sigma_px(diameter_px(radius, float(np.linalg.norm(rp - position_km)), obs.camera),
                                       f"{target}/{use}", self.track_frames.get(tuple(track), 1))
        if replace_xy is not None:
            xy = np.asarray(replace_xy(obs, res, use, sigma_px), dtype=float)
        R = np.asarray(res.R_cam_icrs, dtype=float)
        los, los_cov = _line_of_sight(xy, sigma_px, R, obs.camera)
        return BeaconMeasurement(t_tdb_s=t, body=target, xy_px=xy, sigma_px=float(sigma_px), line_of_sight_icrs=los,
                                 line_of_sight_cov_rad2=los_cov, R_cam_icrs=R, camera=obs.camera, body_position_km=rp,
                                 body_velocity_km_s=vp, sun_position_km=self.eph.position("sun", t),
                                 body_radius_km=radius if self.phase_offset else 0.0, photocentre=use)

    def _outcome(self, u, residual, accepted):
        """The update's (residual (N, 2), accepted (N,)), or a fault when it is not of that shape."""
        try:
            acc = np.asarray(getattr(u, "accepted"), dtype=bool).reshape(self.n_runs)
            res = getattr(u, "residual_px", None)
            res = residual if res is None else np.asarray(res, dtype=float).reshape(self.n_runs, 2)
        except (AttributeError, TypeError, ValueError) as exc:
            self._faults.append(f"update gave no accepted (N,) and residual_px (N, 2) ({type(exc).__name__}: {exc})"[:200])
            return residual, accepted
        return res, acc
