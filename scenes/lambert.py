"""Lambert's problem, single revolution, after Izzo (2015).

Core module: floats and NumPy only.

Given two positions ``r1_km``, ``r2_km`` about a central body of parameter ``mu_km3_s2`` and a
time of flight, find the velocities of the conic arc joining them. The solver follows

    D. Izzo, "Revisiting Lambert's problem", Celestial Mechanics and Dynamical Astronomy 121,
    1-15 (2015), doi:10.1007/s10569-014-9587-y,

with its non-dimensional variable ``x`` (Lancaster-Blanchard), the time-of-flight equation
(Eq. 18, with Battin's hypergeometric series near the parabola, Eq. 20), the initial guesses of
Sec. 3.2 (Eq. 30) and Householder's third-order iterations on ``T(x)`` (Eq. 22 for the
derivatives). Only the zero-revolution solution is computed (enough for an Earth-Mars transfer
of less than one orbit); ``revolutions > 0`` is refused.

Tests check the arc by propagating ``(r1, v1)`` for the time of flight with SciPy's DOP853 on
the two-body problem and comparing with ``r2`` (``tests/scenes/test_lambert.py``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .errors import LambertError

__all__ = ["LambertSolution", "solve_lambert"]


@dataclass(frozen=True, kw_only=True)
class LambertSolution:
    """Velocities at both ends of a Lambert arc.

    Attributes
    ----------
    v1_km_s, v2_km_s : ndarray, shape (3,)
        Velocity at departure and at arrival, km/s (same axes as the positions).
    x : float
        Izzo's non-dimensional variable at convergence (x < 1 ellipse, x > 1 hyperbola).
    iterations : int
        Householder iterations used.

    References
    ----------
    Izzo, D. (2015), "Revisiting Lambert's problem", Celestial Mechanics and Dynamical
    Astronomy 121, 1-15.

    Examples
    --------
    A quarter of a circular orbit (mu = 1, radius 1, period 2 pi):

    >>> from skynav.scenes import solve_lambert
    >>> sol = solve_lambert([1.0, 0.0, 0.0], [0.0, 1.0, 0.0], np.pi / 2, 1.0)
    >>> np.round(sol.v1_km_s, 12) + 0.0, np.round(sol.v2_km_s, 12) + 0.0
    (array([0., 1., 0.]), array([-1.,  0.,  0.]))
    """

    v1_km_s: np.ndarray
    v2_km_s: np.ndarray
    x: float
    iterations: int


def _hyp2f1b(z: float) -> float:
    """Gauss hypergeometric 2F1(3, 1; 5/2; z) by its series (|z| < 1), Battin's function."""
    if z >= 1.0:
        return math.inf
    res, term = 1.0, 1.0
    n = 0
    while True:
        term *= (3.0 + n) * (1.0 + n) / (2.5 + n) * z / (n + 1.0)
        res_old = res
        res += term
        n += 1
        if res == res_old or n > 10000:
            return res


def _tof(x: float, y: float, lam: float) -> float:
    """Non-dimensional time of flight T(x) (Izzo 2015 Eq. 18; Battin series near x = 1)."""
    if 0.7745966692414834 < x < 1.1832159566199232:  # sqrt(0.6) < x < sqrt(1.4), near the parabola: Battin's series (Izzo 2015 Eq. 20), no cancellation
        eta = y - lam * x
        s1 = 0.5 * (1.0 - lam - x * eta)
        q = 4.0 / 3.0 * _hyp2f1b(s1)
        return 0.5 * (eta**3 * q + 4.0 * lam * eta)
    one_minus_x2 = 1.0 - x * x
    if x < 1.0:
        psi = math.acos(max(-1.0, min(1.0, x * y + lam * one_minus_x2)))
    else:
        psi = math.acosh(max(1.0, x * y + lam * one_minus_x2))  # = xy - lam (x^2 - 1)
    return (psi / math.sqrt(abs(one_minus_x2)) - x + lam * y) / one_minus_x2


def _tof_derivatives(x: float, t: float, y: float, lam: float):
    """dT/dx, d2T/dx2, d3T/dx3 (Izzo 2015 Eq. 22)."""
    umx2 = 1.0 - x * x
    l2 = lam * lam
    l3 = l2 * lam
    dt = (3.0 * t * x - 2.0 + 2.0 * l3 * x / y) / umx2
    ddt = (3.0 * t + 5.0 * x * dt + 2.0 * (1.0 - l2) * l3 / y**3) / umx2
    dddt = (7.0 * x * ddt + 8.0 * dt - 6.0 * (1.0 - l2) * l2 * l3 * x / y**5) / umx2
    return dt, ddt, dddt


@dataclass(frozen=True)
class _TransferGeometry:
    """The transfer's geometry, Izzo (2015) Sec. 2: the norms of ``r1``, ``r2`` and the chord
    ``c``, the semi-perimeter ``s``, lambda (signed by the transfer angle and the direction),
    and the radial and tangential unit vectors at both ends."""

    r1_n: float
    r2_n: float
    c_n: float
    s: float
    lam: float
    ir1: np.ndarray
    ir2: np.ndarray
    it1: np.ndarray
    it2: np.ndarray

    @classmethod
    def of(cls, r1, r2, prograde: bool) -> "_TransferGeometry":
        c_n = float(np.linalg.norm(r2 - r1))
        r1_n = float(np.linalg.norm(r1))
        r2_n = float(np.linalg.norm(r2))
        s = 0.5 * (r1_n + r2_n + c_n)
        ir1 = r1 / r1_n
        ir2 = r2 / r2_n
        h = np.cross(ir1, ir2)
        h_n = float(np.linalg.norm(h))
        if h_n < 1e-12:
            raise LambertError("r1 and r2 are collinear: the transfer plane is undefined")
        ih = h / h_n
        lam = math.sqrt(max(0.0, 1.0 - c_n / s))
        if ih[2] < 0.0:  # transfer angle > pi for a prograde arc
            lam = -lam
            it1 = np.cross(ir1, ih)
            it2 = np.cross(ir2, ih)
        else:
            it1 = np.cross(ih, ir1)
            it2 = np.cross(ih, ir2)
        if not prograde:
            lam = -lam
            it1 = -it1
            it2 = -it2
        return cls(r1_n=r1_n, r2_n=r2_n, c_n=c_n, s=s, lam=lam, ir1=ir1, ir2=ir2, it1=it1, it2=it2)


def _initial_x(lam: float, t_target: float) -> float:
    """The starting ``x`` of the iterations for the non-dimensional time ``t_target``, Izzo
    (2015) Eq. 30 (M = 0)."""
    t00 = math.acos(lam) + lam * math.sqrt(1.0 - lam * lam)
    t1 = 2.0 / 3.0 * (1.0 - lam**3)
    if t_target >= t00:
        return (t00 / t_target) ** (2.0 / 3.0) - 1.0
    if t_target < t1:
        return 2.5 * t1 / t_target * (t1 - t_target) / (1.0 - lam**5) + 1.0
    return (t00 / t_target) ** math.log2(t1 / t00) - 1.0


def _householder(x: float, lam: float, t_target: float, rtol: float, max_iterations: int, tof_s: float) -> tuple:
    """``(x, iterations)``: Householder's third-order iterations from ``x`` until the
    non-dimensional time of flight is ``t_target``, Izzo (2015) Sec. 3; LambertError when they
    diverge or do not converge."""
    for it in range(1, max_iterations + 1):
        y = math.sqrt(1.0 - lam * lam * (1.0 - x * x))
        t = _tof(x, y, lam)
        f = t - t_target
        dt, ddt, dddt = _tof_derivatives(x, t, y, lam)
        dt2 = dt * dt
        x_new = x - f * (dt2 - 0.5 * f * ddt) / (dt * (dt2 - f * ddt) + dddt * f * f / 6.0)
        if not math.isfinite(x_new) or x_new <= -1.0:
            raise LambertError(f"Lambert iterations diverged (x = {x_new!r}) for tof = {tof_s} s")
        done = abs(x_new - x) < rtol * max(1.0, abs(x))
        x = x_new
        if done:
            return x, it
    raise LambertError(f"Lambert solver did not converge in {max_iterations} iterations")


def solve_lambert(r1_km, r2_km, tof_s: float, mu_km3_s2: float, *, prograde: bool = True,
                  revolutions: int = 0, rtol: float = 1e-13, max_iterations: int = 50) -> LambertSolution:
    """Velocities of the conic arc from ``r1_km`` to ``r2_km`` in ``tof_s`` seconds.

    Parameters
    ----------
    r1_km, r2_km : array_like, shape (3,)
        Positions relative to the central body, km.
    tof_s : float
        Time of flight, s (> 0).
    mu_km3_s2 : float
        Gravitational parameter of the central body, km^3/s^2.
    prograde : bool
        Prograde (angular momentum along +z of the axes given) or retrograde transfer.
    revolutions : int
        Only 0 is supported.
    rtol : float
        Convergence threshold on the change of ``x`` between iterations.
    max_iterations : int
        Householder iterations allowed before :class:`LambertError`.

    Returns
    -------
    LambertSolution
        The velocities at both ends, km/s, and the solver's state.

    Raises
    ------
    LambertError
        Non-positive time of flight, collinear positions, multi-revolution request, or no
        convergence.

    References
    ----------
    Izzo (2015), Secs. 2-3.

    Examples
    --------
    >>> from skynav.scenes import solve_lambert
    >>> sol = solve_lambert([1.0, 0, 0], [0, 1.0, 0], np.pi / 2, 1.0)  # quarter circular orbit
    >>> np.round(sol.v1_km_s, 12) + 0.0
    array([0., 1., 0.])
    """
    if revolutions != 0:
        raise LambertError(f"revolutions = {revolutions!r} is not supported; only 0 (single arc)")
    if not (tof_s > 0 and math.isfinite(tof_s)):
        raise LambertError(f"time of flight = {tof_s!r} s; expected a finite value > 0")
    if not mu_km3_s2 > 0:
        raise LambertError(f"mu = {mu_km3_s2!r} km^3/s^2; expected > 0")
    r1 = np.asarray(r1_km, dtype=float)
    r2 = np.asarray(r2_km, dtype=float)
    g = _TransferGeometry.of(r1, r2, prograde)
    t_target = math.sqrt(2.0 * mu_km3_s2 / g.s**3) * tof_s
    x, it = _householder(_initial_x(g.lam, t_target), g.lam, t_target, rtol, max_iterations, tof_s)

    # velocities, Izzo (2015) Algorithm 1 last lines
    lam, r1_n, r2_n = g.lam, g.r1_n, g.r2_n
    y = math.sqrt(1.0 - lam * lam * (1.0 - x * x))
    gamma = math.sqrt(0.5 * mu_km3_s2 * g.s)
    rho = (r1_n - r2_n) / g.c_n
    sigma = math.sqrt(max(0.0, 1.0 - rho * rho))
    vr1 = gamma * ((lam * y - x) - rho * (lam * y + x)) / r1_n
    vr2 = -gamma * ((lam * y - x) + rho * (lam * y + x)) / r2_n
    vt = gamma * sigma * (y + lam * x)
    v1 = vr1 * g.ir1 + (vt / r1_n) * g.it1
    v2 = vr2 * g.ir2 + (vt / r2_n) * g.it2
    return LambertSolution(v1_km_s=v1, v2_km_s=v2, x=float(x), iterations=it)
