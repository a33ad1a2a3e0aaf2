"""Errors of the sky model.

Every class also subclasses the builtin exception a caller would expect (``ValueError``,
``KeyError``), so generic handlers keep working, and carries the data that explains it. The
command line prints ``str(error)`` on one line and exits with code 2 for any ``SkynavError``.
"""

from __future__ import annotations


class SkynavError(Exception):
    """Base class of every error skynav raises for a user's bad input."""


class ConfigValueError(SkynavError, ValueError):
    """A configuration value is outside what is allowed.

    Parameters
    ----------
    key : str
        Dotted name of the offending key, e.g. ``camera.exposure_s``.
    value : object
        The value given.
    allowed : str
        What is allowed, in words, e.g. ``"> 0"`` or ``"one of: a, b"``.
    """

    def __init__(self, key: str, value, allowed: str):
        self.key = key
        self.value = value
        self.allowed = allowed
        super().__init__(f"{key} = {value!r} is not allowed; expected {allowed}")


class SceneFileError(SkynavError, ValueError):
    """A scene/recipe file cannot be read or is malformed."""


class EphemerisRangeError(SkynavError, ValueError):
    """Epochs outside the span of the ephemeris kernel.

    Attributes
    ----------
    time_mask : ndarray of bool
        True where the epoch is outside the kernel.
    """

    def __init__(self, message: str, time_mask=None, start_jd=None, end_jd=None):
        self.time_mask = time_mask
        self.start_jd = start_jd
        self.end_jd = end_jd
        super().__init__(message)


class UnknownBodyError(SkynavError, KeyError):
    """A body name that skynav does not know."""

    def __init__(self, name: str, allowed):
        self.name = name
        self.allowed = tuple(allowed)
        super().__init__(name)

    def __str__(self) -> str:  # KeyError would print the repr of the key only
        return f"unknown body {self.name!r}; known bodies: {', '.join(self.allowed)}"


class DataFileError(SkynavError, OSError):
    """An installed data file (ephemeris, catalog) is missing or unreadable."""


class LambertError(SkynavError, ValueError):
    """A Lambert problem with no solution for the inputs (or a solver failure)."""


class MovedKeyError(ConfigValueError):
    """A configuration key that has moved elsewhere (names the new key).

    Parameters
    ----------
    key : str
        Dotted name of the old key, e.g. ``camera.limiting_v_mag``.
    value : object
        The value given.
    new_key : str
        Where it lives now, e.g. ``visibility.limiting_v_mag``.
    """

    def __init__(self, key: str, value, new_key: str):
        super().__init__(key, value, f"it has moved to {new_key}")
        self.new_key = new_key
        self.args = (f"{key} has moved: write it as {new_key} (value given: {value!r})",)

    def __str__(self) -> str:
        return self.args[0]


class ObserverInsideBodyError(SkynavError, ValueError):
    """The observer is inside a solar-system body (closer to its centre than its radius).

    Attributes
    ----------
    body : str
        The body's name.
    distance_km, radius_km : float
        Observer-to-centre distance and the body's mean radius, km.
    position_km : tuple of float, shape (3,)
        The observer's barycentric ICRS position, km.
    """

    def __init__(self, body: str, distance_km: float, radius_km: float, position_km=()):
        self.body = body
        self.distance_km = float(distance_km)
        self.radius_km = float(radius_km)
        self.position_km = tuple(float(x) for x in position_km)
        super().__init__(f"observer.position_km = {[round(x, 3) for x in self.position_km]} is inside {body}: "
                         f"{self.distance_km:.3f} km from its centre, radius {self.radius_km:g} km")


class SkynavWarning(UserWarning):
    """An absurd but possible input (a 173 deg field, ``k1: 1000``, 1e6 deg/s): the work goes on
    and the command line prints one ``skynav: warning:`` line."""
