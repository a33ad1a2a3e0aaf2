"""The sky WCS of a frame with lens distortion: FITS TAN-SIP fitted to the camera's Brown-Conrady
model over the whole sensor.

The SIP convention (Shupe et al. 2005) keeps the TAN WCS of :func:`~.fits_files.tan_wcs_header`
(``CD``, ``CRPIX``, ``CRVAL`` of the undistorted pinhole) and adds polynomials on the pixel
offsets ``(u, v) = p - CRPIX`` from the principal point:

- forward ``A, B`` (pixel to sky): ``U = u + A(u, v)``, ``V = v + B(u, v)``, where ``(U, V)``
  are the offsets the undistorted pinhole would give (what ``CD`` maps to the tangent plane);
- inverse ``AP, BP`` (sky to pixel): ``u = U + AP(U, V)``, ``v = V + BP(U, V)``.

With ``K2 = K[:2, :2]`` and ``D`` the distortion on normalised coordinates
(:class:`~skynav.scenes.distortion.BrownConrady`), the exact maps are
``(U, V) = K2 D^-1(K2^-1 (u, v))`` and ``(u, v) = K2 D(K2^-1 (U, V))``. Neither is a polynomial
in general (``D^-1`` never is), so both are fitted by least squares on a grid covering the
sensor edge to edge, at the lowest order (2 to 9) whose largest residual on a second, denser
grid is within :data:`SIP_TARGET_PX`; the header records the order and both residuals
(``SIPMXERR``, ``SIPIMXER``, px). Terms: ``2 <= p + q <= order`` for ``A, B`` (the linear part is
``CD``'s), ``1 <= p + q <= order`` for ``AP, BP``.

References
----------
Shupe, D. L., et al. (2005), "The SIP Convention for Representing Distortion in FITS Image
Headers", ASP Conference Series 347, 491.
Calabretta & Greisen (2002), A&A 395, 1077 (TAN).
"""

from __future__ import annotations

import functools
import warnings

import numpy as np

from skynav.scenes.camera import Camera

from .fits_files import tan_wcs_header

__all__ = ["SIP_TARGET_PX", "SIP_MAX_ORDER", "sip_fit", "sky_wcs_header"]

#: Largest residual of the fitted polynomials the fit aims at, px: ten times below the 0.01 px a
#: FITS user may expect of the header, leaving room for WCSLIB's iterative inversion.
SIP_TARGET_PX = 1e-3
#: Highest SIP order tried (WCSLIB and astropy read any; 9 keeps the fit well conditioned).
SIP_MAX_ORDER = 9


def _grid(width: int, height: int, n: int):
    """Pixel coordinates of an ``n x n`` grid covering the sensor edge to edge (centres of the
    corner pixels are at 0 and W-1; their outer edges at -0.5 and W-0.5)."""
    x, y = np.meshgrid(np.linspace(-0.5, width - 0.5, n), np.linspace(-0.5, height - 0.5, n))
    return x.ravel(), y.ravel()


def _terms(order: int, lowest: int):
    return [(p, t - p) for t in range(lowest, order + 1) for p in range(t, -1, -1)]


def _design(u, v, terms, scale: float):
    s, t = u / scale, v / scale
    return np.stack([s ** p * t ** q for p, q in terms], axis=1)


def _fit(u, v, du, dv, order: int, lowest: int, scale: float):
    """``{(p, q): (a, b)}`` coefficients (px) of the least-squares fit ``du ~ a(u, v)``."""
    terms = _terms(order, lowest)
    coef, *_ = np.linalg.lstsq(_design(u, v, terms, scale), np.stack([du, dv], axis=1), rcond=None)
    # fitted on (u/scale, v/scale): a_pq (u/scale)^p (v/scale)^q = (a_pq / scale^(p+q)) u^p v^q
    return {(p, q): (coef[i, 0] / scale ** (p + q), coef[i, 1] / scale ** (p + q)) for i, (p, q) in enumerate(terms)}


def _evaluate(coef, u, v, scale: float):
    """``(a(u, v), b(u, v))`` of :func:`_fit`'s coefficients, px."""
    terms = list(coef)
    c = np.array([[coef[t][0] * scale ** sum(t), coef[t][1] * scale ** sum(t)] for t in terms])
    ab = _design(u, v, terms, scale) @ c
    return ab[:, 0], ab[:, 1]


def _exact_maps(cam: Camera):
    """(undistort, distort) on pixel offsets from the principal point, exact (Newton for the
    inverse, as :meth:`Camera.back_project`)."""
    K2 = np.asarray(cam.K, dtype=float)[:2, :2]
    K2inv = np.linalg.inv(K2)
    d = cam.distortion

    def through(f, u, v):
        n = K2inv @ np.stack([u, v])
        x, y = f(n[0], n[1])
        out = K2 @ np.stack([x, y])
        return out[0], out[1]

    return (lambda u, v: through(d.undistort, u, v)), (lambda u, v: through(d.distort, u, v))


@functools.lru_cache(maxsize=16)
def sip_fit(cam: Camera):
    """The SIP polynomials of a distorting camera: ``(order, A/B coefficients, AP/BP coefficients,
    forward residual px, inverse residual px)``, coefficients ``{(p, q): (A_p_q, B_p_q)}``;
    residuals are the largest over a 73 x 73 grid of the sensor (edge to edge, not the fit's
    41 x 41), against the exact Brown-Conrady maps. Cached per camera geometry (a dataset's
    frames share one camera; :class:`Camera` is a hashable value)."""
    undistort, _ = _exact_maps(cam)
    cx, cy = float(cam.K[0, 2]), float(cam.K[1, 2])
    scale = max(cam.width, cam.height) / 2.0
    x, y = _grid(cam.width, cam.height, 41)
    xc, yc = _grid(cam.width, cam.height, 73)
    u, v = x - cx, y - cy
    U, V = undistort(u, v)
    uc, vc = xc - cx, yc - cy
    Uc, Vc = undistort(uc, vc)
    best = None
    for order in range(2, SIP_MAX_ORDER + 1):
        fwd = _fit(u, v, U - u, V - v, order, 2, scale)
        inv = _fit(U, V, u - U, v - V, order, 1, scale)
        a, b = _evaluate(fwd, uc, vc, scale)
        err_f = float(np.max(np.hypot(uc + a - Uc, vc + b - Vc)))
        ap, bp = _evaluate(inv, Uc, Vc, scale)
        err_i = float(np.max(np.hypot(Uc + ap - uc, Vc + bp - vc)))
        best = (order, fwd, inv, err_f, err_i)
        if max(err_f, err_i) <= SIP_TARGET_PX:
            break
    return best


def sky_wcs_header(cam: Camera, R_cam_icrs) -> dict:
    """The WCS of a frame: TAN for an undistorted camera (:func:`~.fits_files.tan_wcs_header`),
    TAN-SIP fitted to the distortion otherwise (this module's docstring).

    Values are plain or ``(value, comment)``. ``SIPMXERR`` / ``SIPIMXER``: the largest residual
    of ``A, B`` / ``AP, BP`` over the sensor, px. A distortion that order 9 cannot follow to
    0.01 px (far beyond a navigation camera's) warns and still writes the best fit, its residual
    in the header.
    """
    h = tan_wcs_header(cam.K, cam.width, cam.height, R_cam_icrs)
    if cam.distortion.is_identity:
        return h
    order, fwd, inv, err_f, err_i = sip_fit(cam)
    if max(err_f, err_i) > 0.01:
        warnings.warn(f"the SIP fit of the camera's distortion leaves {max(err_f, err_i):.3g} px at order "
                      f"{order}; the FITS WCS is that far from the rendered pixels", stacklevel=2)
    h["CTYPE1"], h["CTYPE2"] = "RA---TAN-SIP", "DEC--TAN-SIP"
    for name, coef, col in (("A", fwd, 0), ("B", fwd, 1), ("AP", inv, 0), ("BP", inv, 1)):
        h[f"{name}_ORDER"] = order
        for (p, q), c in coef.items():
            h[f"{name}_{p}_{q}"] = float(c[col])
    h["SIPMXERR"] = (err_f, "[px] max residual of A, B over the sensor")
    h["SIPIMXER"] = (err_i, "[px] max residual of AP, BP over the sensor")
    return h
