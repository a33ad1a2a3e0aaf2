"""Errors of the renderer room.

Every class subclasses :class:`skynav.infra.errors.SkynavError` (so the command line prints one
line and exits with code 2) and the builtin exception a caller would expect. Configuration values
outside their range raise :class:`~skynav.infra.errors.ConfigValueError` (re-exported here);
the file-format errors live with the writers and readers on the datasets side.
"""

from __future__ import annotations

from skynav.infra.errors import ConfigValueError, SkynavError

__all__ = [
    "SkynavError",
    "ConfigValueError",
    "BackendUnavailableError",
    "SensorInputError",
    "ProjectionCropError",
]


class BackendUnavailableError(SkynavError, RuntimeError):
    """A Dr.Jit backend was requested explicitly but does not work on this machine.

    Raised when ``RenderOptions(backend="llvm")`` or ``"cuda"`` (``--backend``) names a backend
    that is not there (no libLLVM >= 19, no CUDA GPU); its line names the backend, why, and
    ``backend='numpy' or 'auto'`` as what works. ``"auto"`` never raises it.

    Examples
    --------
    >>> from skynav.renderer import BackendUnavailableError
    >>> from skynav.scenes import SkynavError
    >>> issubclass(BackendUnavailableError, SkynavError), issubclass(BackendUnavailableError, RuntimeError)
    (True, True)
    """


class SensorInputError(SkynavError, ValueError):
    """An image or exposure handed to the sensor is not acceptable.

    Examples
    --------
    >>> from skynav.renderer import Sensor, SensorInputError
    >>> from skynav.scenes import SensorParams
    >>> sensor = Sensor(SensorParams(), (4, 5))
    >>> try:
    ...     sensor.expose(np.zeros((3, 3)), 0.1, np.random.default_rng(0), backend="numpy")
    ... except SensorInputError as exc:
    ...     print(exc)
    electrons has shape (3, 3); this sensor is (4, 5)
    """


class ProjectionCropError(SkynavError, ValueError):
    """A resolved body's crop window cannot be ray-traced through the projection.

    Its lines of sight are not finite or span a hemisphere or more (the crop's rays are
    interpolated on the plane tangent to its central line of sight).

    Parameters
    ----------
    body : str
        Name of the body.
    window : tuple of int
        ``(x0, y0, w, h)`` of the crop, px.
    why : str
        What is wrong with the window's lines of sight.

    Attributes
    ----------
    body : str
        Name of the body.
    window : tuple of int
        ``(x0, y0, w, h)`` of the crop, px.

    Examples
    --------
    >>> from skynav.renderer import ProjectionCropError
    >>> print(ProjectionCropError("earth", (0, 0, 64, 64), "spans 90 deg or more from its central line of sight"))
    resolved body 'earth': crop (x0, y0, w, h) = (0, 0, 64, 64) spans 90 deg or more from its central line of sight; render it as a point (RenderOptions(resolved=False)) or use a projection defined over the crop
    """

    def __init__(self, body: str, window: tuple, why: str):
        self.body = body
        self.window = tuple(int(v) for v in window)
        super().__init__(f"resolved body {body!r}: crop (x0, y0, w, h) = {self.window} {why}; "
                         "render it as a point (RenderOptions(resolved=False)) or use a projection defined over the crop")
