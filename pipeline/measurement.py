"""Planet-centroid measurement model of the navigation filter (Andreis et al. (2024), Sec. 4.2).

Core module: NumPy only. The measurement is the pixel position of a planet's centroid. The
model maps the spacecraft state ``x = (r, v)`` (barycentric ICRS, km and km/s) to it through

1. first-order light-time (Andreis et al. (2024), Eq. 26-31): with the planet moving on a straight line over
   the light time, ``|rho - v_p tau| = c tau`` with ``rho = r_p(t) - r`` is a quadratic in tau,
   ``(c^2 - v_p^2) tau^2 + 2 (rho . v_p) tau - rho^2 = 0``, whose positive root is
   ``tau = (-(rho . v_p) + sqrt((rho . v_p)^2 + (c^2 - v_p^2) rho^2)) / (c^2 - v_p^2)``;
   the line of sight is ``l = (rho - v_p tau) / |rho - v_p tau|`` (Eq. 32);
2. first-order aberration (Eq. 33): ``w = l + beta - (l . beta) l``, ``beta = v / c`` (unit length
   to first order; the projection is homogeneous so ``w`` is not renormalised);
3. the calibrated camera (Eq. 34-35): ``v_cam = R_cam_icrs w``, pinhole ``K`` then the camera's
   Brown-Conrady distortion (:meth:`skynav.scenes.camera.Camera.project`).

The analytic Jacobian (Eq. 36-42, written here for the filter's state only):
``dxy/dr = P R (dw/dl) (dl/dd) (dd/drho) (-I)`` and ``dxy/dv = P R (I - l l^T) / c`` with
``dd/drho = I - v_p d^T / sqrt((rho . v_p)^2 + (c^2 - v_p^2) rho^2)`` (implicit differentiation of the
quadratic), ``dl/dd = (I - l l^T) / |d|``, ``dw/dl = (1 - l . beta) I - l beta^T`` and ``P``
the 2 x 3 derivative of the pinhole-plus-distortion projection.

Cases of Andreis et al. (2024), Sec. 5.2 (:data:`CASES`): 1 both effects in the model; 2 light-time in the
model, aberration removed from the measured centroid in image processing
(:func:`deaberrate_pixel`, with the filter's velocity); 3 no correction; 4 aberration only;
5 light-time only.

How good is first order: the renderer's exact light-time (iterated) and relativistic aberration
differ from this model by less than 0.01 arcsec at 1 AU and 30 km/s
(tests/pipeline/test_measurement_against_apparent.py), three orders of magnitude below the
15 arcsec that Andreis et al. (2024) (after Eq. 33) gives as the image-processing floor.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from skynav.scenes.constants import C_KM_S

__all__ = ["LightCorrections", "CASES", "PlanetMeasurement", "planet_pixel", "deaberrate_pixel",
           "lambert_photocentre_offset", "saturated_photocentre_offset", "PHOTOCENTRE_LAWS", "spot_saturated"]


def lambert_photocentre_offset(phase_angle_rad):
    """Offset of a Lambert sphere's centre of light from its centre, towards the Sun, in radii.

    ``(3 pi / 16) sin a (1 + cos a) / (sin a + (pi - a) cos a)``: 0 at full phase; towards new
    phase it tends to 9 pi / 32 (e.g. Lindegren 1977, A&A 57, 55; Gaia's solar-system photocentre
    correction). At 120 deg it is 0.75 radius: 1.5 px for the Earth at 0.05 au with the paper camera, which the
    renderer's discs show and the point-planet model of Andreis et al. (2024) would take as a position error.
    """
    a = np.asarray(phase_angle_rad, dtype=float)
    den = np.sin(a) + (np.pi - a) * np.cos(a)
    with np.errstate(invalid="ignore", divide="ignore"):
        out = 3.0 * np.pi / 16.0 * np.sin(a) * (1.0 + np.cos(a)) / den
    return np.where(a > np.pi - 1e-6, 9.0 * np.pi / 32.0, np.where(a < 1e-9, 0.0, out))


def saturated_photocentre_offset(phase_angle_rad):
    """Offset of the centroid of a SATURATED resolved disc from its centre, towards the Sun, in radii.

    When every lit pixel of a resolved planet sits at full scale (the Earth early in the cruise
    holds ~1e5 full wells per pixel), a flux-weighted centroid no longer sees the Lambert
    brightness: it returns the centroid of the lit AREA (the PSF, symmetric, does not move it).
    The lit region is the half disc on the Sun's side plus (phase < 90 deg) or minus (> 90 deg)
    the half ellipse of semi-axes ``(|cos a|, 1)``: area ``pi / 2 (1 + cos a)``, first moment
    ``2 / 3 (1 - cos^2 a)``, so the centroid is at ``4 / (3 pi) (1 - cos a)`` radii (0 at full
    phase, 8 / (3 pi) = 0.85 towards new phase). At 120 deg: 0.64 radius against Lambert's 0.75,
    0.26 px for the Earth at 4.9 px, which the campaign's centroids show (docs/pipeline.md).
    """
    a = np.asarray(phase_angle_rad, dtype=float)
    return 4.0 / (3.0 * np.pi) * (1.0 - np.cos(a))


#: Photocentre laws ``name -> offset(phase) in radii`` that :func:`planet_pixel` can aim at.
PHOTOCENTRE_LAWS = {"lambert": lambert_photocentre_offset, "saturated": saturated_photocentre_offset}


def spot_saturated(dn, xy_px, radius_px: float, max_dn: float) -> bool:
    """Whether any pixel within ``radius_px`` of ``xy_px`` of the image ``dn`` is at ``max_dn``.

    Image-side test for :func:`saturated_photocentre_offset` (the on-board image, no truth).
    """
    img = np.asarray(dn)
    x, y = float(xy_px[0]), float(xy_px[1])
    r = max(1.0, float(radius_px))
    h, w = img.shape[:2]
    x0, x1 = max(0, int(np.floor(x - r))), min(w, int(np.ceil(x + r)) + 1)
    y0, y1 = max(0, int(np.floor(y - r))), min(h, int(np.ceil(y + r)) + 1)
    if x0 >= x1 or y0 >= y1:
        return False
    return bool(np.any(img[y0:y1, x0:x1] >= max_dn))


@dataclass(frozen=True, kw_only=True)
class LightCorrections:
    """Which light effects the measurement model carries (Andreis et al. (2024), cases 1-5).

    Attributes
    ----------
    light_time : bool
        First-order light-time in the model (Eq. 26-31).
    aberration : bool
        First-order aberration in the model (Eq. 33).
    deaberrate_measurement : bool
        Case 2: the measured centroid is de-aberrated in image processing instead.

    Raises
    ------
    ValueError
        Aberration both in the model and removed from the measurement.

    References
    ----------
    Andreis et al. (2024), Sec. 5.2 (cases 1-5), Eqs. 26-33.

    Examples
    --------
    >>> from skynav.pipeline import CASES, LightCorrections
    >>> CASES[2]
    LightCorrections(light_time=True, aberration=False, deaberrate_measurement=True)
    >>> LightCorrections(light_time=False, aberration=False) == CASES[3]
    True
    """

    light_time: bool = True
    aberration: bool = True
    deaberrate_measurement: bool = False

    def __post_init__(self):
        if self.aberration and self.deaberrate_measurement:
            raise ValueError("aberration is either in the model or removed from the measurement, not both")


CASES = {
    1: LightCorrections(light_time=True, aberration=True),
    2: LightCorrections(light_time=True, aberration=False, deaberrate_measurement=True),
    3: LightCorrections(light_time=False, aberration=False),
    4: LightCorrections(light_time=False, aberration=True),
    5: LightCorrections(light_time=True, aberration=False),
}
"""The measurement-model cases of Andreis et al. (2024), Sec. 5.2: case number ->
:class:`LightCorrections` (1: light-time and aberration modelled, the default)."""


@dataclass(frozen=True, kw_only=True, eq=False)
class PlanetMeasurement:
    """Predicted planet centroid and its Jacobian.

    Attributes
    ----------
    xy_px : ndarray, shape (2,), px
    H : ndarray, shape (2, 6), px/km and px/(km/s)
        ``d xy / d (r, v)``.
    light_time_s : float
        First-order light time (0 when the model has none).
    los_icrs : ndarray, shape (3,)
        Modelled (aberrated if asked) line of sight, unit, ICRS.
    """

    xy_px: np.ndarray
    H: np.ndarray
    light_time_s: float
    los_icrs: np.ndarray


def _projection_jacobian(camera, v_cam):
    """Pixels (2,) and d(pixel)/d(v_cam) (2, 3) of the pinhole + distortion projection."""
    x, y, z = v_cam
    xn, yn = x / z, y / z
    dn = np.array([[1.0 / z, 0.0, -x / (z * z)], [0.0, 1.0 / z, -y / (z * z)]])
    dist = camera.distortion
    if not dist.is_identity:
        xd, yd = dist.distort(xn, yn)
        a, b, c, d = dist.jacobian(xn, yn)
        dn = np.array([[a, b], [c, d]]) @ dn
    else:
        xd, yd = xn, yn
    xy = np.array([camera.fx_px * xd + camera.cx, camera.fy_px * yd + camera.cy])
    return xy, np.array([[camera.fx_px], [camera.fy_px]]) * dn


def planet_pixel(position_km, velocity_km_s, planet_position_km, planet_velocity_km_s, R_cam_icrs, camera,
                 *, corrections: LightCorrections = CASES[1], sun_position_km=None,
                 planet_radius_km: float = 0.0, photocentre: str = "lambert") -> PlanetMeasurement:
    """Modelled pixel position of a planet and its Jacobian wrt the spacecraft state.

    Parameters
    ----------
    position_km, velocity_km_s : ndarray, shape (3,)
        Spacecraft barycentric ICRS state at the reception epoch, km, km/s.
    planet_position_km, planet_velocity_km_s : ndarray, shape (3,)
        Planet's barycentric ICRS state at the reception epoch (on-board ephemeris), km, km/s.
    R_cam_icrs : ndarray, shape (3, 3)
        Attitude (passive), ``v_cam = R_cam_icrs @ v_icrs``, geometric (stars de-aberrated).
    camera : skynav.scenes.camera.Camera
        Calibrated camera.
    corrections : LightCorrections
        Which effects are modelled (:data:`CASES`).
    sun_position_km : ndarray, shape (3,), optional
        With ``planet_radius_km > 0``: the model aims at the planet's Lambert centre of light
        (:func:`lambert_photocentre_offset`, towards the Sun across the line of sight) instead of
        its centre (an addition to Andreis et al. (2024)). The Jacobian treats the offset as constant (its
        derivative is ~ offset / distance, < 1e-3 of ``H``).
    planet_radius_km : float
        The planet's radius, km (0: aim at its centre).
    photocentre : str
        Which centre of light (:data:`PHOTOCENTRE_LAWS`): ``"lambert"`` (the brightness-weighted
        one) or ``"saturated"`` (the lit area's, for a resolved disc whose pixels are at full scale).

    Returns
    -------
    PlanetMeasurement
        ``xy_px`` (2,), px; ``H`` (2, 6), the Jacobian wrt ``(r, v)`` in px/km and px/(km/s);
        ``light_time_s``; ``los_icrs``.

    References
    ----------
    Andreis et al. (2024), Eqs. 26-42.

    Examples
    --------
    A planet 1e8 km away on the boresight, the spacecraft moving across the line of sight at
    30 km/s: aberration moves it by 20.6 arcsec, 0.29 px of the paper camera:

    >>> from skynav.pipeline import CASES, planet_pixel
    >>> from skynav.scenes import paper_camera, point_boresight
    >>> r, v = np.array([1.5e8, 0.0, 0.0]), np.array([30.0, 0.0, 0.0])
    >>> rp, vp = np.array([1.5e8, 1e8, 0.0]), np.zeros(3)
    >>> cam, R = paper_camera(), point_boresight(rp - r)
    >>> planet_pixel(r, v, rp, vp, R, cam, corrections=CASES[3]).xy_px   # geometric
    array([511.5, 511.5])
    >>> m = planet_pixel(r, v, rp, vp, R, cam)   # light-time and aberration
    >>> m.xy_px.round(3), m.H.shape, round(m.light_time_s, 2)
    (array([511.5  , 511.209]), (2, 6), 333.56)
    """
    r = np.asarray(position_km, dtype=float)
    v = np.asarray(velocity_km_s, dtype=float)
    rp = np.asarray(planet_position_km, dtype=float)
    vp = np.asarray(planet_velocity_km_s, dtype=float)
    R = np.asarray(R_cam_icrs, dtype=float)
    rho = rp - r
    eye = np.eye(3)
    if corrections.light_time:
        a = C_KM_S * C_KM_S - vp @ vp
        b = rho @ vp
        disc = np.sqrt(b * b + a * (rho @ rho))
        tau = (disc - b) / a
        d = rho - vp * tau
        dd_drho = eye - np.outer(vp, d) / disc  # d tau / d rho = d / (a tau + b) = d / disc
    else:
        tau = 0.0
        d = rho
        dd_drho = eye
    if sun_position_km is not None and planet_radius_km > 0.0:
        to_sun = np.asarray(sun_position_km, dtype=float) - (r + d)   # planet (at emission) to Sun
        to_sun /= np.linalg.norm(to_sun)
        lhat = d / np.linalg.norm(d)
        phase = np.arccos(np.clip(-lhat @ to_sun, -1.0, 1.0))
        across = to_sun - (to_sun @ lhat) * lhat
        na = np.linalg.norm(across)
        if na > 0:
            d = d + float(PHOTOCENTRE_LAWS[photocentre](phase)) * planet_radius_km * across / na
    nd = np.linalg.norm(d)
    l = d / nd
    dl_dd = (eye - np.outer(l, l)) / nd
    dl_dr = -dl_dd @ dd_drho
    if corrections.aberration:
        beta = v / C_KM_S
        lb = l @ beta
        w = l + beta - lb * l
        dw_dl = (1.0 - lb) * eye - np.outer(l, beta)
        dw_dr = dw_dl @ dl_dr
        dw_dv = (eye - np.outer(l, l)) / C_KM_S
    else:
        w = l
        dw_dr = dl_dr
        dw_dv = np.zeros((3, 3))
    xy, P = _projection_jacobian(camera, R @ w)
    PR = P @ R
    H = np.hstack([PR @ dw_dr, PR @ dw_dv])
    return PlanetMeasurement(xy_px=xy, H=H, light_time_s=float(tau), los_icrs=w / np.linalg.norm(w))


def deaberrate_pixel(xy_px, velocity_km_s, R_cam_icrs, camera) -> np.ndarray:
    """Case 2: remove first-order aberration from a measured centroid (image-processing side).

    The centroid is back-projected to an ICRS direction ``u'``, the first-order aberration is
    inverted (``u = u' - beta + (u' . beta) u'``, the same formula with ``-beta``) and the result
    projected again. ``velocity_km_s`` is the filter's estimate.

    Returns
    -------
    ndarray, shape (2,), px
    """
    R = np.asarray(R_cam_icrs, dtype=float)
    los_cam = np.asarray(camera.line_of_sight(np.asarray(xy_px, dtype=float).reshape(1, 2)), dtype=float).reshape(3)
    u_app = R.T @ (los_cam / np.linalg.norm(los_cam))
    beta = np.asarray(velocity_km_s, dtype=float) / C_KM_S
    u = u_app - beta + (u_app @ beta) * u_app
    return camera.project((R @ u).reshape(1, 3))[0]
