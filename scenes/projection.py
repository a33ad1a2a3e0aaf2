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
        xy_px : ndarray, shape (..., 2), px

        Returns
        -------
        ndarray, shape (..., 3)
            Unit vectors in the camera frame.
        """
        ...
