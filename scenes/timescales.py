"""Epochs: astropy ``Time`` at the edge, TDB seconds past J2000 inside.

astropy is loaded on the first epoch conversion, not with this module (``astropy.time`` takes
about 0.7 s to import, and reading a dataset or printing ``skynav --help`` converts none); loading
it turns astropy's IERS auto-download off: skynav never touches the network at run time. TDB-TT
is computed by astropy/ERFA analytically and needs no IERS table.
"""

from __future__ import annotations

import sys
from typing import TYPE_CHECKING

import numpy as np

from .constants import J2000_JD, SECONDS_PER_DAY

if TYPE_CHECKING:
    from astropy.time import Time


def _astropy_time():
    """astropy's ``Time`` class, with IERS auto-download off (module docstring)."""
    # astropy.time: ~0.7 s to import, loaded on the first epoch conversion (module docstring)
    from astropy.time import Time
    from astropy.utils import iers

    iers.conf.auto_download = False
    iers.conf.auto_max_age = None
    return Time


def _is_time(epoch) -> bool:
    """Whether ``epoch`` is an astropy ``Time`` (one exists only once astropy.time is loaded)."""
    module = sys.modules.get("astropy.time")
    return module is not None and isinstance(epoch, module.Time)


def _is_float_epoch(epoch) -> bool:
    return not (_is_time(epoch) or isinstance(epoch, str)) and np.issubdtype(np.asarray(epoch).dtype, np.number)


def to_time(epoch) -> Time:
    """Coerce an epoch to an astropy ``Time``: a ``Time``, an ISO string in TDB, or a float.

    A float epoch (scalar or array) is always TDB seconds past J2000 (JD 2451545.0 TDB), the one
    meaning of a float epoch in skynav (names end in ``_tdb_s``); a Julian date goes through
    ``Time(jd, format="jd", scale="tdb")`` explicitly.

    Parameters
    ----------
    epoch : astropy.time.Time, str, float or array_like of float
        A ``Time`` (returned as it is), an ISO date read in the TDB scale, or TDB seconds past
        J2000, s.

    Returns
    -------
    astropy.time.Time
        The epoch (scale TDB unless a ``Time`` of another scale was given); an array of epochs
        for an array of seconds.

    Examples
    --------
    >>> from skynav.scenes import to_time
    >>> to_time("2030-01-01T00:00:00").isot
    '2030-01-01T00:00:00.000'
    >>> to_time(0.0).jd
    2451545.0
    """
    if _is_time(epoch):
        _astropy_time()  # a Time made elsewhere: its conversions must not download IERS tables either
        return epoch
    if isinstance(epoch, str):
        return _astropy_time()(epoch, scale="tdb")
    return time_from_tdb_seconds(epoch)


def tdb_seconds(epoch) -> np.ndarray | float:
    """TDB seconds past J2000 (JD 2451545.0 TDB) of an epoch, as float64.

    Parameters
    ----------
    epoch : astropy.time.Time, str, float or array_like of float
        As for :func:`to_time`; a float (or array of floats) is returned as it is: it already is
        TDB seconds past J2000.

    Returns
    -------
    float or numpy.ndarray
        TDB seconds past J2000, s (an array for an array epoch).

    Examples
    --------
    >>> from skynav.scenes import tdb_seconds
    >>> tdb_seconds("2000-01-02T12:00:00")
    86400.0
    """
    if _is_float_epoch(epoch):
        s = np.asarray(epoch, dtype=float)
        return float(s) if np.ndim(s) == 0 else s
    t = to_time(epoch).tdb
    s = ((t.jd1 - J2000_JD) + t.jd2) * SECONDS_PER_DAY
    return float(s) if np.ndim(s) == 0 else s


def tdb_jd(epoch) -> tuple:
    """Two-part Julian date (jd1, jd2) in TDB for full precision."""
    t = to_time(epoch).tdb
    return t.jd1, t.jd2


def time_from_tdb_seconds(t_tdb_s) -> Time:
    """Epoch of TDB seconds past J2000 (inverse of :func:`tdb_seconds`).

    Parameters
    ----------
    t_tdb_s : float or array_like of float
        TDB seconds past J2000 (JD 2451545.0 TDB), s.

    Returns
    -------
    astropy.time.Time
        The epoch in the TDB scale, as a two-part Julian date (J2000 and the days after it, so
        no precision is lost).

    Examples
    --------
    >>> from skynav.scenes import time_from_tdb_seconds
    >>> time_from_tdb_seconds(86400.0).isot
    '2000-01-02T12:00:00.000'
    """
    t_tdb_s = np.asarray(t_tdb_s, dtype=float)
    return _astropy_time()(J2000_JD, t_tdb_s / SECONDS_PER_DAY, format="jd", scale="tdb")
