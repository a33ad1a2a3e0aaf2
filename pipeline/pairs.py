"""Optimal planet pair for a navigation leg (Franzese & Topputo; Andreis et al. (2024), Sec. 2.2, Eq. 1-2).

Core module. Two planets seen along unit lines of sight ``l_i`` at distances ``d_i`` with an
angular error ``sigma`` (rad, 1 sigma per axis) constrain the spacecraft position across each
line of sight with variance ``(sigma d_i)^2``; triangulating the two gives the position covariance

    P = sigma^2 (A_i + A_j)^-1,   A_i = (I - l_i l_i^T) / rho_i^2,   rho_i = d_i / 1 au   (Eq. 2)

and the figure of merit is ``J = tr(P)`` (Eq. 1), non-dimensional with the distances in au. The
pair minimising ``J`` among the eligible planets (``V < 7``, Sun elongation ``> 20 deg``, Andreis et al. (2024)
Sec. 5.2) is the optimal pair; the brighter planet is tracked first. With one eligible planet the
pair is that planet twice (``J`` infinite); with none, :func:`optimal_pair` returns None.

The dataset's leg planner (:mod:`skynav.datasets.sequence`) uses a stand-in criterion (largest
smallest eigenvalue of ``A_i + A_j``); the benchmark reports where the two choices differ.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from skynav.scenes.constants import AU_KM
from skynav.scenes.sky import sky_bodies

__all__ = ["PairCandidate", "PairChoice", "figure_of_merit", "optimal_pair", "candidates_from_state", "PLANETS"]

PLANETS = ("mercury", "venus", "earth", "mars", "jupiter", "saturn", "uranus", "neptune")


@dataclass(frozen=True, kw_only=True)
class PairCandidate:
    """A planet as the spacecraft predicts to see it."""

    name: str
    los_icrs: tuple          # unit vector, ICRS
    distance_km: float
    v_mag: float
    elongation_rad: float


@dataclass(frozen=True, kw_only=True)
class PairChoice:
    """The chosen pair (A tracked first: the brighter), its figure of merit and every pair's."""

    first: str
    second: str
    figure_of_merit: float
    all_pairs: tuple  # ((a, b, J), ...), sorted by J


def figure_of_merit(l_i, d_i_km, l_j, d_j_km, sigma_rad: float = 1.0) -> float:
    """``J = sigma^2 tr((A_i + A_j)^-1)`` of Andreis et al. (2024), Eq. 1-2 (au^2 x sigma^2; inf if parallel).

    Examples
    --------
    >>> J = figure_of_merit(np.array([1.0, 0, 0]), AU_KM, np.array([0, 1.0, 0]), AU_KM)
    >>> round(J, 12)   # (A_i + A_j) = diag(1, 1, 2): tr of the inverse = 2.5
    2.5
    """
    eye = np.eye(3)
    A = np.zeros((3, 3))
    for l, d in ((l_i, d_i_km), (l_j, d_j_km)):
        l = np.asarray(l, dtype=float)
        l = l / np.linalg.norm(l)
        A += (eye - np.outer(l, l)) / (d / AU_KM) ** 2
    if np.linalg.cond(A) > 1e12:
        return math.inf
    return float(sigma_rad**2 * np.trace(np.linalg.inv(A)))


def optimal_pair(candidates, *, limiting_v_mag: float = 7.0, elongation_min_rad: float = math.radians(20.0)):
    """The pair of eligible planets minimising :func:`figure_of_merit` (or None).

    Parameters
    ----------
    candidates : sequence of PairCandidate
        The planets as the spacecraft predicts to see them (:func:`candidates_from_state`).
    limiting_v_mag : float
        Eligible when ``V < limiting_v_mag``, mag.
    elongation_min_rad : float
        Eligible when the angle from the Sun exceeds this, rad.

    Returns
    -------
    PairChoice or None
        The pair (the brighter tracked first), its ``J`` and every pair's; one eligible planet
        gives that planet twice (``J`` infinite); None when none is eligible.

    References
    ----------
    Andreis et al. (2024), Sec. 2.2, Eqs. 1-2, and Sec. 5.2 (V < 7, 20 deg).

    Examples
    --------
    Venus is brightest but 11 deg from the Sun: the pair is Jupiter and Mars.

    >>> from skynav.pipeline import optimal_pair
    >>> from skynav.pipeline.pairs import PairCandidate
    >>> c = [PairCandidate(name="mars", los_icrs=(1.0, 0, 0), distance_km=1.5e8, v_mag=-1.0, elongation_rad=2.0),
    ...      PairCandidate(name="jupiter", los_icrs=(0, 1.0, 0), distance_km=6e8, v_mag=-2.0, elongation_rad=1.5),
    ...      PairCandidate(name="venus", los_icrs=(0.6, 0.8, 0), distance_km=1e8, v_mag=-4.0, elongation_rad=0.2)]
    >>> choice = optimal_pair(c)
    >>> choice.first, choice.second, round(choice.figure_of_merit, 3)
    ('jupiter', 'mars', 18.038)
    """
    elig = [c for c in candidates if c.name in PLANETS and np.isfinite(c.v_mag) and c.v_mag < limiting_v_mag
            and c.elongation_rad > elongation_min_rad]
    if not elig:
        return None
    if len(elig) == 1:
        return PairChoice(first=elig[0].name, second=elig[0].name, figure_of_merit=math.inf, all_pairs=())
    scores = []
    for i in range(len(elig)):
        for j in range(i + 1, len(elig)):
            a, b = elig[i], elig[j]
            J = figure_of_merit(a.los_icrs, a.distance_km, b.los_icrs, b.distance_km)
            a, b = sorted((a, b), key=lambda c: c.v_mag)
            scores.append((a.name, b.name, J))
    scores.sort(key=lambda s: s[2])
    best = scores[0]
    return PairChoice(first=best[0], second=best[1], figure_of_merit=best[2], all_pairs=tuple(scores))


def candidates_from_state(t_tdb_s: float, position_km, velocity_km_s, *, ephemeris=None):
    """:class:`PairCandidate` list of the planets, predicted from the spacecraft's own state estimate
    (on-board ephemeris and photometry through ``skynav.scenes``)."""
    bodies, _ = sky_bodies(t_tdb_s, position_km, velocity_km_s, ephemeris=ephemeris, names=PLANETS)
    return [PairCandidate(name=b.name, los_icrs=tuple(np.asarray(b.directions.u_icrs, dtype=float)),
                          distance_km=float(b.directions.distance_km), v_mag=float(b.v_mag),
                          elongation_rad=float(b.elongation_rad)) for b in bodies]
