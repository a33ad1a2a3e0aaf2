"""Brown-Conrady lens distortion: the map between ideal and distorted normalised coordinates.

The camera (:class:`~skynav.scenes.camera.Camera`) applies it between the pinhole and ``K``:
``[x, y, 1]^T ~ K [distort(x/z, y/z), 1]^T``. A frozen, hashable value object like the camera
that carries it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True, kw_only=True)
class BrownConrady:
    """Brown-Conrady lens distortion on normalised coordinates (x/z, y/z).

    ``r2 = x^2 + y^2``, radial ``1 + k1 r2 + k2 r2^2 + k3 r2^3``, tangential ``p1``, ``p2``
    (OpenCV's ordering and signs):
    ``xd = x radial + 2 p1 x y + p2 (r2 + 2 x^2)``,
    ``yd = y radial + p1 (r2 + 2 y^2) + 2 p2 x y``.

    Parameters
    ----------
    k1, k2, k3 : float
        Radial coefficients (of ``r2``, ``r2^2``, ``r2^3``; normalised coordinates, no unit).
    p1, p2 : float
        Tangential (decentring) coefficients, no unit.

    References
    ----------
    Brown, D. C. (1966), "Decentering distortion of lenses", Photogrammetric Engineering 32(3),
    444-462; Conrady, A. E. (1919), MNRAS 79, 384. The ordering is OpenCV's
    (``cv2.projectPoints``), docs/conventions.md "Choices made in the code".

    Examples
    --------
    >>> from skynav.scenes import BrownConrady
    >>> d = BrownConrady(k1=-0.05, p1=1e-4)
    >>> xd, yd = d.distort(np.array([0.1]), np.array([0.05]))
    >>> x, y = d.undistort(xd, yd)
    >>> bool(np.allclose([x[0], y[0]], [0.1, 0.05], atol=1e-14))
    True
    """

    k1: float = 0.0
    k2: float = 0.0
    k3: float = 0.0
    p1: float = 0.0
    p2: float = 0.0

    @property
    def is_identity(self) -> bool:
        """No distortion: every coefficient is 0."""
        return self.k1 == self.k2 == self.k3 == self.p1 == self.p2 == 0.0

    def distort(self, xn, yn):
        """Distorted normalised coordinates of ideal normalised coordinates.

        Parameters
        ----------
        xn, yn : numpy.ndarray
            Ideal normalised coordinates ``x/z``, ``y/z`` (no unit), any shape (broadcast).

        Returns
        -------
        xd, yd : numpy.ndarray
            Distorted normalised coordinates.
        """
        r2 = xn * xn + yn * yn
        radial = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3))
        xd = xn * radial + 2.0 * self.p1 * xn * yn + self.p2 * (r2 + 2.0 * xn * xn)
        yd = yn * radial + self.p1 * (r2 + 2.0 * yn * yn) + 2.0 * self.p2 * xn * yn
        return xd, yd

    def jacobian(self, xn, yn):
        """The derivatives of :meth:`distort`.

        Parameters
        ----------
        xn, yn : numpy.ndarray
            Ideal normalised coordinates (no unit).

        Returns
        -------
        tuple of numpy.ndarray
            ``(dxd/dxn, dxd/dyn, dyd/dxn, dyd/dyn)``.
        """
        r2 = xn * xn + yn * yn
        radial = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3))
        dradial_dr2 = self.k1 + r2 * (2.0 * self.k2 + 3.0 * r2 * self.k3)
        dxx = radial + 2 * xn * xn * dradial_dr2 + 2 * self.p1 * yn + 6 * self.p2 * xn
        dxy = 2 * xn * yn * dradial_dr2 + 2 * self.p1 * xn + 2 * self.p2 * yn
        dyx = 2 * xn * yn * dradial_dr2 + 2 * self.p1 * xn + 2 * self.p2 * yn
        dyy = radial + 2 * yn * yn * dradial_dr2 + 6 * self.p1 * yn + 2 * self.p2 * xn
        return dxx, dxy, dyx, dyy

    def undistort(self, xd, yd, *, iterations: int = 20, tol: float = 1e-15):
        """Ideal normalised coordinates of distorted ones, by Newton's method.

        Converges quadratically from the distorted point as first guess; for the mild
        distortions of navigation cameras 3-5 iterations reach 1e-15.

        Parameters
        ----------
        xd, yd : array_like
            Distorted normalised coordinates (no unit).
        iterations : int
            Most Newton steps.
        tol : float
            Stop when every point's step ``|dx| + |dy|`` is below this.

        Returns
        -------
        x, y : numpy.ndarray
            Ideal normalised coordinates.
        """
        xd = np.asarray(xd, dtype=float)
        yd = np.asarray(yd, dtype=float)
        if self.is_identity:
            return xd.copy(), yd.copy()
        x, y = xd.copy(), yd.copy()
        for _ in range(iterations):
            fx, fy = self.distort(x, y)
            rx, ry = fx - xd, fy - yd
            a, b, c, d = self.jacobian(x, y)
            det = a * d - b * c
            dx = (d * rx - b * ry) / det
            dy = (-c * rx + a * ry) / det
            x = x - dx
            y = y - dy
            if np.all(np.abs(dx) + np.abs(dy) < tol):
                break
        return x, y
