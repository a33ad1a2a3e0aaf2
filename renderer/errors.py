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
    """A Dr.Jit backend was requested explicitly but does not work on this machine."""


class SensorInputError(SkynavError, ValueError):
    """An image or exposure handed to the sensor is not acceptable."""


class ProjectionCropError(SkynavError, ValueError):
    """A resolved body's crop window cannot be ray-traced through the projection: its lines of
    sight are not finite or span a hemisphere or more (the crop's rays are interpolated on the
    plane tangent to its central line of sight).

    Attributes
    ----------
    body : str
        Name of the body.
    window : tuple of int
        ``(x0, y0, w, h)`` of the crop, px.
    """

    def __init__(self, body: str, window: tuple, why: str):
        self.body = body
        self.window = tuple(int(v) for v in window)
        super().__init__(f"resolved body {body!r}: crop (x0, y0, w, h) = {self.window} {why}; "
                         "render it as a point (RenderOptions(resolved=False)) or use a projection defined over the crop")
