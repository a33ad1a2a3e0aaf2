"""Dynamics of the navigation filter (Andreis et al. (2023b), Eq. 1-7), batched over Monte Carlo runs.

Core module. State (12): ``x = (r, v, eta_R, eta_SRP)``, barycentric ICRS, km, km/s, km/s^2, with

    dr/dt = v
    dv/dt = a_bodies(r) + a_SRP(r) + eta_R + eta_SRP
    d eta_R / dt = -xi eta_R + w_R,   d eta_SRP / dt = -xi eta_SRP + w_SRP

- point masses: the Sun, the planets (system barycentres), the Earth and the Moon at their DE421
  positions, all that the on-board ephemeris carries (Andreis et al. (2023b) keeps the Earth-Moon barycentre,
  Mars and Jupiter: leaving Venus, Mercury and Saturn out is a 2e-11 km/s^2 model error, 6.6e-11
  at most, on the reference Earth-Mars cruise; with them the model differs from the truth's by
  the 1PN term only, 1.6e-13 km/s^2); barycentric frame, so no indirect terms;
- SRP: cannonball, inverse square from the Sun (``skynav.scenes.dynamics.SpacecraftSRP``);
- no 1PN term: the filter's model is lower-fidelity than the truth's (scenes.dynamics has it on);
  the Gauss-Markov (GM) accelerations absorb the difference, as in Andreis et al. (2024).

Process noise (Andreis et al. (2023b), Eq. 7), sized to the model error: the GM processes' steady-state sigma is
1e-11 km/s^2 per axis each (1.4e-11 for the two together), 16 % of the SRP acceleration at 1 au
(6.2e-11 km/s^2 for the sequence preset's 24 kg, 0.25 m^2, C_R 1.3 spacecraft: the SRP model
trusted to ~10-20 %) and 60 times the 1PN term the filter leaves out (the measured gap to the
truth's force model; the 5e-10 km/s^2 of Andreis et al. (2023b), Table 2, stays the GM states' INITIAL sigma,
:func:`skynav.pipeline.ekf.initial_covariance`). Checked by the consistency Monte Carlo over
independent renderings of the cruise held out of R's calibration (docs/navigation.md): with R
measured on six renderings and its track biases, 27 runs on 21 renderings give a mean NEES of 6.66
(95 % band about 4.5..7.5) and final 3-sigma sample/filter -1 % (position), -8 % (velocity).
5e-12 (the default for a day, chosen on 20 renderings) left the filter optimistic on held-out ones
(NEES 8.2-10.3, position 3-sigma 13-40 % above the filter's). With 5e-10 as steady state the GM
processes alone would wander the velocity by ~0.5 m/s per axis over each 10-day propagation,
above the campaign's 0.35 m/s 3-sigma target.
The GM driving noises have power spectral densities
``q_R = 2 xi sigma_R^2`` and ``q_SRP = 2 xi sigma_SRP^2`` (so ``sigma_*`` is the steady-state
standard deviation of each GM process), and the velocity gets ``q_a = (q_R + q_SRP) / (2 xi)``
(km^2/s^3 read as a PSD). Covariance: ``dP/dt = F P + P F^T + Q`` (Andreis et al. (2023b), Table 1) integrated with
the state by :func:`scipy.integrate.solve_ivp`.

Non-dimensional units (Andreis et al. (2024), Sec. 4.3, after Andreis et al.): the integration runs in
``LU = 1 au``, ``TU = sqrt(au^3 / GM_sun)`` (58.13 days), ``VU = LU / TU`` (29.78 km/s),
``ACU = LU / TU^2`` so that every state component and the covariance are O(1)-scaled and the
integrator's tolerances mean the same for all of them. Inputs and outputs stay dimensional.

The batch axis N carries the Monte Carlo runs: every run shares the body tables and is integrated
in one ``solve_ivp`` call (the runs differ only in their initial errors and measurements).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.integrate import solve_ivp

from skynav.scenes.constants import AU_KM, GM_KM3_S2, SECONDS_PER_DAY
from skynav.scenes.dynamics import BodyTable, SpacecraftSRP

__all__ = ["LU_KM", "TU_S", "VU_KM_S", "ACU_KM_S2", "FilterDynamics", "STATE_SIZE", "state_scale"]

LU_KM = AU_KM
TU_S = math.sqrt(AU_KM**3 / GM_KM3_S2["sun"])
VU_KM_S = LU_KM / TU_S
ACU_KM_S2 = LU_KM / TU_S**2
STATE_SIZE = 12


def state_scale() -> np.ndarray:
    """Dimensional value of one non-dimensional unit per state component, shape (12,)."""
    return np.array([LU_KM] * 3 + [VU_KM_S] * 3 + [ACU_KM_S2] * 6)


@dataclass(frozen=True, kw_only=True)
class FilterDynamics:
    """The filter's force and noise model.

    Attributes
    ----------
    bodies : tuple of str
        Point masses (ephemeris names); must include ``"sun"``.
    srp : SpacecraftSRP or None
        Cannonball solar radiation pressure (None: none).
    correlation_time_s : float
        ``1 / xi`` of the GM processes (Andreis et al. (2023b) does not list it; 10 days).
    sigma_residual_km_s2, sigma_srp_km_s2 : float
        Steady-state sigmas of the GM processes (1e-11 km/s^2 each: the model error, module notes;
        the 5e-10 km/s^2 of Andreis et al. (2023b), Table 2, is their initial sigma).
    rtol, atol : float
        Integrator tolerances (non-dimensional).

    References
    ----------
    Andreis et al. (2023b), Eqs. 1-7 and Table 2; Andreis et al. (2024), Sec. 4.3
    (non-dimensional units).

    Examples
    --------
    >>> from skynav.pipeline import FilterDynamics
    >>> model = FilterDynamics()
    >>> model.correlation_time_s / 86400.0   # days
    10.0
    >>> Q = model.process_noise_psd()
    >>> Q.shape, bool(np.isclose(Q[6, 6], 2 / model.correlation_time_s * 1e-22))
    ((12, 12), True)
    """

    bodies: tuple = ("sun", "mercury", "venus", "earth", "moon", "mars", "jupiter", "saturn", "uranus", "neptune")
    srp: SpacecraftSRP | None = field(default_factory=SpacecraftSRP)
    correlation_time_s: float = 10 * SECONDS_PER_DAY
    sigma_residual_km_s2: float = 1e-11
    sigma_srp_km_s2: float = 1e-11
    rtol: float = 1e-9
    atol: float = 1e-12

    def __post_init__(self):
        if "sun" not in self.bodies:
            raise ValueError("FilterDynamics.bodies must include 'sun'")
        if self.correlation_time_s <= 0:
            raise ValueError(f"correlation_time_s must be > 0, got {self.correlation_time_s}")

    @property
    def xi_per_s(self) -> float:
        """``xi = 1 / correlation_time_s``, 1/s."""
        return 1.0 / self.correlation_time_s

    def process_noise_psd(self) -> np.ndarray:
        """The process noise Q of Andreis et al. (2023b), Eq. 7.

        Returns
        -------
        numpy.ndarray, shape (12, 12)
            Diagonal power spectral densities: km^2/s^5 on the two Gauss-Markov accelerations
            (``2 xi sigma^2``), ``(q_R + q_SRP) / (2 xi)`` on the velocity (read as km^2/s^3:
            module notes), 0 on the position.
        """
        xi = self.xi_per_s
        q_r = 2.0 * xi * self.sigma_residual_km_s2**2
        q_s = 2.0 * xi * self.sigma_srp_km_s2**2
        q = np.zeros(STATE_SIZE)
        q[3:6] = (q_r + q_s) / (2.0 * xi)
        q[6:9] = q_r
        q[9:12] = q_s
        return np.diag(q)

    def bind(self, ephemeris, t0_tdb_s: float, t1_tdb_s: float, table_step_s: float = 10800.0) -> "BoundDynamics":
        """The model bound to body-state tables over a span.

        Parameters
        ----------
        ephemeris : Ephemeris
            Where the body states come from (``skynav.scenes.ephemeris_jpl``).
        t0_tdb_s, t1_tdb_s : float
            The span, TDB seconds past J2000.
        table_step_s : float
            Step of the body-state tables (cubic Hermite between), s.

        Returns
        -------
        BoundDynamics
            Batched derivative, Jacobian and propagation over the span (:class:`NavFilter`'s).
        """
        return BoundDynamics(self, BodyTable(ephemeris, self.bodies, t0_tdb_s, t1_tdb_s, table_step_s))


class BoundDynamics:
    """:class:`FilterDynamics` with body tables: batched derivative, Jacobian and propagation."""

    def __init__(self, model: FilterDynamics, table: BodyTable):
        self.model = model
        self.table = table
        self.gm = np.array([GM_KM3_S2[b] for b in model.bodies])
        self._i_sun = model.bodies.index("sun")
        self._k_srp = (model.srp.accel_1au_km_s2 * AU_KM * AU_KM) if model.srp is not None else 0.0
        s = state_scale()
        self._s = s
        self._q_nd = model.process_noise_psd() / np.outer(s, s) * TU_S

    def _check(self, t):
        lo, hi = self.table.span_tdb_s
        if not lo <= t <= hi:
            raise ValueError(f"epoch {t} TDB s outside the filter's body table [{lo}, {hi}]")

    def acceleration(self, t_tdb_s: float, r_km):
        """Gravity + SRP, shape (N, 3), km/s^2, for positions (N, 3) km."""
        self._check(t_tdb_s)
        pos = self.table.positions(t_tdb_s)
        d = r_km[:, None, :] - pos[None]                        # (N, B, 3)
        inv3 = np.sum(d * d, -1) ** -1.5                         # (N, B)
        a = -np.einsum("nb,nbi->ni", self.gm * inv3, d)
        if self._k_srp:
            rs = d[:, self._i_sun]
            a += self._k_srp * rs * inv3[:, self._i_sun, None]
        return a

    def jacobian(self, t_tdb_s: float, x):
        """F = df/dx, shape (N, 12, 12), dimensional, for states (N, 12)."""
        self._check(t_tdb_s)
        pos = self.table.positions(t_tdb_s)
        d = x[:, None, :3] - pos[None]
        dn2 = np.sum(d * d, -1)
        inv3 = dn2**-1.5
        inv5 = inv3 / dn2
        coef3 = -self.gm * inv3
        coef5 = 3.0 * self.gm * inv5
        if self._k_srp:
            coef3 = coef3.copy()
            coef5 = coef5.copy()
            coef3[:, self._i_sun] += self._k_srp * inv3[:, self._i_sun]
            coef5[:, self._i_sun] -= 3.0 * self._k_srp * inv5[:, self._i_sun]
        da_dr = np.sum(coef3, 1)[:, None, None] * np.eye(3) + np.einsum("nb,nbi,nbj->nij", coef5, d, d)
        n = x.shape[0]
        F = np.zeros((n, STATE_SIZE, STATE_SIZE))
        F[:, 0:3, 3:6] = np.eye(3)
        F[:, 3:6, 0:3] = da_dr
        F[:, 3:6, 6:9] = np.eye(3)
        F[:, 3:6, 9:12] = np.eye(3)
        F[:, 6:12, 6:12] = -self.model.xi_per_s * np.eye(6)
        return F

    def derivative(self, t_tdb_s: float, x):
        """f(x, t), shape (N, 12), dimensional."""
        out = np.empty_like(x)
        out[:, 0:3] = x[:, 3:6]
        out[:, 3:6] = self.acceleration(t_tdb_s, x[:, :3]) + x[:, 6:9] + x[:, 9:12]
        out[:, 6:12] = -self.model.xi_per_s * x[:, 6:12]
        return out

    def propagate(self, t0_tdb_s: float, t1_tdb_s: float, x, P=None):
        """Propagate states (N, 12) and covariances (N, 12, 12) from t0 to t1.

        Integrates ``dx/dt = f`` and ``dP/dt = F P + P F^T + Q`` together in non-dimensional
        units (module docstring). Returns ``(x1, P1)`` (``P1`` None when ``P`` is None).
        """
        x = np.atleast_2d(np.asarray(x, dtype=float))
        if t1_tdb_s == t0_tdb_s:
            return x.copy(), (None if P is None else np.array(P, dtype=float))
        n = x.shape[0]
        s = self._s
        xs = x / s
        with_p = P is not None
        y0 = xs.ravel()
        if with_p:
            Ps = np.asarray(P, dtype=float) / np.outer(s, s)
            y0 = np.concatenate([y0, Ps.ravel()])
        scale_F = s[None, :] / s[:, None] * TU_S     # F_nd[i, j] = F[i, j] s_j / s_i * TU
        t0 = t0_tdb_s

        def rhs(tau, y):
            t = t0 + tau * TU_S
            xd = y[: n * STATE_SIZE].reshape(n, STATE_SIZE) * s
            dx = self.derivative(t, xd) / s * TU_S
            if not with_p:
                return dx.ravel()
            Pn = y[n * STATE_SIZE:].reshape(n, STATE_SIZE, STATE_SIZE)
            F = self.jacobian(t, xd) * scale_F
            FP = F @ Pn
            dP = FP + FP.transpose(0, 2, 1) + self._q_nd
            return np.concatenate([dx.ravel(), dP.ravel()])

        sol = solve_ivp(rhs, (0.0, (t1_tdb_s - t0_tdb_s) / TU_S), y0, method="DOP853",
                        rtol=self.model.rtol, atol=self.model.atol)
        if not sol.success:
            raise RuntimeError(f"filter propagation failed: {sol.message}")
        y = sol.y[:, -1]
        x1 = y[: n * STATE_SIZE].reshape(n, STATE_SIZE) * s
        if not with_p:
            return x1, None
        P1 = y[n * STATE_SIZE:].reshape(n, STATE_SIZE, STATE_SIZE) * np.outer(s, s)
        P1 = 0.5 * (P1 + P1.transpose(0, 2, 1))
        return x1, P1
