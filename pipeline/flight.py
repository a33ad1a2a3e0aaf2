"""The flight loop: one navigation step, written once, and the contract a navigation filter fulfils.

Core module (on-board knowledge only; never the truth). ``skynav bench nav`` (a dataset's frames),
the closed loop (``skynav bench loop``: frames asked of the render service) and the
measurement-noise calibration all fly through :class:`FlightComputer`:

1. propagate the filter to the frame's epoch;
2. predict: the runs' mean state, with the runs' mean covariance plus their spread, widened by the
   target's radius (the image processing predicts the planet's centre; its spot is the centre of
   light, up to 0.9 radius away, :func:`skynav.pipeline.measurement.lambert_photocentre_offset`);
3. process the frame (:func:`skynav.pipeline.process_frame`) with that prediction and the previous
   frame's attitude;
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

import importlib
import importlib.util
import os
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from skynav.infra.errors import SkynavError
from skynav.scenes.constants import SECONDS_PER_DAY
from skynav.scenes.ephemeris_jpl import BODY_RADII_KM

from .catalog import OnboardCatalog
from .ekf import NavFilter, initial_covariance
from .measurement import CASES
from .pairs import candidates_from_state, optimal_pair
from .planet_centroid import CentroidNoise, centroid_usable, diameter_px, target_beacon
from .process import process_frame
from .protocols import BeaconMeasurement, FilterSetup, FilterUpdate, NavigationFilter
from .results import PredictedState

__all__ = ["UPDATE_ITERATIONS", "DEFAULT_FILTER", "FilterPluginError", "FlightComputer", "FlightStep", "SkynavEKF",
           "Sighting", "initial_states", "load_filter_factory", "make_filter", "measure_target", "skynav_ekf"]

#: Iterated EKF update of skynav's filter: after the first 10-day propagation the position is known
#: to ~1e5 km only and the first Earth fix is nonlinear over that spread; with the one-step EKF 2 of
#: 6 runs (seed 3, synthetic centroids) were left 4 sigma off and then gated out every later
#: measurement (final error 4e6 km); 3 iterations keep them all (tests/pipeline/test_ekf_iterated.py).
UPDATE_ITERATIONS = 3

#: The filter ``--filter`` names by default: skynav's EKF, through the plug-in interface.
DEFAULT_FILTER = "skynav.pipeline.flight:skynav_ekf"


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
    :class:`FilterPluginError` in one line."""
    module, sep, name = str(spec).rpartition(":")
    if not sep or not module or not name.isidentifier():
        raise FilterPluginError(f"--filter {spec}: give MODULE:FACTORY or FILE.py:FACTORY, e.g. {DEFAULT_FILTER}")
    try:
        if module.endswith(".py"):
            mod = _module_of_file(spec, Path(module))
        else:
            if os.getcwd() not in sys.path and "" not in sys.path:
                sys.path.append(os.getcwd())   # a module in the current folder, as ``python -m`` finds it
            mod = importlib.import_module(module)
    except FilterPluginError:
        raise
    except BaseException as exc:   # noqa: BLE001 - anyone's module: any error is the user's to read in one line
        if isinstance(exc, KeyboardInterrupt):
            raise
        raise FilterPluginError(f"--filter {spec}: cannot import {module} ({type(exc).__name__}: {exc})") from None
    factory = getattr(mod, name, None)
    if not callable(factory):
        raise FilterPluginError(f"--filter {spec}: {module} has no callable {name}")
    return factory


def _module_of_file(spec: str, path: Path):
    """The module of a ``.py`` file, executed once per process (kept in ``sys.modules``)."""
    if not path.is_file():
        raise FilterPluginError(f"--filter {spec}: {path} is not a file")
    key = f"skynav_filter_{abs(hash(str(path.resolve())))}"
    if key not in sys.modules:
        loader = importlib.util.spec_from_file_location(key, path)
        mod = importlib.util.module_from_spec(loader)
        sys.modules[key] = mod
        try:
            loader.loader.exec_module(mod)
        except BaseException:
            del sys.modules[key]
            raise
    return sys.modules[key]


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
    """The image processing's view of one frame's target: the frame result, the target's beacon
    result (None: not found or no attitude) and how the filter may use it (None: not at all)."""

    frame: object
    beacon: object
    use: str | None


def measure_target(obs, target: str, *, t: float, predicted_state, previous_attitude, catalog, ephemeris) -> Sighting:
    """Process ``obs`` with ``predicted_state`` (None: lost in space, no beacon); the target's
    centroid and its photocentre law (:func:`~skynav.pipeline.planet_centroid.centroid_usable` at
    the predicted position)."""
    fr = process_frame(obs, catalog=catalog, predicted_state=predicted_state, previous_attitude=previous_attitude)
    b = target_beacon(fr, target)
    use = None if b is None or predicted_state is None else centroid_usable(obs, fr, b, target, t=t, position_km=predicted_state.position_km,
                                                 ephemeris=ephemeris)
    return Sighting(fr, b, use)


@dataclass(frozen=True, kw_only=True, eq=False)
class FlightStep:
    """What one frame's step did, for the N runs (the filter's state after it: :meth:`FlightComputer.estimate`).

    ``status``: the image processing's (``"blended"``: the centroid was found but not usable);
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
    """The flight software of one flight: a navigation filter, the image processing, the on-board
    catalogue and ephemeris, the measurement noise. Sees images, never the truth.

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
    """

    def __init__(self, nav, *, noise: CentroidNoise, ephemeris, track_frames: dict | None = None,
                 phase_offset: bool = True, catalog=None):
        self.nav, self.noise, self.eph = nav, noise, ephemeris
        self.track_frames = dict(track_frames or {})
        self.phase_offset = bool(phase_offset)
        self.catalog = catalog
        self.previous_attitude = None
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
        ``(observation, frame_result, photocentre, sigma_px) -> xy`` that replaces the centroid the filter is given
        (the benchmark's synthetic reference mode), or None.
        """
        t = float(obs.epoch_tdb_s)
        if self.catalog is None:
            self.catalog = OnboardCatalog.load(camera=obs.camera)
        c0 = time.perf_counter()
        ps = self.predicted_state(target)
        sight = measure_target(obs, target, t=t, predicted_state=ps, previous_attitude=self.previous_attitude,
                               catalog=self.catalog, ephemeris=self.eph)
        fr, b, use = sight.frame, sight.beacon, sight.use
        self.previous_attitude = fr.attitude.R_cam_icrs
        c1 = time.perf_counter()
        self.ip_time_s += c1 - c0
        status = "blended" if b is not None and use is None else fr.status
        residual = np.full((self.n_runs, 2), np.nan)
        accepted = np.zeros(self.n_runs, dtype=bool)
        xy = None if b is None else np.asarray(b.xy_px, dtype=float)
        meas = None
        if use is not None:
            meas = self._measurement(obs, fr, xy, target, use, ps.position_km, track, replace_xy)
            xy = meas.xy_px
            u = self._call("update", self.nav.update, meas)
            if u is not None:
                residual, accepted = self._outcome(u, residual, accepted)
        x, P, reasons = self.estimate()
        reasons = [self._faults[0] if self._faults else r for r in reasons]
        self.filter_time_s += time.perf_counter() - c1
        failed = np.array([bool(r) for r in reasons])
        return FlightStep(status=status, xy_px=xy, measurement=meas, residual_px=residual, accepted=accepted & ~failed,
                          fault=next((r for r in reasons if r), ""), failed=failed, attitude=fr.attitude.R_cam_icrs)

    def _measurement(self, obs, fr, xy, target, use, position_km, track, replace_xy) -> BeaconMeasurement:
        t = float(obs.epoch_tdb_s)
        rp, vp = self.eph.position_velocity(target, t)
        radius = BODY_RADII_KM[target]
        sigma_px = self.noise.sigma_px(diameter_px(radius, float(np.linalg.norm(rp - position_km)), obs.camera),
                                       f"{target}/{use}", self.track_frames.get(tuple(track), 1))
        if replace_xy is not None:
            xy = np.asarray(replace_xy(obs, fr, use, sigma_px), dtype=float)
        R = np.asarray(fr.attitude.R_cam_icrs, dtype=float)
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
