"""Epochs: astropy ``Time`` at the edge, TDB seconds past J2000 inside.

Importing this module turns astropy's IERS auto-download off: skynav never touches the
network at run time. TDB-TT is computed by astropy/ERFA analytically and needs no IERS table.
"""

from __future__ import annotations

import numpy as np
from astropy.time import Time
from astropy.utils import iers

from .constants import J2000_JD, SECONDS_PER_DAY

iers.conf.auto_download = False
iers.conf.auto_max_age = None


def to_time(epoch) -> Time:
    """Coerce an epoch (``Time``, ISO string in TDB, or Julian date TDB as float) to ``Time``."""
    if isinstance(epoch, Time):
        return epoch
    if isinstance(epoch, str):
        return Time(epoch, scale="tdb")
    return Time(np.asarray(epoch, dtype=float), format="jd", scale="tdb")


def tdb_seconds(epoch) -> np.ndarray | float:
    """TDB seconds past J2000 (JD 2451545.0 TDB) of an epoch, as float64."""
    t = to_time(epoch).tdb
    s = ((t.jd1 - J2000_JD) + t.jd2) * SECONDS_PER_DAY
    return float(s) if np.ndim(s) == 0 else s


def tdb_jd(epoch) -> tuple:
    """Two-part Julian date (jd1, jd2) in TDB for full precision."""
    t = to_time(epoch).tdb
    return t.jd1, t.jd2


def time_from_tdb_seconds(t_s) -> Time:
    """Inverse of :func:`tdb_seconds`."""
    t_s = np.asarray(t_s, dtype=float)
    return Time(J2000_JD, t_s / SECONDS_PER_DAY, format="jd", scale="tdb")
