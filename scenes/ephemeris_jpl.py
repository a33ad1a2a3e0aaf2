"""Adapter over ``jplephem``: JPL DE421 positions and velocities of the Sun, Moon and planets.

The kernel is the ``de421.bsp`` that the ``skyfield-data`` package installs
(:func:`skynav.infra.data_files.de421_path`); it is opened lazily on first use, never in a
constructor or on import, and an :class:`Ephemeris` pickles without it (it reopens after
unpickling). Outputs are barycentric ICRS: km and km/s; times are TDB seconds past J2000
(JD 2451545.0 TDB), passed to jplephem as a two-part Julian date for full precision.

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

from .constants import J2000_JD, SECONDS_PER_DAY

# jplephem's own constants (jplephem.spk.T0, S_PER_DAY), used to repeat its interval arithmetic
_T0 = J2000_JD
_S_PER_DAY = SECONDS_PER_DAY
from jplephem.spk import SPK

from skynav.infra.data_files import de421_path
from skynav.infra.errors import DataFileError
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


def _intervals(a1, a2, inits, intlens, ns):
    """jplephem's interval arithmetic (``Segment.generate``) for arrays of segments and epochs:
    ``(index, offset)`` of the Chebyshev interval holding the epoch ``a1 + a2`` (seconds from
    ``_T0``, in two parts), ``inits``/``intlens``/``ns`` each segment's start, interval length and
    interval count (broadcast). numpy's float64 divmod is CPython's float divmod (the same IEEE
    operations), so the same bits as jplephem; an epoch at a segment's very end is the last
    interval's."""
    index1, offset1 = np.divmod(a1 - inits, intlens)
    index2, offset2 = np.divmod(a2, intlens)
    index3, offset = np.divmod(offset1 + offset2, intlens)
    index = (index1 + index2 + index3).astype(np.intp)
    last = index == ns
    return np.where(last, index - 1, index), np.where(last, offset + intlens, offset)


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
        self._tables = None
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
        """Barycentric ICRS position, km; shape (3,) or (N, 3). See :meth:`position_velocity`.

        Evaluates the Chebyshev series only (no derivative): about half the cost, the same bits
        as ``position_velocity(...)[0]``.
        """
        return self._states(body, t_tdb_s, offset_s, velocity=False)

    def states_at(self, t_tdb_s: float, bodies=BODIES) -> dict:
        """Position and velocity of several bodies at one epoch: ``{body: (r_km (3,), v_km_s (3,))}``.

        Each DE421 segment is evaluated once (the Earth-Moon barycentre serves the Earth and the
        Moon) and all segments' Chebyshev series in one vectorised Clenshaw recurrence: about
        ten times faster than a :meth:`position_velocity` call per body, with the same bits (the
        same interval arithmetic as ``jplephem``; shorter series are padded with leading zeros,
        which leave the recurrence's bits unchanged).
        """
        st = self.epoch_states(t_tdb_s, bodies)
        W, s, s2, n = st._W, st._s, st._s2, st._n
        dw0 = dw1 = 0.0
        for i in range(1, n):  # the recurrence's w1 of each step, W[1] .. W[n - 1]
            dw2 = dw1
            dw1 = dw0
            dw0 = 2.0 * W[i] + dw1 * s2 - dw2
        rates = W[n] + s * dw0 - dw1
        rates /= st._intl
        rates *= 2.0
        rates *= _S_PER_DAY
        # each body: the sum of its chain's segments, 0 + first + second (a zero column pads the
        # shorter chains; adding +0.0 leaves the sum's bits unchanged), all bodies at once
        rates = np.concatenate([rates, np.zeros((3, 1))], axis=1)
        v = np.zeros((3, len(st.bodies)))
        for row in st._rows:
            v += rates[:, row]
        v = (v / SECONDS_PER_DAY).T.copy()
        r = st.positions
        return {b: (r[j], v[j]) for j, b in enumerate(bodies)}

    def epoch_states(self, t_tdb_s: float, bodies=BODIES) -> "EpochStates":
        """The positions of several bodies at one epoch now (:attr:`EpochStates.positions`, the
        bits of :meth:`states_at`), each velocity when asked (:meth:`EpochStates.velocity`, the
        bits of :meth:`states_at`): the Clenshaw recurrence of every segment's position in numpy,
        its derivative only for the segments of the bodies whose velocity is used."""
        bodies = tuple(bodies)
        rows, (inits, intlens, ns, base, big), npairs, col = self._epoch_plan(bodies)
        t = float(t_tdb_s)
        day = float(math.floor(t / SECONDS_PER_DAY))  # numpy.floor's value
        jd1 = J2000_JD + day
        jd2 = (t - day * SECONDS_PER_DAY) / SECONDS_PER_DAY
        if not (self._start_jd <= jd1 + jd2 <= self._end_jd):
            raise EphemerisRangeError(
                f"{self._name()} covers {_jd_to_date(self._start_jd)}..{_jd_to_date(self._end_jd)} TDB;"
                f" epoch {t!r} s outside", time_mask=True, start_jd=self._start_jd, end_jd=self._end_jd)
        index, offset = _intervals((float(jd1) - _T0) * _S_PER_DAY, float(jd2) * _S_PER_DAY, inits, intlens, ns)
        # each segment's coefficients of that interval, highest degree first, shorter series
        # padded with leading zeros: (C, 3, P)
        coef = big.take(base + index, axis=0).transpose(1, 2, 0)
        s = 2.0 * offset / intlens - 1.0
        s2 = 2.0 * s
        # Clenshaw: W[i + 2] = c_i + (s2 W[i + 1] - W[i]) from W[0] = W[1] = 0 (the recurrence's
        # w0 after step i; zeros for the initial 0.0 give the same bits elementwise); the
        # buffer's rows and the coefficients as lists of views, the product and the difference
        # in one scratch array (the same three operations a step)
        n = coef.shape[0]
        W = np.zeros((n + 1, 3, npairs))
        Wl, cl = list(W), list(coef)
        tmp = np.empty((3, npairs))
        for i in range(n - 1):
            np.multiply(s2, Wl[i + 1], out=tmp)
            np.subtract(tmp, Wl[i], out=tmp)
            np.add(cl[i], tmp, out=Wl[i + 2])
        pos = np.empty((3, npairs + 1))
        pos[:, npairs] = 0.0  # the zero column of the shorter chains
        np.add(cl[n - 1], s * Wl[n] - Wl[n - 1], out=pos[:, :npairs])
        r = np.zeros((3, len(bodies)))
        for row in rows:
            r += pos[:, row]
        return EpochStates(bodies, r.T.copy(), W, s, s2, intlens, n, rows, col)

    def positions_at(self, t_tdb_s, bodies=BODIES) -> np.ndarray:
        """Positions of several bodies at several epochs, km, shape (N, len(bodies), 3): every
        segment at every epoch in one vectorised Clenshaw recurrence (jplephem's interval
        arithmetic and series, as :meth:`states_at`; the Earth-Moon barycentre once for the
        Earth and the Moon). For a batch of epochs, e.g. the Monte Carlo sampler's pre-tests of
        its drawn poses: about a tenth of a :meth:`position` call per body.

        Raises
        ------
        UnknownBodyError, EphemerisRangeError
            As :meth:`position`.
        """
        bodies = tuple(bodies)
        t = np.atleast_1d(np.asarray(t_tdb_s, dtype=float))
        rows, (inits, intlens, ns, base, big), npairs, _ = self._epoch_plan(bodies)
        days = np.floor(t / SECONDS_PER_DAY)
        jd1 = J2000_JD + days
        jd2 = (t - days * SECONDS_PER_DAY) / SECONDS_PER_DAY
        jd = jd1 + jd2
        if not np.all((jd >= self._start_jd) & (jd <= self._end_jd)):
            for b in bodies:  # the error of position(), with its time mask
                self.position(b, t)
        il = intlens[:, None]
        index, offset = _intervals(((jd1 - _T0) * _S_PER_DAY)[None, :], (jd2 * _S_PER_DAY)[None, :], inits[:, None], il,
                                   ns[:, None])  # (P, N)
        coef = big[base[:, None] + index]  # (P, N, C, 3), highest degree first
        s = (2.0 * offset / il - 1.0)[:, :, None]
        s2 = 2.0 * s
        w0 = w1 = np.zeros((npairs, t.size, 3))
        for i in range(coef.shape[2] - 1):
            w2, w1 = w1, w0
            w0 = coef[:, :, i] + (s2 * w1 - w2)
        pos = np.concatenate([coef[:, :, -1] + (s * w0 - w1), np.zeros((1, t.size, 3))])  # zero row: shorter chains
        r = np.zeros((len(bodies), t.size, 3))
        for row in rows:
            r += pos[row]
        return r.transpose(1, 0, 2)

    def _epoch_plan(self, bodies: tuple):
        """Per tuple of bodies (kept on the object): the chain rows, the segment tables, the
        segment count and ``{body: column}`` of :meth:`epoch_states` and :meth:`positions_at`."""
        plan = self.__dict__.setdefault("_epoch_plans", {}).get(bodies)
        if plan is None:
            keys = [b.lower() if isinstance(b, str) else b for b in bodies]
            for k, b in zip(keys, bodies):
                if k not in _CHAINS:
                    raise UnknownBodyError(b, BODIES)
            self._open()
            pairs, rows = self._states_plan(tuple(keys))
            plan = self._epoch_plans[bodies] = (rows, self._states_tables(tuple(pairs)), len(pairs),
                                                {b: j for j, b in enumerate(bodies)})
        if self._kernel is None:
            self._open()
        return plan

    @staticmethod
    @functools.lru_cache(maxsize=16)
    def _states_plan(keys: tuple):
        """The segments of ``keys``' chains (each once, in first-use order) and, per chain
        position, the column of each body's segment (``len(pairs)``, a zero column, where its
        chain is shorter)."""
        pairs = list(dict.fromkeys(p for k in keys for p in _CHAINS[k]))
        col = {p: j for j, p in enumerate(pairs)}
        depth = max(len(_CHAINS[k]) for k in keys)
        rows = tuple(np.array([col[_CHAINS[k][i]] if i < len(_CHAINS[k]) else len(pairs) for k in keys], dtype=np.intp)
                     for i in range(depth))
        return pairs, rows

    def _states_tables(self, pairs: tuple):
        """For :meth:`states_at`, per tuple of segments (computed once, kept on the object):
        their ``init`` and ``intlen`` (s) and interval counts, and one table (sum of intervals,
        C, 3) of every interval's coefficients, highest degree first, zero-padded at the top to
        the longest series, with each segment's first row (``base``)."""
        cache = self.__dict__.setdefault("_states_cache", {})
        hit = cache.get(pairs)
        if hit is None:
            tables = self._cheb_tables()
            cmax = max(tables[p][2].shape[0] for p in pairs)
            ns = np.array([tables[p][2].shape[2] for p in pairs], dtype=np.intp)
            base = np.concatenate([[0], np.cumsum(ns)[:-1]]).astype(np.intp)
            big = np.zeros((int(ns.sum()), cmax, 3))
            for b0, p in zip(base.tolist(), pairs):
                c = tables[p][2]  # (C, 3, N)
                big[b0:b0 + c.shape[2], cmax - c.shape[0]:, :] = c.transpose(2, 0, 1)
            inits = np.array([float(tables[p][0]) for p in pairs])
            intlens = np.array([float(tables[p][1]) for p in pairs])
            hit = cache[pairs] = (inits, intlens, ns, base, big)
        return hit

    def _cheb_tables(self) -> dict:
        """``{(center, target): (init_s, intlen_s, coefficients (C, 3, N))}`` of every chained
        segment, highest degree first, as ``jplephem`` holds them (memory-mapped, loaded once)."""
        tables = getattr(self, "_tables", None)
        if tables is None:
            tables = {p: self._segments[p]._data for chain in _CHAINS.values() for p in chain}
            self._tables = tables
        return tables

    def _states(self, body, t_tdb_s, offset_s, *, velocity: bool):
        key = body.lower() if isinstance(body, str) else body
        if key not in _CHAINS:
            raise UnknownBodyError(body, BODIES)
        self._open()
        if isinstance(t_tdb_s, (float, int)) and isinstance(offset_s, (float, int)):
            got = self._scalar_state(key, float(t_tdb_s), float(offset_s), velocity)
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

    #: Intervals whose coefficients :meth:`_scalar_state` keeps (as Python floats) per object.
    SCALAR_INTERVALS_KEPT = 4096

    def _scalar_state(self, key, t: float, off: float, velocity: bool):
        """The fast twin of :meth:`_states` for one epoch (the light-time iterations read one
        body at one epoch at a time): jplephem's ``Segment.generate`` repeated in Python floats,
        the same IEEE operations in the same order (CPython's float ``divmod`` is numpy's, the
        Clenshaw recurrence and its derivative step by step), so the same bits as the reference
        (tested within 2 ulps, as :meth:`states_at`), at a fifth of its cost per call: no
        arrays of one element. Each interval's coefficients are kept on this object, as lists,
        for the next read (up to :attr:`SCALAR_INTERVALS_KEPT` intervals, then started again).
        None where the reference must answer (an epoch outside the kernel: it raises)."""
        days = float(math.floor(t / SECONDS_PER_DAY))  # numpy.floor's value
        jd1 = J2000_JD + days
        jd2 = ((t - days * SECONDS_PER_DAY) + off) / SECONDS_PER_DAY
        if not (self._start_jd <= jd1 + jd2 <= self._end_jd):
            return None
        kept = self.__dict__.get("_intervals")
        if kept is None or len(kept) > self.SCALAR_INTERVALS_KEPT:
            kept = self._intervals = {}
        tables = self._cheb_tables()
        pos = [0.0, 0.0, 0.0]
        vel = [0.0, 0.0, 0.0]
        for pair in _CHAINS[key]:
            init, intlen, coefs = tables[pair]
            init, intlen = float(init), float(intlen)
            index1, offset1 = divmod((jd1 - _T0) * _S_PER_DAY - init, intlen)
            index2, offset2 = divmod(jd2 * _S_PER_DAY, intlen)
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
                    rate = rate * _S_PER_DAY
                    vel[k] = vel[k] + rate
        if not velocity:
            return np.array(pos)
        return np.array(pos), np.array(vel) / SECONDS_PER_DAY

    def _name(self) -> str:
        return self.path.replace("\\", "/").rsplit("/", 1)[-1]


class EpochStates:
    """Positions of several bodies at one epoch, and each body's velocity on demand
    (:meth:`Ephemeris.epoch_states`). ``positions`` (n, 3): km, barycentric ICRS, in the order
    of ``bodies``."""

    __slots__ = ("bodies", "positions", "_W", "_s", "_s2", "_intl", "_n", "_rows", "_col", "_v")

    def __init__(self, bodies, positions, W, s, s2, intl, n, rows, col):
        self.bodies, self.positions = bodies, positions
        self._W, self._s, self._s2, self._intl, self._n, self._rows = W, s, s2, intl, n, rows
        self._col = col  # {body: row}, shared by every epoch of one body tuple (read only)
        self._v = {}

    def position(self, body):
        return self.positions[self._col[body]]

    def velocity(self, body):
        """Velocity (3,), km/s, of one of ``bodies``: the derivative recurrence of
        :meth:`Ephemeris.states_at` for that body's segments only, in Python floats (the same
        operations elementwise, so the same bits)."""
        v = self._v.get(body)
        if v is None:
            j = self._col[body]
            n, W = self._n, self._W
            out = [0.0, 0.0, 0.0]
            for row in self._rows:
                seg = int(row[j])
                if seg >= W.shape[2]:  # the zero column of a shorter chain: + 0.0
                    out = [o + 0.0 for o in out]
                    continue
                s, s2, intl = float(self._s[seg]), float(self._s2[seg]), float(self._intl[seg])
                for k, w in enumerate(W[:, :, seg].T.tolist()):
                    dw0 = dw1 = 0.0
                    for wi in w[1:n]:  # the recurrence's w1 of each step, W[1] .. W[n - 1]
                        # dw2 = dw1; dw1 = dw0; dw0 = 2.0 w1 + dw1 s2 - dw2
                        dw0, dw1 = 2.0 * wi + dw0 * s2 - dw1, dw0
                    rate = w[n] + s * dw0 - dw1
                    rate = rate / intl
                    rate = rate * 2.0
                    rate = rate * _S_PER_DAY
                    out[k] = out[k] + rate
            v = self._v[body] = np.array([o / SECONDS_PER_DAY for o in out])
        return v


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
