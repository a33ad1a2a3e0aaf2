"""Extended Kalman filter on planet centroids (Andreis et al. (2023b), Table 1; Andreis et al. (2024), Sec. 4), batched over
Monte Carlo runs.

Core module. :class:`NavFilter` holds N filters (one per run) on the 12-state model of
:mod:`skynav.pipeline.filter_dynamics`:

- propagation: state and covariance together (``dP/dt = F P + P F^T + Q``), non-dimensional;
- correction: the planet-pixel model of :mod:`skynav.pipeline.measurement` (cases 1-5), Joseph
  form ``P = (I - K H) P (I - K H)^T + K R K^T`` (001 Table 1);
- optionally the iterated EKF update (``iterations > 1``: Gauss-Newton relinearisation of the
  measurement about the updated state; the benchmark uses 3);
- outlier rejection: a measurement whose innovation ``nu`` has ``sqrt(nu^T S^-1 nu) > k``
  (``k = 4`` by default) is rejected and the filter only propagates;
- when the image processing gives no centroid (no attitude, planet not found) the filter only
  propagates: the caller passes ``None`` for that run.

``R = sigma_px^2 I`` with ``sigma_px`` the measured planet-centroid error (the benchmark measures
it on the dataset's frames, see :mod:`skynav.pipeline.scoring_nav`); never a guess inside here.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .filter_dynamics import STATE_SIZE, BoundDynamics
from .measurement import CASES, LightCorrections, deaberrate_pixel, planet_pixel

__all__ = ["UpdateResult", "NavFilter", "initial_covariance"]


def initial_covariance(*, sigma_position_km: float = 1e4, sigma_velocity_km_s: float = 0.1,
                       sigma_residual_km_s2: float = 5e-10, sigma_srp_km_s2: float = 5e-10) -> np.ndarray:
    """Initial covariance P0 of the 12-state filter, diagonal.

    Parameters
    ----------
    sigma_position_km : float
        1-sigma of each position component, km.
    sigma_velocity_km_s : float
        1-sigma of each velocity component, km/s.
    sigma_residual_km_s2, sigma_srp_km_s2 : float
        1-sigma of each component of the two Gauss-Markov accelerations, km/s^2.

    Returns
    -------
    numpy.ndarray, shape (12, 12)
        ``diag(sigma^2)`` over ``(r, v, eta_R, eta_SRP)``: km^2, km^2/s^2, km^2/s^4.

    References
    ----------
    Andreis et al. (2023b), Table 2 (the defaults: 1e4 km, 0.1 km/s, 5e-10 km/s^2 twice).

    Examples
    --------
    >>> from skynav.pipeline import initial_covariance
    >>> P0 = initial_covariance(sigma_position_km=100.0)
    >>> P0.shape, np.sqrt(np.diag(P0))[[0, 3, 6, 9]].tolist()
    ((12, 12), [100.0, 0.1, 5e-10, 5e-10])
    """
    return np.diag([sigma_position_km**2] * 3 + [sigma_velocity_km_s**2] * 3
                   + [sigma_residual_km_s2**2] * 3 + [sigma_srp_km_s2**2] * 3)


@dataclass(frozen=True, kw_only=True, eq=False)
class UpdateResult:
    """Outcome of one correction for the N runs.

    Attributes
    ----------
    residual_px : ndarray, shape (N, 2)
        Pre-fit innovation ``z - h(x_p)`` (NaN where no measurement).
    nis : ndarray, shape (N,)
        Normalised innovation squared (NaN where no measurement).
    accepted : ndarray of bool, shape (N,)
    """

    residual_px: np.ndarray
    nis: np.ndarray
    accepted: np.ndarray


class NavFilter:
    """N extended Kalman filters sharing dynamics and epochs.

    The state of each run is ``x = (r, v, eta_R, eta_SRP)``: barycentric ICRS position (km),
    velocity (km/s) and two Gauss-Markov accelerations (km/s^2).

    Parameters
    ----------
    dynamics : BoundDynamics
        :meth:`FilterDynamics.bind` over the span of the filter.
    x0 : ndarray, shape (N, 12) or (12,)
        Initial states of the N runs.
    P0 : ndarray, shape (12, 12) or (N, 12, 12)
        Initial covariances (:func:`initial_covariance`).
    t0_tdb_s : float
        Epoch of ``x0``, TDB s past J2000.
    corrections : LightCorrections
        Measurement-model case (:data:`skynav.pipeline.measurement.CASES`).
    gate_k : float
        Innovation gate in sigmas.
    iterations : int
        1: the EKF update; n > 1: the iterated EKF, relinearising the measurement n - 1 times about
        the updated state (the gate is on the first innovation).

    References
    ----------
    Andreis et al. (2023b), Eqs. 1-7 and Table 2 (dynamics, noise, initial covariance);
    Andreis et al. (2024), Eqs. 26-42 (the planet measurement and its Jacobian).

    Examples
    --------
    One run from 5e6 km beside the Earth, propagated one hour:

    >>> from skynav.pipeline import FilterDynamics, NavFilter, initial_covariance
    >>> from skynav.scenes import default_ephemeris
    >>> eph = default_ephemeris()
    >>> r, v = eph.position_velocity("earth", 0.0)
    >>> nav = NavFilter(FilterDynamics().bind(eph, 0.0, 86400.0),
    ...                 np.concatenate([r + 5e6, v, np.zeros(6)]), initial_covariance(), 0.0)
    >>> nav.propagate(3600.0)
    >>> nav.x.shape, nav.P.shape, nav.t
    ((1, 12), (1, 12, 12), 3600.0)
    >>> bool(np.sqrt(nav.P[0, 0, 0]) > 1e4)   # the position sigma grows, km
    True
    """

    def __init__(self, dynamics: BoundDynamics, x0, P0, t0_tdb_s: float, *,
                 corrections: LightCorrections = CASES[1], gate_k: float = 4.0, iterations: int = 1):
        self.dynamics = dynamics
        self.x = np.atleast_2d(np.array(x0, dtype=float))
        n = self.x.shape[0]
        P0 = np.asarray(P0, dtype=float)
        self.P = np.broadcast_to(P0, (n, STATE_SIZE, STATE_SIZE)).copy()
        self.t = float(t0_tdb_s)
        self.corrections = corrections
        self.gate_k = float(gate_k)
        if int(iterations) < 1:
            raise ValueError(f"iterations must be >= 1, got {iterations}")
        self.iterations = int(iterations)

    @property
    def n_runs(self) -> int:
        """Number of runs N (the batch axis)."""
        return self.x.shape[0]

    def propagate(self, t_tdb_s: float) -> None:
        """Propagate every run's state and covariance to ``t_tdb_s`` (in place).

        Parameters
        ----------
        t_tdb_s : float
            The new epoch, TDB s past J2000, within the dynamics' span.
        """
        self.x, self.P = self.dynamics.propagate(self.t, t_tdb_s, self.x, self.P)
        self.t = float(t_tdb_s)

    def update(self, measured_xy_px, planet_position_km, planet_velocity_km_s, R_cam_icrs, camera,
               sigma_px: float, *, sun_position_km=None, planet_radius_km: float = 0.0,
               photocentre: str = "lambert") -> UpdateResult:
        """Correct every run with its planet centroid.

        Parameters
        ----------
        measured_xy_px : sequence of (ndarray (2,) or None), length N, or ndarray (N, 2) with NaN
            The centroid each run's image processing gave (None/NaN: propagate only).
        planet_position_km, planet_velocity_km_s : ndarray, shape (3,)
            On-board ephemeris of the planet at the epoch.
        R_cam_icrs : ndarray, shape (3, 3) or (N, 3, 3)
            Attitude from the image processing (per run or shared).
        camera : Camera
            Calibrated camera.
        sigma_px : float
            Measurement noise (1 sigma per axis), px.
        sun_position_km, planet_radius_km, photocentre : optional
            Aim the model at the planet's Lambert centre of light
            (:func:`skynav.pipeline.measurement.planet_pixel`).

        Returns
        -------
        UpdateResult
            Per run: the innovation (px), its normalised square, and whether the gate accepted
            it (the state and covariance are updated in place).

        References
        ----------
        Andreis et al. (2024), Eqs. 26-42 (the measurement model and its Jacobian).
        """
        n = self.n_runs
        R_all = np.broadcast_to(np.asarray(R_cam_icrs, dtype=float), (n, 3, 3))
        Rm = np.eye(2) * sigma_px**2
        residual = np.full((n, 2), np.nan)
        nis = np.full(n, np.nan)
        accepted = np.zeros(n, dtype=bool)
        eye = np.eye(STATE_SIZE)
        for i in range(n):
            z = measured_xy_px[i]
            if z is None:
                continue
            z = np.asarray(z, dtype=float)
            if not np.all(np.isfinite(z)):
                continue
            r, v = self.x[i, :3], self.x[i, 3:6]
            if self.corrections.deaberrate_measurement:
                z = deaberrate_pixel(z, v, R_all[i], camera)
            m = planet_pixel(r, v, planet_position_km, planet_velocity_km_s, R_all[i], camera,
                             corrections=self.corrections, sun_position_km=sun_position_km,
                             planet_radius_km=planet_radius_km, photocentre=photocentre)
            H = np.zeros((2, STATE_SIZE))
            H[:, :6] = m.H
            nu = z - m.xy_px
            P = self.P[i]
            PHt = P @ H.T
            S = H @ PHt + Rm
            Sinv = np.linalg.inv(S)
            d2 = float(nu @ Sinv @ nu)
            residual[i] = nu
            nis[i] = d2
            if not np.isfinite(d2) or d2 > self.gate_k**2:
                continue
            K = PHt @ Sinv
            xp = self.x[i].copy()
            xn = xp + K @ nu
            for _ in range(self.iterations - 1):
                # iterated EKF (Gauss-Newton on the MAP cost): relinearise h about the new estimate
                mj = planet_pixel(xn[:3], xn[3:6], planet_position_km, planet_velocity_km_s, R_all[i], camera,
                                  corrections=self.corrections, sun_position_km=sun_position_km,
                                  planet_radius_km=planet_radius_km, photocentre=photocentre)
                H = np.zeros((2, STATE_SIZE))
                H[:, :6] = mj.H
                PHt = P @ H.T
                K = PHt @ np.linalg.inv(H @ PHt + Rm)
                xn = xp + K @ (z - mj.xy_px - H @ (xp - xn))
            self.x[i] = xn
            IKH = eye - K @ H
            Pn = IKH @ P @ IKH.T + K @ Rm @ K.T
            self.P[i] = 0.5 * (Pn + Pn.T)
            accepted[i] = True
        return UpdateResult(residual_px=residual, nis=nis, accepted=accepted)
