"""Errors of the sky model.

Every class subclasses skynav's own :class:`~skynav.infra.errors.SkynavError` (the command line
prints ``str(error)`` on one line and exits with code 2) and the builtin exception a caller would
expect (``ValueError``, ``KeyError``), so generic handlers keep working, and carries the data that
explains it.
"""

from __future__ import annotations

from skynav.infra.errors import ConfigValueError, SkynavError


class SceneFileError(SkynavError, ValueError):
    """A scene/recipe file cannot be read or is malformed.

    Examples
    --------
    >>> import io
    >>> from skynav.scenes import SceneFileError, read_scene_file
    >>> try:
    ...     read_scene_file(io.StringIO("camera: [1, 2"), "bad.yaml")
    ... except SceneFileError as exc:
    ...     print(exc)
    bad.yaml: malformed YAML at line 1, column 14: expected ',' or ']', but got '<stream end>'
    """


class EphemerisRangeError(SkynavError, ValueError):
    """Epochs outside the span of the ephemeris kernel.

    Attributes
    ----------
    time_mask : ndarray of bool
        True where the epoch is outside the kernel.
    start_jd, end_jd : float or None
        The kernel's span, Julian dates (TDB).

    Examples
    --------
    >>> from skynav.scenes import EphemerisRangeError, default_ephemeris
    >>> try:
    ...     default_ephemeris().position_velocity("earth", 4e9)   # TDB s past J2000: year 2126
    ... except EphemerisRangeError as exc:
    ...     print(exc)
    de421.bsp covers 1899-07-29..2053-10-09 TDB; 1 of 1 epochs outside (see .time_mask)
    """

    def __init__(self, message: str, time_mask=None, start_jd=None, end_jd=None):
        self.time_mask = time_mask
        self.start_jd = start_jd
        self.end_jd = end_jd
        super().__init__(message)


class UnknownBodyError(SkynavError, KeyError):
    """A body name that skynav does not know.

    Attributes
    ----------
    name : str
        The name given.
    allowed : tuple of str
        The names known where it was given.

    Examples
    --------
    >>> from skynav.scenes import UnknownBodyError, planet_v_mag
    >>> try:
    ...     planet_v_mag("pluto", 5.9e9, 5.8e9, 0.01)
    ... except UnknownBodyError as exc:
    ...     print(exc)
    unknown body 'pluto'; known bodies: mercury, venus, earth, moon, mars, jupiter, saturn, uranus, neptune
    """

    def __init__(self, name: str, allowed):
        self.name = name
        self.allowed = tuple(allowed)
        super().__init__(name)

    def __str__(self) -> str:  # KeyError would print the repr of the key only
        return f"unknown body {self.name!r}; known bodies: {', '.join(self.allowed)}"



class LambertError(SkynavError, ValueError):
    """A Lambert problem with no solution for the inputs (or a solver failure).

    Examples
    --------
    >>> from skynav.scenes import LambertError, solve_lambert
    >>> try:
    ...     solve_lambert([1.0, 0.0, 0.0], [2.0, 0.0, 0.0], 1.0, 1.0)
    ... except LambertError as exc:
    ...     print(exc)
    r1 and r2 are collinear: the transfer plane is undefined
    """


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

    Examples
    --------
    >>> from skynav.scenes import Camera, MovedKeyError
    >>> try:
    ...     Camera.from_dict({"width": 64, "height": 64, "focal_length_mm": 40.0,
    ...                       "pixel_pitch_um": 10.0, "limiting_v_mag": 7.0})
    ... except MovedKeyError as exc:
    ...     print(exc)
    camera.limiting_v_mag has moved: write it as visibility.limiting_v_mag (value given: 7.0)
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

    Examples
    --------
    >>> from skynav.scenes import ObserverInsideBodyError, default_ephemeris, sky_bodies
    >>> r, v = default_ephemeris().position_velocity("earth", 0.0)
    >>> try:
    ...     sky_bodies(0.0, r + [100.0, 0.0, 0.0], v)
    ... except ObserverInsideBodyError as exc:
    ...     print(exc.body, round(exc.distance_km, 3), exc.radius_km)
    earth 100.0 6371.0084
    """

    def __init__(self, body: str, distance_km: float, radius_km: float, position_km=()):
        self.body = body
        self.distance_km = float(distance_km)
        self.radius_km = float(radius_km)
        self.position_km = tuple(float(x) for x in position_km)
        super().__init__(f"observer.position_km = {[round(x, 3) for x in self.position_km]} is inside {body}: "
                         f"{self.distance_km:.3f} km from its centre, radius {self.radius_km:g} km")
