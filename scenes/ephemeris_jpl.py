"""Adapter over ``jplephem``: JPL DE421 positions and velocities of the Sun, Moon and planets.

The kernel is the ``de421.bsp`` that the ``skyfield-data`` package installs
(:func:`skynav.infra.data_files.de421_path`); it is opened lazily on first use, never in a
constructor or on import, and an :class:`Ephemeris` pickles without it (it reopens after
unpickling). Outputs are barycentric ICRS: km and km/s; times are TDB seconds past J2000
(JD 2451545.0 TDB), passed to jplephem as a two-part Julian date for full precision.

jplephem evaluates the Chebyshev series (``Segment.compute`` and ``compute_and_differentiate``,
vectorised over epochs). One fast path sits beside it: a single epoch (a float, as the
light-time iterations read one body at a time) goes through :func:`one_epoch_state`, the same
operations in Python floats instead of arrays of one element, held to jplephem within 2 ulps
by ``tests/scenes/test_ephemeris.py``.

Bodies and the DE421 segments chained for them
----------------------------------------------
* sun: 0 -> 10; earth: 0 -> 3 -> 399; moon: 0 -> 3 -> 301.
* mercury, venus, mars: the body centres 199, 299, 499 (0 -> 1 -> 199, 0 -> 2 -> 299,
  0 -> 4 -> 499); for Mercury and Venus centre and barycentre coincide in DE421, Mars differs
  by ~ 20 cm.
* jupiter, saturn, uranus, neptune: the SYSTEM BARYCENTRES 5, 6, 7, 8, because DE421 has no
  body-centre segments for them. The offset of the planet centre from its system barycentre is
  ~ 1 km for Jupiter, ~ 200 km for Saturn (Titan) and tens of km for Uranus and Neptune; seen
  from 1 AU away, Saturn's is 0.3 arcsec. Satellite ephemerides (sat*.bsp) would remove it.
"""

from __future__ import annotations

import functools
import math
import threading

import numpy as np
from jplephem.spk import SPK

from skynav.infra.data_files import de421_path
from skynav.infra.errors import DataFileError

from .constants import J2000_JD, SECONDS_PER_DAY
from .errors import EphemerisRangeError, UnknownBodyError

BODIES = ("sun", "mercury", "venus", "earth", "moon", "mars", "jupiter", "saturn", "uranus", "neptune")

BODY_NAIF_IDS = {
    "sun": 10,
    "mercury": 199,
    "venus": 299,
    "earth": 399,
    "moon": 301,
    "mars": 499,
    "jupiter": 5,  # system barycentre: DE421 has no 599 segment
    "saturn": 6,  # system barycentre
    "uranus": 7,  # system barycentre
    "neptune": 8,  # system barycentre
}
"""NAIF integer codes of what :class:`Ephemeris` returns for each body."""

BODY_RADII_KM = {
    "sun": 695700.0,  # IAU 2015 Resolution B3 nominal solar radius (Prsa et al. 2016)
    "mercury": 2439.4,
    "venus": 6051.8,
    "earth": 6371.0084,
    "moon": 1737.4,
    "mars": 3389.50,
    "jupiter": 69911.0,
    "saturn": 58232.0,
    "uranus": 25362.0,
    "neptune": 24622.0,
}
"""Mean radii, km: Archinal et al. (2018), "Report of the IAU Working Group on Cartographic
Coordinates and Rotational Elements: 2015", Celest. Mech. Dyn. Astr. 130:22, Tables 1 and 5
(Sun: IAU 2015 Resolution B3)."""

_CHAINS = {
    "sun": ((0, 10),),
    "mercury": ((0, 1), (1, 199)),
    "venus": ((0, 2), (2, 299)),
    "earth": ((0, 3), (3, 399)),
    "moon": ((0, 3), (3, 301)),
    "mars": ((0, 4), (4, 499)),
    "jupiter": ((0, 5),),
    "saturn": ((0, 6),),
    "uranus": ((0, 7),),
    "neptune": ((0, 8),),
}


def _jd_to_date(jd: float) -> str:
    """Calendar date (proleptic Gregorian, YYYY-MM-DD) of a Julian date; Fliegel & van Flandern (1968)."""
    j = int(np.floor(jd + 0.5))
    f = j + 1401 + (((4 * j + 274277) // 146097) * 3) // 4 - 38
    e = 4 * f + 3
    h = 5 * ((e % 1461) // 4) + 2
    day = (h % 153) // 5 + 1
    month = (h // 153 + 2) % 12 + 1
    year = e // 1461 - 4716 + (12 + 2 - month) // 12
    return f"{year:04d}-{month:02d}-{day:02d}"


class Ephemeris:
    """Barycentric ICRS states of :data:`BODIES` from a JPL SPK kernel (DE421 by default).

    Parameters
    ----------
    path : str or Path, optional
        SPK file; default :func:`skynav.infra.data_files.de421_path`. Nothing is opened here.

    Examples
    --------
    >>> from skynav.scenes import Ephemeris
    >>> eph = Ephemeris()
    >>> r_km, v_km_s = eph.position_velocity("earth", 0.0)
    >>> bool(1.4e8 < np.linalg.norm(r_km) < 1.5e8)
    True
    """

    def __init__(self, path=None):
        self._path = None if path is None else str(path)
        self._kernel = None
        self._lock = threading.Lock()

    def __repr__(self) -> str:
        return f"Ephemeris(path={self._path!r})"

    def __eq__(self, other):
        return isinstance(other, Ephemeris) and self._path == other._path

    def __hash__(self):
        return hash((Ephemeris, self._path))

    def __getstate__(self):
        return {"_path": self._path}

    def __setstate__(self, state):
        self._path = state["_path"]
        self._kernel = None
        self._lock = threading.Lock()

    # -- kernel -------------------------------------------------------------------------------
    @property
    def path(self) -> str:
        """Path of the SPK file."""
        return self._path if self._path is not None else str(de421_path())

    def _open(self):
        if self._kernel is None:
            with self._lock:
                if self._kernel is None:
                    try:
                        kernel = SPK.open(self.path)
                    except OSError as exc:
                        raise DataFileError(f"cannot open SPK kernel {self.path}: {exc}") from exc
                    segs = {(s.center, s.target): s for s in kernel.segments}
                    missing = [p for chain in _CHAINS.values() for p in chain if p not in segs]
                    if missing:
                        raise DataFileError(f"{self.path} lacks segments {missing}")
                    used = [segs[p] for chain in _CHAINS.values() for p in chain]
                    self._segments = segs
                    self._start_jd = max(s.start_jd for s in used)
                    self._end_jd = min(s.end_jd for s in used)
                    self._kernel = kernel
        return self._kernel

    @property
    def span_tdb_s(self) -> tuple:
        """(start, end) of the kernel, TDB seconds past J2000 (opens the kernel)."""
        self._open()
        return (
            (self._start_jd - J2000_JD) * SECONDS_PER_DAY,
            (self._end_jd - J2000_JD) * SECONDS_PER_DAY,
        )

    # -- states -------------------------------------------------------------------------------
    def position_velocity(self, body: str, t_tdb_s, *, offset_s=0.0):
        """Barycentric ICRS position and velocity of a body.

        Parameters
        ----------
        body : str
            One of :data:`BODIES` (case-insensitive).
        t_tdb_s : float or ndarray, shape (N,)
            Epochs, TDB seconds past J2000.
        offset_s : float or ndarray, shape (N,), optional
            Added to ``t_tdb_s`` without loss of precision (e.g. minus a light-time): the sum is
            formed as a two-part Julian date, good to ~1e-11 s, where a float of seconds past
            J2000 resolves only ~2e-7 s.

        Returns
        -------
        position_km : ndarray, shape (3,) or (N, 3)
        velocity_km_s : ndarray, shape (3,) or (N, 3)

        Raises
        ------
        UnknownBodyError
            ``body`` is not in :data:`BODIES`.
        EphemerisRangeError
            An epoch is outside the kernel (``.time_mask`` marks which).
        """
        return self._states(body, t_tdb_s, offset_s, velocity=True)

    def position(self, body: str, t_tdb_s, *, offset_s=0.0):
        """Barycentric ICRS position of a body, km (:meth:`position_velocity` without the velocity).

        Evaluates the Chebyshev series only (no derivative): the same bits as
        ``position_velocity(...)[0]``.

        Parameters
        ----------
        body : str
            One of :data:`BODIES` (case-insensitive).
        t_tdb_s : float or array_like, shape (N,)
            Epochs, TDB seconds past J2000.
        offset_s : float or array_like
            Added to ``t_tdb_s`` in two parts (a light-time offset kept exact), s.

        Returns
        -------
        numpy.ndarray, shape (3,) or (N, 3)
            Position, km.
        """
        return self._states(body, t_tdb_s, offset_s, velocity=False)

    def states_at(self, t_tdb_s: float, bodies=BODIES) -> dict:
        """Position and velocity of several bodies at one epoch.

        Parameters
        ----------
        t_tdb_s : float
            Epoch, TDB seconds past J2000.
        bodies : sequence of str
            Body names (default: all of :data:`BODIES`).

        Returns
        -------
        dict
            ``{body: (r_km (3,), v_km_s (3,))}``, each :meth:`position_velocity` ``(body, t_tdb_s)``.
        """
        return {b: self.position_velocity(b, float(t_tdb_s)) for b in bodies}

    def epoch_states(self, t_tdb_s: float, bodies=BODIES) -> "EpochStates":
        """The positions and velocities of several bodies at one epoch, as an :class:`EpochStates`.

        Parameters
        ----------
        t_tdb_s : float
            Epoch, TDB seconds past J2000.
        bodies : sequence of str
            Body names (default: all of :data:`BODIES`).

        Returns
        -------
        EpochStates
            Positions (km) and velocities (km/s) as rows, one per body (:meth:`states_at`).
        """
        bodies = tuple(bodies)
        states = [self.position_velocity(b, float(t_tdb_s)) for b in bodies]
        return EpochStates(bodies, np.array([r for r, _ in states]).reshape(-1, 3),
                           np.array([v for _, v in states]).reshape(-1, 3))

    def positions_at(self, t_tdb_s, bodies=BODIES) -> np.ndarray:
        """Positions of several bodies at several epochs: each :meth:`position` ``(body, t_tdb_s)``.

        Parameters
        ----------
        t_tdb_s : array_like, shape (N,)
            Epochs, TDB seconds past J2000.
        bodies : sequence of str
            Body names (default: all of :data:`BODIES`).

        Returns
        -------
        numpy.ndarray, shape (N, len(bodies), 3)
            Positions, km.

        Raises
        ------
        UnknownBodyError, EphemerisRangeError
            As :meth:`position`.
        """
        t = np.atleast_1d(np.asarray(t_tdb_s, dtype=float))
        return np.stack([self.position(b, t) for b in bodies], axis=1).reshape(t.size, len(bodies), 3)

    def _states(self, body, t_tdb_s, offset_s, *, velocity: bool):
        key = body.lower() if isinstance(body, str) else body
        if key not in _CHAINS:
            raise UnknownBodyError(body, BODIES)
        self._open()
        if isinstance(t_tdb_s, (float, int)) and isinstance(offset_s, (float, int)):
            got = self._one_epoch(key, float(t_tdb_s), float(offset_s), velocity)
            if got is not None:
                return got
        t = np.asarray(t_tdb_s, dtype=float)
        off = np.asarray(offset_s, dtype=float)
        scalar = t.ndim == 0 and off.ndim == 0
        t, off = np.broadcast_arrays(np.atleast_1d(t), np.atleast_1d(off))
        days = np.floor(t / SECONDS_PER_DAY)
        jd1 = J2000_JD + days
        jd2 = ((t - days * SECONDS_PER_DAY) + off) / SECONDS_PER_DAY  # t - 86400 k is exact
        jd = jd1 + jd2
        mask = ~((jd >= self._start_jd) & (jd <= self._end_jd))  # NaN counts as outside
        if mask.any():
            raise EphemerisRangeError(
                f"{self._name()} covers {_jd_to_date(self._start_jd)}..{_jd_to_date(self._end_jd)} TDB;"
                f" {int(mask.sum())} of {mask.size} epochs outside (see .time_mask)",
                time_mask=mask if not scalar else bool(mask[0]),
                start_jd=self._start_jd,
                end_jd=self._end_jd,
            )
        pos = np.zeros((3, t.size))
        vel = np.zeros((3, t.size)) if velocity else None
        for pair in _CHAINS[key]:
            seg = self._segments[pair]
            if velocity:
                p, v = seg.compute_and_differentiate(jd1, jd2)
                vel += v
            else:
                p = seg.compute(jd1, jd2)
            pos += p
        pos = pos.T
        if scalar:
            pos = pos[0]
        else:
            pos = pos.reshape(t.shape + (3,))
        if not velocity:
            return pos
        vel = vel.T / SECONDS_PER_DAY  # jplephem gives km/day
        return pos, (vel[0] if scalar else vel.reshape(t.shape + (3,)))

    def _one_epoch(self, key, t: float, off: float, velocity: bool):
        """:func:`one_epoch_state` of ``key``'s chain at ``t + off``; None where the reference
        must answer (an epoch outside the kernel: it raises)."""
        days = float(math.floor(t / SECONDS_PER_DAY))  # numpy.floor's value
        jd1 = J2000_JD + days
        jd2 = ((t - days * SECONDS_PER_DAY) + off) / SECONDS_PER_DAY
        if not (self._start_jd <= jd1 + jd2 <= self._end_jd):
            return None
        kept = self.__dict__.get("_intervals")
        if kept is None or len(kept) > INTERVALS_KEPT:
            kept = self._intervals = {}
        return one_epoch_state([(pair, *self._segments[pair]._data) for pair in _CHAINS[key]], jd1, jd2, velocity, kept)

    def _name(self) -> str:
        return self.path.replace("\\", "/").rsplit("/", 1)[-1]


class EpochStates:
    """Positions and velocities of several bodies at one epoch (:meth:`Ephemeris.epoch_states`):
    ``positions`` and ``velocities`` (n, 3), km and km/s, barycentric ICRS, in the order of
    ``bodies``."""

    __slots__ = ("bodies", "positions", "velocities", "_col")

    def __init__(self, bodies, positions, velocities):
        self.bodies, self.positions, self.velocities = bodies, positions, velocities
        self._col = {b: j for j, b in enumerate(bodies)}

    def position(self, body):
        return self.positions[self._col[body]]

    def velocity(self, body):
        return self.velocities[self._col[body]]


#: Intervals whose coefficients :func:`one_epoch_state` keeps per :class:`Ephemeris`, as lists.
INTERVALS_KEPT = 4096


def one_epoch_state(segments, jd1: float, jd2: float, velocity: bool, kept: dict):
    """The fast path of :meth:`Ephemeris.position_velocity` (and :meth:`Ephemeris.position`)
    for one epoch, which the light-time iterations read one body at a time: the sum over a chain
    of SPK type 2 segments of their Chebyshev series at the two-part Julian date ``jd1 + jd2``
    (TDB), in Python floats instead of arrays of one element.

    It repeats jplephem's ``Segment.generate`` (the reference: an array of epochs goes through
    it) operation for operation: its interval arithmetic (CPython's float ``divmod`` is numpy's),
    the Clenshaw recurrence of the position and of its derivative; ``tests/scenes/
    test_ephemeris.py`` holds it to the reference within 2 ulps of each vector's largest
    coordinate.

    Parameters
    ----------
    segments : list of (pair, init_s, intlen_s, coefficients)
        The chain's segments: ``(center, target)``, the first interval's start (TDB s past
        J2000) and the interval length (s), the coefficients (C, 3, N) highest degree first
        (jplephem's ``Segment._data``).
    jd1, jd2 : float
        The epoch as a two-part Julian date, TDB.
    velocity : bool
        Also the velocity.
    kept : dict
        ``{(pair, interval): its coefficients as 3 lists}``, filled as intervals are read.

    Returns
    -------
    position_km : ndarray, shape (3,), and velocity_km_s : ndarray, shape (3,) with ``velocity``;
    None where an interval is outside its segment (the reference raises).
    """
    pos = [0.0, 0.0, 0.0]
    vel = [0.0, 0.0, 0.0]
    for pair, init, intlen, coefs in segments:
        init, intlen = float(init), float(intlen)
        index1, offset1 = divmod((jd1 - J2000_JD) * SECONDS_PER_DAY - init, intlen)
        index2, offset2 = divmod(jd2 * SECONDS_PER_DAY, intlen)
        index3, offset = divmod(offset1 + offset2, intlen)
        index = int(index1 + index2 + index3)
        n = coefs.shape[2]
        if index < 0 or index > n:
            return None
        if index == n:
            index -= 1
            offset += intlen
        rows = kept.get((pair, index))
        if rows is None:
            rows = kept[(pair, index)] = coefs[:, :, index].T.tolist()  # 3 x C, highest degree first
        s = 2.0 * offset / intlen - 1.0
        s2 = 2.0 * s
        for k, c in enumerate(rows):
            w0 = w1 = 0.0
            wlist = []
            for ci in c[:-1]:
                w2 = w1
                w1 = w0
                w0 = ci + (s2 * w1 - w2)
                wlist.append(w1)
            pos[k] = pos[k] + (c[-1] + (s * w0 - w1))
            if velocity:
                dw0 = dw1 = 0.0
                for wi in wlist:
                    dw2 = dw1
                    dw1 = dw0
                    dw0 = 2.0 * wi + dw1 * s2 - dw2
                rate = w0 + s * dw0 - dw1
                rate = rate / intlen
                rate = rate * 2.0
                rate = rate * SECONDS_PER_DAY
                vel[k] = vel[k] + rate
    if not velocity:
        return np.array(pos)
    return np.array(pos), np.array(vel) / SECONDS_PER_DAY


@functools.lru_cache(maxsize=1)
def default_ephemeris() -> Ephemeris:
    """The process-wide DE421 :class:`Ephemeris` (kernel opened on first use).

    Returns
    -------
    Ephemeris
        The same object on every call: barycentric ICRS positions (km) and velocities (km/s)
        of the Sun, planets and Moon at TDB epochs, 1899-07-29 to 2053-10-09.

    References
    ----------
    Folkner, W. M. et al. (2009), "The Planetary and Lunar Ephemeris DE 421", JPL IPN Progress
    Report 42-178.

    Examples
    --------
    >>> from skynav.scenes import default_ephemeris
    >>> eph = default_ephemeris()
    >>> r, v = eph.position_velocity("earth", 0.0)   # J2000 TDB
    >>> au_km = 1.495978707e8
    >>> round(float(np.linalg.norm(r)) / au_km, 4), round(float(np.linalg.norm(v)), 2)   # au, km/s
    (0.9819, 30.29)
    >>> default_ephemeris() is eph
    True
    """
    return Ephemeris()
