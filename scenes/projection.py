"""The Projection protocol: pixel <-> camera-frame line of sight, both directions, vectorised.

Everything that turns a direction into a pixel (or back) goes through this seam: the pinhole +
distortion :class:`~skynav.scenes.camera.Camera` implements it, and so can a per-pixel
line-of-sight table (a hardware-in-the-loop bench screen seen through its collimator). The
renderer places point sources with :meth:`Projection.project` and takes the rays of resolved
bodies from :meth:`Projection.line_of_sight`, so it never assumes a pinhole.

Pixel convention (docs/conventions.md): ``(x, y)`` with x along columns and y along rows, the CENTRE of
the top-left pixel at ``(0.0, 0.0)``. Camera frame: +z boresight, +x right, +y down.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np


@runtime_checkable
class Projection(Protocol):
    """Pixel <-> line of sight of an image of ``width`` x ``height`` pixels.

    Attributes
    ----------
    width, height : int
        Image size, px.

    Examples
    --------
    The pinhole camera is one; so is any object with these two methods and the size:

    >>> from skynav.scenes import Camera, Projection
    >>> cam = Camera(width=64, height=48, focal_length_mm=40.0, pixel_pitch_um=10.0)
    >>> isinstance(cam, Projection)
    True
    >>> xy = cam.project(np.array([0.001, -0.002, 1.0]))
    >>> xy, cam.line_of_sight(xy) * np.sqrt(1 + 0.001**2 + 0.002**2)
    (array([35.5, 15.5]), array([ 0.001, -0.002,  1.   ]))
    """

    width: int
    height: int

    def project(self, v_cam: np.ndarray) -> np.ndarray:
        """Pixel coordinates of camera-frame directions.

        Parameters
        ----------
        v_cam : ndarray, shape (..., 3)
            Directions in the camera frame (any length).

        Returns
        -------
        ndarray, shape (..., 2), px
            ``(x, y)``; NaN where the direction cannot reach the image plane.
        """
        ...

    def line_of_sight(self, xy_px: np.ndarray) -> np.ndarray:
        """Unit camera-frame directions seen at pixel coordinates (the inverse of :meth:`project`).

        Parameters
        ----------
        xy_px : ndarray, shape (..., 2)
            Pixel coordinates ``(x, y)``, px.

        Returns
        -------
        ndarray, shape (..., 3)
            Unit vectors in the camera frame.
        """
        ...
