"""High-fidelity ballistic propagation of a spacecraft in the solar system, with the state
transition matrix and the Jacobians an extended Kalman filter needs.

Core + one adapter use: the ephemeris is passed in (an object with
``position_velocity(body, t_tdb_s)`` such as :func:`skynav.scenes.ephemeris_jpl.default_ephemeris`).

Force model, barycentric ICRS (an inertial frame, so no indirect terms), state ``x = (r, v)`` in km
and km/s, time in TDB seconds past J2000, ``dx/dt = f(x, t) = (v, a(r, v, t))``:

- Newtonian point masses: the Sun, Mercury, Venus, Earth, Moon, Mars (system), Jupiter, Saturn,
  Uranus and Neptune (system barycentres) at their DE421 positions, with the DE421 mass
  parameters (:data:`skynav.scenes.constants.GM_KM3_S2`);
- solar radiation pressure, cannonball model (Andreis et al. (2023b), Eq. 5; Andreis et al. (2024), Eq. 3):
  ``a = C_R P_1AU (1 AU / r)^2 (A / m) r_hat``, ``P_1AU = 1361 W m^-2 / c``, ``r`` from the Sun;
- the post-Newtonian (1PN) correction of a Schwarzschild Sun (PPN beta = gamma = 1; Moyer 2003,
  JPL DESCANSO monograph 2, Eq. 4-61, reduced to one central mass):
  ``a = GM / (c^2 r^3) [ (4 GM / r - v^2) r + 4 (r . v) v ]`` with heliocentric ``r, v``.

Integration: :func:`scipy.integrate.solve_ivp` with DOP853 at tight tolerances (relative 1e-12,
absolute 1e-6 km / 1e-12 km/s by default), dense output kept for the frames' epochs.

To keep the right-hand side cheap (a DE421 lookup per body and step would dominate), body states are read
once on a regular grid (``table_step_s``, 3 h by default) and interpolated with a cubic Hermite
spline on positions AND velocities; the interpolation error is below 10 m for every body at 3 h
(tested against direct DE421 reads), which is far below anything that matters for a navigation
camera and does not depend on the spacecraft.

Filter support: :func:`acceleration_jacobian` and :meth:`ForceField.jacobian` give the analytic
``A(x, t) = df/dx`` (6 x 6); :func:`propagate_stm` integrates the variational equations
``dPhi/dt = A(x(t), t) Phi``, ``Phi(t0, t0) = I``, alongside the state.

Differences from the filter dynamics of Andreis et al. (2023b), Eq. 1-7:

- frame: the paper integrates heliocentric ``r`` with the Sun as central body (Eq. 4) and the
  planets' third-body terms with their indirect part (Eq. 6); here the origin is the solar-system
  barycentre and every body, the Sun included, is a direct point-mass term (no indirect terms in
  an inertial frame). The two are the same physics in different frames.
- bodies: the paper keeps the Earth-Moon barycentre, Mars and Jupiter; here the Moon and Earth are
  separate and all eight planets are in.
- SRP: the paper's Eq. 5 writes ``C_R P_0 R_0^2 A_s / (c m_s) r / r^3`` with the solar power at the
  Sun's surface; here the same inverse-square law is scaled at 1 au by the solar constant (equal
  when ``P_0 R_0^2 = S_1au (1 au)^2``).
- 1PN: the paper has none; here the Sun's Schwarzschild term is on by default (about 8 km over
  100 days in cruise; switch it off with ``ForceModel(relativity=False)``).
- state: the paper appends six Gauss-Markov accelerations ``eta = (eta_R, eta_SRP)`` with
  ``d eta/dt = -xi eta + w`` (Eq. 1, 3) and process noise (Eq. 7); they belong to the filter, which
  extends ``A`` by ``[[0, 0], [I, I], [-xi I, 0], [0, -xi I]]`` blocks; this module is the
  deterministic ``(r, v)`` part that the filter builds on.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.integrate import solve_ivp
from scipy.interpolate import CubicHermiteSpline

from .constants import AU_KM, C_KM_S, GM_KM3_S2, SOLAR_CONSTANT_W_M2

__all__ = [
    "SpacecraftSRP",
    "ForceModel",
    "BodyTable",
    "ForceField",
    "Trajectory",
    "StmTrajectory",
    "acceleration",
    "acceleration_jacobian",
    "propagate",
    "propagate_stm",
]


@dataclass(frozen=True, kw_only=True)
class SpacecraftSRP:
    """Cannonball solar-radiation-pressure parameters.

    Defaults: a 12U CubeSat with deployed panels, ``m = 24 kg``, ``A = 0.25 m^2``, ``C_R = 1.3``
    (Andreis et al. (2023b) and Andreis et al. (2024) do not list their values).
    """

    mass_kg: float = 24.0
    area_m2: float = 0.25
    reflectivity_coefficient: float = 1.3

    @property
    def accel_1au_km_s2(self) -> float:
        """SRP acceleration at 1 AU, km/s^2."""
        p_n_m2 = SOLAR_CONSTANT_W_M2 / (C_KM_S * 1e3)
        return self.reflectivity_coefficient * p_n_m2 * self.area_m2 / self.mass_kg * 1e-3


@dataclass(frozen=True, kw_only=True)
class ForceModel:
    """Which accelerations act on the spacecraft (the module's docstring has the equations).

    Parameters
    ----------
    bodies : tuple of str
        Point masses, names of :data:`skynav.scenes.constants.GM_KM3_S2` (all ten by default);
        must include ``"sun"`` when SRP or 1PN is on.
    srp : SpacecraftSRP or None
        Solar radiation pressure (cannonball), None for none.
    relativity : bool
        The Sun's 1PN (Schwarzschild) term.

    References
    ----------
    Andreis et al. (2023b), Eqs. 1-7 and Andreis et al. (2024), Eq. 3 (the filter's dynamics,
    and how this model differs from them: module docstring); Moyer, T. D. (2003), JPL
    DESCANSO monograph 2, Eq. 4-61 (1PN).

    Examples
    --------
    Sun-only two-body motion:

    >>> from skynav.scenes import ForceModel
    >>> ForceModel(bodies=("sun",), srp=None, relativity=False)
    ForceModel(bodies=('sun',), srp=None, relativity=False)
    """

    bodies: tuple = tuple(GM_KM3_S2)
    srp: SpacecraftSRP | None = field(default_factory=SpacecraftSRP)
    relativity: bool = True


class BodyTable:
    """Body states on a grid, interpolated by a cubic Hermite spline (positions and velocities).

    Parameters
    ----------
    ephemeris : object
        Has ``position_velocity(body, t_tdb_s)`` returning km, km/s arrays of shape (N, 3).
    bodies : sequence of str
    t0_tdb_s, t1_tdb_s : float
        Span to cover (a margin of two steps is added on both sides).
    step_s : float
        Grid step, s.
    """

    def __init__(self, ephemeris, bodies, t0_tdb_s: float, t1_tdb_s: float, step_s: float = 10800.0):
        lo, hi = min(t0_tdb_s, t1_tdb_s) - 2 * step_s, max(t0_tdb_s, t1_tdb_s) + 2 * step_s
        n = int(math.ceil((hi - lo) / step_s)) + 1
        t = lo + step_s * np.arange(n)
        self.bodies = tuple(bodies)
        self.span_tdb_s = (float(t[0]), float(t[-1]))
        pos = np.empty((n, len(self.bodies), 3))
        vel = np.empty_like(pos)
        for j, b in enumerate(self.bodies):
            pos[:, j], vel[:, j] = ephemeris.position_velocity(b, t)
        self._spline = CubicHermiteSpline(t, pos.reshape(n, -1), vel.reshape(n, -1))
        self._dspline = self._spline.derivative()

    def positions(self, t_tdb_s: float) -> np.ndarray:
        """Positions, shape (B, 3), km (B = number of bodies)."""
        return self._spline(t_tdb_s).reshape(len(self.bodies), 3)

    def velocities(self, t_tdb_s: float) -> np.ndarray:
        """Velocities, shape (B, 3), km/s."""
        return self._dspline(t_tdb_s).reshape(len(self.bodies), 3)


def acceleration(r_km, v_km_s, body_pos_km, body_gm, sun_pos_km=None, sun_vel_km_s=None, *,
                 srp_accel_1au_km_s2: float = 0.0, relativity: bool = False) -> np.ndarray:
    """Acceleration of the spacecraft, km/s^2 (see the module docstring for the model).

    Parameters
    ----------
    r_km, v_km_s : ndarray, shape (3,)
        Barycentric ICRS state of the spacecraft.
    body_pos_km : ndarray, shape (B, 3)
        Barycentric positions of the attracting bodies.
    body_gm : ndarray, shape (B,)
        Their mass parameters, km^3/s^2.
    sun_pos_km, sun_vel_km_s : ndarray, shape (3,), optional
        The Sun's barycentric state (needed for SRP and the 1PN term).
    srp_accel_1au_km_s2 : float
        SRP acceleration at 1 AU (0 turns it off).
    relativity : bool
        Add the 1PN Schwarzschild term of the Sun.
    """
    d = r_km - body_pos_km
    inv3 = np.sum(d * d, axis=1) ** -1.5
    a = -(body_gm * inv3) @ d
    if sun_pos_km is not None and (srp_accel_1au_km_s2 or relativity):
        rs = r_km - sun_pos_km
        rn2 = float(rs @ rs)
        rn = math.sqrt(rn2)
        if srp_accel_1au_km_s2:
            a = a + srp_accel_1au_km_s2 * (AU_KM * AU_KM / rn2) * (rs / rn)
        if relativity:
            vs = v_km_s - sun_vel_km_s
            gm = GM_KM3_S2["sun"]
            a = a + gm / (C_KM_S**2 * rn2 * rn) * ((4.0 * gm / rn - float(vs @ vs)) * rs + 4.0 * float(rs @ vs) * vs)
    return a


def acceleration_jacobian(r_km, v_km_s, body_pos_km, body_gm, sun_pos_km=None, sun_vel_km_s=None, *,
                          srp_accel_1au_km_s2: float = 0.0, relativity: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Partial derivatives of :func:`acceleration` with respect to the spacecraft's state.

    Same arguments as :func:`acceleration`; the bodies' states do not depend on the spacecraft's.

    Returns
    -------
    da_dr : ndarray, shape (3, 3), s^-2
        ``d a / d r``: point masses ``-GM (I / d^3 - 3 d d^T / d^5)``, SRP
        ``k AU^2 (I / r^3 - 3 r r^T / r^5)``, plus the 1PN term's.
    da_dv : ndarray, shape (3, 3), s^-1
        ``d a / d v``: zero unless ``relativity`` (only the 1PN term depends on velocity).

    Notes
    -----
    1PN term, with heliocentric ``r, v``, ``s = GM / c^2``, ``g = 4 GM / r^4 - v^2 / r^3`` and
    ``h = (r . v) / r^3``, ``a = s (g r + 4 h v)``:
    ``da/dr = s (g I + r dg/dr^T + 4 v dh/dr^T)`` with ``dg/dr = (-16 GM / r^6 + 3 v^2 / r^5) r``,
    ``dh/dr = v / r^3 - 3 (r . v) r / r^5``; ``da/dv = s (-2 r v^T / r^3 + 4 h I + 4 v r^T / r^3)``.
    Checked against central differences in ``tests/scenes/test_dynamics_against_finite_differences.py``.
    """
    eye = np.eye(3)
    d = np.asarray(r_km, dtype=float) - np.asarray(body_pos_km, dtype=float)
    dn2 = np.sum(d * d, axis=1)
    inv3 = dn2**-1.5
    inv5 = inv3 / dn2
    gm = np.asarray(body_gm, dtype=float)
    da_dr = -(np.sum(gm * inv3) * eye - 3.0 * np.einsum("b,bi,bj->ij", gm * inv5, d, d))
    da_dv = np.zeros((3, 3))
    if sun_pos_km is not None and (srp_accel_1au_km_s2 or relativity):
        rs = np.asarray(r_km, dtype=float) - np.asarray(sun_pos_km, dtype=float)
        rn2 = float(rs @ rs)
        rn = math.sqrt(rn2)
        rrt = np.outer(rs, rs)
        if srp_accel_1au_km_s2:
            k = srp_accel_1au_km_s2 * AU_KM * AU_KM
            da_dr = da_dr + k * (eye / (rn2 * rn) - 3.0 * rrt / (rn2 * rn2 * rn))
        if relativity:
            vs = np.asarray(v_km_s, dtype=float) - np.asarray(sun_vel_km_s, dtype=float)
            mu = GM_KM3_S2["sun"]
            s_km = mu / C_KM_S**2
            v2 = float(vs @ vs)
            rv = float(rs @ vs)
            r3 = rn2 * rn
            g = 4.0 * mu / (rn2 * rn2) - v2 / r3
            h = rv / r3
            dg_dr = (-16.0 * mu / (r3 * r3) + 3.0 * v2 / (r3 * rn2)) * rs
            dh_dr = vs / r3 - 3.0 * rv / (r3 * rn2) * rs
            da_dr = da_dr + s_km * (g * eye + np.outer(rs, dg_dr) + 4.0 * np.outer(vs, dh_dr))
            da_dv = s_km * (-2.0 * np.outer(rs, vs) / r3 + 4.0 * h * eye + 4.0 * np.outer(vs, rs) / r3)
    return da_dr, da_dv


class ForceField:
    """The force model bound to body states over a span: ``f(x, t)`` and ``A(x, t) = df/dx``.

    Parameters
    ----------
    ephemeris : object
        ``position_velocity(body, t_tdb_s)`` (DE421 adapter).
    t0_tdb_s, t1_tdb_s : float
        Span to cover, TDB s past J2000 (either order).
    model : ForceModel
    table_step_s : float
        Step of the body-state interpolation table, s.

    Examples
    --------
    >>> from skynav.scenes.ephemeris_jpl import default_ephemeris
    >>> ff = ForceField(default_ephemeris(), 0.0, 86400.0)
    >>> x = np.array([1.5e8, 0.0, 0.0, 0.0, 30.0, 0.0])
    >>> ff.derivative(0.0, x).shape, ff.jacobian(0.0, x).shape
    ((6,), (6, 6))
    """

    def __init__(self, ephemeris, t0_tdb_s: float, t1_tdb_s: float, *, model: ForceModel = ForceModel(),
                 table_step_s: float = 10800.0):
        bodies = tuple(model.bodies)
        self.model = model
        self.table = BodyTable(ephemeris, bodies, t0_tdb_s, t1_tdb_s, table_step_s)
        self.gm = np.array([GM_KM3_S2[b] for b in bodies])
        self._i_sun = bodies.index("sun") if "sun" in bodies else None
        self._srp = model.srp.accel_1au_km_s2 if model.srp is not None else 0.0
        if self._i_sun is None and (self._srp or model.relativity):
            raise ValueError("the force model needs 'sun' among its bodies for SRP or relativity")

    def _bodies(self, t):
        lo, hi = self.table.span_tdb_s
        if not lo <= t <= hi:  # the spline would extrapolate silently
            raise ValueError(f"epoch {t} TDB s outside the force field's body table [{lo}, {hi}]")
        pos = self.table.positions(t)
        i_sun = self._i_sun
        if i_sun is not None and self.model.relativity:
            sun_v = self.table.velocities(t)[i_sun]
        else:
            sun_v = None
        return pos, (pos[i_sun] if i_sun is not None else None), sun_v

    def derivative(self, t_tdb_s: float, state) -> np.ndarray:
        """``f(x, t) = (v, a)``, shape (6,): km/s and km/s^2, for ``state`` = (r km, v km/s), shape (6,)."""
        r, v = state[:3], state[3:]
        pos, sun_p, sun_v = self._bodies(t_tdb_s)
        a = acceleration(r, v, pos, self.gm, sun_p, sun_v, srp_accel_1au_km_s2=self._srp,
                         relativity=self.model.relativity)
        return np.concatenate([v, a])

    def jacobian(self, t_tdb_s: float, state) -> np.ndarray:
        """``A(x, t) = df/dx``, shape (6, 6): ``[[0, I], [da/dr, da/dv]]``; units ``[[s^-1, 1], [s^-2, s^-1]]``."""
        state = np.asarray(state, dtype=float)
        pos, sun_p, sun_v = self._bodies(t_tdb_s)
        da_dr, da_dv = acceleration_jacobian(state[:3], state[3:], pos, self.gm, sun_p, sun_v,
                                             srp_accel_1au_km_s2=self._srp, relativity=self.model.relativity)
        out = np.zeros((6, 6))
        out[:3, 3:] = np.eye(3)
        out[3:, :3] = da_dr
        out[3:, 3:] = da_dv
        return out


@dataclass(frozen=True, kw_only=True, eq=False)
class Trajectory:
    """A propagated arc with dense output (made by :func:`propagate`).

    Attributes
    ----------
    t0_tdb_s, t1_tdb_s : float
        Span, TDB s past J2000.
    nfev : int
        Right-hand-side evaluations used.

    Examples
    --------
    >>> from skynav.scenes import default_ephemeris, propagate
    >>> eph = default_ephemeris()
    >>> r0, v0 = eph.position_velocity("earth", 0.0)
    >>> arc = propagate(eph, r0 + 5e6, v0 + 1.0, 0.0, 86400.0)
    >>> r, v = arc.state([0.0, 3600.0, 86400.0])
    >>> r.shape, v.shape, bool(np.allclose(r[0], r0 + 5e6))
    ((3, 3), (3, 3), True)
    """

    t0_tdb_s: float
    t1_tdb_s: float
    nfev: int
    _sol: object = field(repr=False)

    def state(self, t_tdb_s):
        """Barycentric ICRS state at epochs of the arc.

        Parameters
        ----------
        t_tdb_s : float or array_like, shape (N,)
            Epochs within ``[t0_tdb_s, t1_tdb_s]``, TDB s past J2000.

        Returns
        -------
        position_km : numpy.ndarray, shape (3,) or (N, 3)
            Position, km.
        velocity_km_s : numpy.ndarray, shape (3,) or (N, 3)
            Velocity, km/s.

        Raises
        ------
        ValueError
            An epoch outside the propagated span.
        """
        t = np.asarray(t_tdb_s, dtype=float)
        self._check_span(t)
        y = self._sol(t)
        if t.ndim == 0:
            return y[:3].copy(), y[3:6].copy()
        return y[:3].T.copy(), y[3:6].T.copy()

    def _check_span(self, t: np.ndarray) -> None:
        lo, hi = min(self.t0_tdb_s, self.t1_tdb_s), max(self.t0_tdb_s, self.t1_tdb_s)
        if np.any((t < lo - 1e-6) | (t > hi + 1e-6)):
            raise ValueError(f"epochs outside the propagated span [{lo}, {hi}] TDB s")


def propagate(ephemeris, r0_km, v0_km_s, t0_tdb_s: float, t1_tdb_s: float, *, model: ForceModel = ForceModel(),
              rtol: float = 1e-12, atol_km: float = 1e-6, atol_km_s: float = 1e-12,
              table_step_s: float = 10800.0, max_step_s: float = np.inf) -> Trajectory:
    """Propagate a barycentric ICRS state from ``t0_tdb_s`` to ``t1_tdb_s`` (DOP853).

    Parameters
    ----------
    ephemeris : object
        ``position_velocity(body, t_tdb_s)`` (DE421 adapter).
    r0_km, v0_km_s : array_like, shape (3,)
        Initial barycentric ICRS state, km and km/s.
    t0_tdb_s, t1_tdb_s : float
        Initial and final epochs, TDB s past J2000 (``t1 < t0`` propagates backwards).
    model : ForceModel
        The accelerations.
    rtol, atol_km, atol_km_s : float
        Integrator tolerances: relative, and absolute on position (km) and velocity (km/s).
    table_step_s : float
        Step of the body-state interpolation table, s.
    max_step_s : float
        Largest integrator step, s.

    Returns
    -------
    Trajectory
        The arc, with the state at any epoch of the span.

    Raises
    ------
    RuntimeError
        The integrator failed (its message).

    References
    ----------
    Dormand-Prince DOP853 as in :func:`scipy.integrate.solve_ivp` (Hairer, Norsett & Wanner
    1993, Solving Ordinary Differential Equations I, Sec. II.10).

    Examples
    --------
    A day from 5e6 km beside the Earth: the full model (planets, SRP and 1PN added to the Sun)
    ends about 19 km from the Sun-only arc:

    >>> from skynav.scenes import ForceModel, default_ephemeris, propagate
    >>> eph = default_ephemeris()
    >>> r0, v0 = eph.position_velocity("earth", 0.0)
    >>> arc = propagate(eph, r0 + 5e6, v0 + 1.0, 0.0, 86400.0)
    >>> sun_only = propagate(eph, r0 + 5e6, v0 + 1.0, 0.0, 86400.0,
    ...                      model=ForceModel(bodies=("sun",), srp=None, relativity=False))
    >>> r1, r2 = arc.state(86400.0)[0], sun_only.state(86400.0)[0]
    >>> round(float(np.linalg.norm(r1 - r2)))   # km
    19
    """
    rhs = ForceField(ephemeris, t0_tdb_s, t1_tdb_s, model=model, table_step_s=table_step_s).derivative
    atol = np.array([atol_km] * 3 + [atol_km_s] * 3)
    y0 = np.concatenate([np.asarray(r0_km, dtype=float), np.asarray(v0_km_s, dtype=float)])
    sol = solve_ivp(rhs, (t0_tdb_s, t1_tdb_s), y0, method="DOP853", rtol=rtol, atol=atol,
                    dense_output=True, max_step=max_step_s)
    if not sol.success:
        raise RuntimeError(f"propagation failed: {sol.message}")
    return Trajectory(t0_tdb_s=float(t0_tdb_s), t1_tdb_s=float(t1_tdb_s), nfev=int(sol.nfev), _sol=sol.sol)


@dataclass(frozen=True, kw_only=True, eq=False)
class StmTrajectory(Trajectory):
    """A propagated arc with its state transition matrix ``Phi(t, t0)``, both with dense output.

    ``Phi(t, t0) = d x(t) / d x(t0)``, shape (6, 6), blocks ``[[dr/dr0, dr/dv0], [dv/dr0, dv/dv0]]``
    in units ``[[1, s], [s^-1, 1]]``. Between two epochs of the arc,
    ``Phi(t2, t1) = Phi(t2, t0) Phi(t1, t0)^-1`` (:meth:`stm_between`).
    """

    def stm(self, t_tdb_s) -> np.ndarray:
        """``Phi(t, t0)``: shape (6, 6) for one epoch, (N, 6, 6) for N epochs."""
        t = np.asarray(t_tdb_s, dtype=float)
        self._check_span(t)
        y = self._sol(t)
        if t.ndim == 0:
            return y[6:].reshape(6, 6).copy()
        return np.moveaxis(y[6:], -1, 0).reshape(-1, 6, 6).copy()

    def stm_between(self, t2_tdb_s: float, t1_tdb_s: float) -> np.ndarray:
        """``Phi(t2, t1) = Phi(t2, t0) Phi(t1, t0)^-1``, shape (6, 6), for two epochs of the arc."""
        return np.linalg.solve(self.stm(t1_tdb_s).T, self.stm(t2_tdb_s).T).T


def propagate_stm(ephemeris, r0_km, v0_km_s, t0_tdb_s: float, t1_tdb_s: float, *, model: ForceModel = ForceModel(),
                  rtol: float = 1e-12, atol_km: float = 1e-6, atol_km_s: float = 1e-12,
                  stm_scale_km: float = 1.0, stm_scale_km_s: float = 1e-6,
                  table_step_s: float = 10800.0, max_step_s: float = np.inf) -> StmTrajectory:
    """Propagate a state and its state transition matrix (variational equations, DOP853).

    Integrates ``dx/dt = f(x, t)`` and ``dPhi/dt = A(x(t), t) Phi`` with ``Phi(t0, t0) = I``
    (42 equations) in one adaptive run, so that the STM belongs to the same trajectory.

    Parameters
    ----------
    ephemeris, r0_km, v0_km_s, t0_tdb_s, t1_tdb_s, model, rtol, atol_km, atol_km_s, table_step_s, max_step_s
        As :func:`propagate`.
    stm_scale_km, stm_scale_km_s : float
        Size of an initial position / velocity error for which the STM is integrated to the
        state's absolute tolerance: the absolute tolerance of ``Phi[i, j]`` is
        ``atol_i / scale_j`` (1 km and 1 mm/s by default).

    Returns
    -------
    StmTrajectory
        ``state(t)`` and ``stm(t) = Phi(t, t0)``.

    Notes
    -----
    The state part follows the same equations as :func:`propagate`, but the step-size control
    now also sees ``Phi``, so the two differ at the integrator's tolerance (not bit for bit).
    The row-major flattening ``Phi.ravel()`` is the ODE state's tail.

    Examples
    --------
    >>> from skynav.scenes import default_ephemeris, propagate_stm
    >>> eph = default_ephemeris()
    >>> r0, v0 = eph.position_velocity("earth", 0.0)
    >>> arc = propagate_stm(eph, r0 + 5e6, v0 + 1.0, 0.0, 86400.0)
    >>> bool(np.allclose(arc.stm(0.0), np.eye(6)))
    True
    """
    force = ForceField(ephemeris, t0_tdb_s, t1_tdb_s, model=model, table_step_s=table_step_s)

    def rhs(t, y):
        x = y[:6]
        phi = y[6:].reshape(6, 6)
        return np.concatenate([force.derivative(t, x), (force.jacobian(t, x) @ phi).ravel()])

    atol_x = np.array([atol_km] * 3 + [atol_km_s] * 3)
    scale = np.array([stm_scale_km] * 3 + [stm_scale_km_s] * 3)
    atol = np.concatenate([atol_x, (atol_x[:, None] / scale[None, :]).ravel()])
    y0 = np.concatenate([np.asarray(r0_km, dtype=float), np.asarray(v0_km_s, dtype=float), np.eye(6).ravel()])
    sol = solve_ivp(rhs, (t0_tdb_s, t1_tdb_s), y0, method="DOP853", rtol=rtol, atol=atol,
                    dense_output=True, max_step=max_step_s)
    if not sol.success:
        raise RuntimeError(f"propagation failed: {sol.message}")
    return StmTrajectory(t0_tdb_s=float(t0_tdb_s), t1_tdb_s=float(t1_tdb_s), nfev=int(sol.nfev), _sol=sol.sol)
