"""skynav's own error class and the errors of its infrastructure.

:class:`SkynavError` is the base of every error skynav raises for a user's bad input: the
command line prints ``str(error)`` on one line and exits with code 2 for any of them. Each room
adds its own classes in its ``errors`` module; the ones here are raised by the infrastructure
itself (an environment variable, an installed data file) and by every room alike. Every class
also subclasses the builtin exception a caller would expect (``ValueError``, ``OSError``).
"""

from __future__ import annotations

__all__ = ["SkynavError", "ConfigValueError", "DataFileError", "SkynavWarning"]


class SkynavError(Exception):
    """Base class of every error skynav raises for a user's bad input.

    Its message is one line naming the bad input and what is allowed; the command line prints
    it and exits with code 2.

    Examples
    --------
    >>> from skynav.infra.errors import SkynavError
    >>> from skynav.scenes import Camera
    >>> try:
    ...     Camera(width=0, height=64, focal_length_mm=40.0, pixel_pitch_um=10.0)
    ... except SkynavError as exc:
    ...     print(exc)
    camera.width = 0 is not allowed; expected a positive integer
    """


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

    Examples
    --------
    >>> from skynav.infra.errors import ConfigValueError
    >>> from skynav.scenes import Camera
    >>> try:
    ...     Camera(width=64, height=64, focal_length_mm=40.0, pixel_pitch_um=10.0, exposure_s=0.0)
    ... except ConfigValueError as exc:
    ...     print(exc.key, "|", exc)
    camera.exposure_s | camera.exposure_s = 0.0 is not allowed; expected > 0 (seconds)
    """

    def __init__(self, key: str, value, allowed: str):
        self.key = key
        self.value = value
        self.allowed = allowed
        super().__init__(f"{key} = {value!r} is not allowed; expected {allowed}")


class DataFileError(SkynavError, OSError):
    """An installed data file (ephemeris, catalog) is missing or unreadable.

    Examples
    --------
    >>> import io
    >>> from skynav.infra.errors import DataFileError
    >>> from skynav.scenes.catalog_hipparcos import read_hipparcos
    >>> try:
    ...     read_hipparcos(io.BytesIO(b""))
    ... except DataFileError as exc:
    ...     print(exc)
    Hipparcos catalog file is empty
    """


class SkynavWarning(UserWarning):
    r"""An absurd but possible input (a 173 deg field, ``k1: 1000``, 1e6 deg/s).

    The work goes on and the command line prints one ``skynav: warning:`` line.

    Examples
    --------
    >>> import io, warnings
    >>> from skynav.infra.errors import SkynavWarning
    >>> from skynav.scenes import read_scene_file
    >>> text = ("epoch: 2030-01-01T00:00:00\n"
    ...         "observer: {position_km: [1.5e8, 0, 0], velocity_km_s: [0, 30, 0]}\n"
    ...         "attitude: {ra_deg: 10, dec_deg: 0, angular_velocity_deg_s: [0, 0, 1000]}\n")
    >>> with warnings.catch_warnings(record=True) as caught:
    ...     warnings.simplefilter("always")
    ...     spec = read_scene_file(io.StringIO(text), "spin.yaml")
    >>> caught[0].category is SkynavWarning
    True
    >>> print(caught[0].message)
    attitude.angular_velocity_deg_s: 1000 deg/s is more than one turn per second; the stars are long streaks
    """
