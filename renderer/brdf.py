"""Reflectance laws of the resolved bodies, their albedos, and far-field disk integrals.

Pure NumPy (core module): the Mitsuba adapter (:mod:`skynav.renderer.mitsuba_backend`) turns a
:class:`BRDF` into a Mitsuba BSDF; the functions here give the same law for quadratures (the
geometric albedo that fixes the reflectance scale, and the far-field photocentre offset that
the point-source path needs to stay continuous with the resolved path).

Conventions
-----------
``mu0 = cos(incidence)``, ``mu = cos(emission)``, ``g`` the phase angle (Sun-body-observer),
``cos_psi`` the cosine of the azimuth between the incidence and emission planes
(``cos g = mu0 mu + sin(i) sin(e) cos_psi``; ``psi = 0`` is backscatter). ``f`` is the BRDF in
sr^-1: the reflected radiance is ``L = f E mu0`` for a collimated irradiance ``E`` (normal to
the beam).

Which albedo maps to which parameter
------------------------------------
The catalogued quantity is the V-band GEOMETRIC albedo ``p`` (disk-integrated brightness at zero
phase relative to a flat Lambert disk of reflectance 1). Each law has one scale parameter
``k`` (the ``reflectance_550`` of a :class:`BRDF`) at 550 nm, chosen so that the law's sphere
has geometric albedo ``p``:

* Lambert, ``f = k / pi``: ``p = 2 k / 3`` (Russell 1916, ApJ 43, 173), so ``k = 1.5 p``, the
  Lambert (normal) reflectance.
* Lommel-Seeliger, ``f = k / (4 pi (mu0 + mu))``: ``p = k / 8`` (Hapke 2012, "Theory of
  Reflectance and Emittance Spectroscopy", 2nd ed., sec. 9.D), so ``k = 8 p`` is the
  single-scattering albedo ``w``.
* Oren-Nayar (qualitative model, Oren & Nayar 1994, SIGGRAPH, eq. 30):
  ``f = k / pi (A + B max(0, cos_psi) sin(alpha) tan(beta))``, ``alpha = max(i, e)``,
  ``beta = min(i, e)``, ``A = 1 - 0.5 s^2 / (s^2 + 0.33)``, ``B = 0.45 s^2 / (s^2 + 0.09)``
  with ``s`` the facet slope deviation (rad); ``p = 2 k (A / 3 + B / 4)``.

Values above 1 (Venus as a Lambert sphere: ``k = 1.03``) are kept: they only scale the
``normalize="none"`` rendering; the default ``"phase_law"`` normalisation uses the law's shape.
The wavelength dependence multiplies ``k`` by :func:`skynav.renderer.spectra.reflectance_shape`
(1 at 550 nm).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from skynav.infra.errors import ConfigValueError
from skynav.scenes.camera import Camera

__all__ = [
    "GEOMETRIC_ALBEDO_V",
    "BRDF",
    "KINDS",
    "default_brdf",
    "brdf_value",
    "sphere_geometric_albedo",
    "far_field_disk",
    "lambert_phase_function",
    "lambert_photocentre_offset",
    "photocentre_offset_xy",
]

#: V-band geometric albedos. Planets: Mallama, Krobusek & Pavlov (2017), Icarus 282, 19, table 8
#: ("Comprehensive wide-band magnitudes and albedos for the planets"). Moon: 0.12, NASA
#: Planetary Fact Sheet (Williams 2024). Unknown bodies use ``DEFAULT_GEOMETRIC_ALBEDO``.
GEOMETRIC_ALBEDO_V = {
    "mercury": 0.142,
    "venus": 0.689,
    "earth": 0.434,
    "moon": 0.12,
    "mars": 0.170,
    "jupiter": 0.538,
    "saturn": 0.499,
    "uranus": 0.488,
    "neptune": 0.442,
}
DEFAULT_GEOMETRIC_ALBEDO = 0.15

KINDS = ("lambert", "lommel_seeliger", "oren_nayar")

#: Default law per body: airless regoliths are Lommel-Seeliger-like (Hapke 2012), cloudy and
#: icy worlds closer to Lambert at the disk-integrated level.
_DEFAULT_KIND = {"mercury": "lommel_seeliger", "moon": "lommel_seeliger", "mars": "oren_nayar"}


@dataclass(frozen=True, kw_only=True)
class BRDF:
    """A reflectance law and its scale.

    Parameters
    ----------
    kind : str
        One of :data:`KINDS`.
    reflectance_550 : float
        The law's scale ``k`` at 550 nm (see the module notes), dimensionless, > 0.
    roughness_rad : float
        Oren-Nayar facet slope standard deviation ``s``, rad (ignored by the other laws).

    References
    ----------
    Hapke (2012), Theory of Reflectance and Emittance Spectroscopy (Lommel-Seeliger);
    Oren & Nayar (1994), SIGGRAPH, Eq. 30 (the module's notes give the albedo relations).

    Examples
    --------
    >>> from skynav.renderer import BRDF
    >>> from skynav.renderer.brdf import sphere_geometric_albedo
    >>> law = BRDF.for_geometric_albedo("lommel_seeliger", 0.12)
    >>> round(law.reflectance_550, 6), round(sphere_geometric_albedo(law), 6)   # p = k / 8
    (0.96, 0.12)
    """

    kind: str = "lambert"
    reflectance_550: float = 1.0
    roughness_rad: float = math.radians(20.0)

    def __post_init__(self):
        if self.kind not in KINDS:
            raise ConfigValueError("brdf.kind", self.kind, "one of: " + ", ".join(KINDS))
        if not (math.isfinite(self.reflectance_550) and self.reflectance_550 > 0):
            raise ConfigValueError("brdf.reflectance_550", self.reflectance_550, "a finite number > 0")
        if not (math.isfinite(self.roughness_rad) and 0 <= self.roughness_rad < math.pi / 2):
            raise ConfigValueError("brdf.roughness_deg", math.degrees(self.roughness_rad), "in [0, 90)")

    @property
    def oren_nayar_ab(self) -> tuple[float, float]:
        """Oren-Nayar ``(A, B)`` of ``roughness_rad``."""
        s2 = self.roughness_rad**2
        return 1.0 - 0.5 * s2 / (s2 + 0.33), 0.45 * s2 / (s2 + 0.09)

    @classmethod
    def for_geometric_albedo(cls, kind: str, geometric_albedo: float, **kw) -> "BRDF":
        """The law ``kind`` scaled so that its sphere has geometric albedo ``geometric_albedo``.

        Parameters
        ----------
        kind : str
            One of :data:`KINDS`.
        geometric_albedo : float
            V-band geometric albedo of the sphere, no unit.
        **kw
            Other fields (``roughness_rad``).

        Returns
        -------
        BRDF
            The scaled law.
        """
        unit = cls(kind=kind, reflectance_550=1.0, **kw)
        return cls(kind=kind, reflectance_550=float(geometric_albedo) / sphere_geometric_albedo(unit), **kw)


@functools.lru_cache(maxsize=64)
def default_brdf(body_name: str, kind: str | None = None) -> BRDF:
    """The law of a body (``kind`` or the body's default) scaled to its geometric albedo.

    Cached: the albedo normalisation is a quadrature, and every unresolved body of every frame
    asks for it (a frozen BRDF is an immutable value, so sharing it is safe).

    Parameters
    ----------
    body_name : str
        The body (``mars``, ``moon``, ...); its first word is looked up, case-insensitively.
    kind : str, optional
        One of :data:`KINDS`; default: the body's own law.

    Returns
    -------
    BRDF
        The law, scaled so that the sphere has the body's V-band geometric albedo.

    Examples
    --------
    >>> from skynav.renderer import default_brdf
    >>> from skynav.renderer.brdf import sphere_geometric_albedo
    >>> mars = default_brdf("mars")
    >>> mars.kind, round(sphere_geometric_albedo(mars), 6)
    ('oren_nayar', 0.17)
    """
    key = str(body_name).strip().lower().split()[0] if str(body_name).strip() else ""
    k = kind or _DEFAULT_KIND.get(key, "lambert")
    return BRDF.for_geometric_albedo(k, GEOMETRIC_ALBEDO_V.get(key, DEFAULT_GEOMETRIC_ALBEDO))


def brdf_value(brdf: BRDF, mu0, mu, cos_psi) -> np.ndarray:
    """BRDF ``f`` (sr^-1) at 550 nm; zero where ``mu0 <= 0`` or ``mu <= 0``.

    Parameters
    ----------
    brdf : BRDF
    mu0, mu, cos_psi : array_like (broadcast), dimensionless

    Returns
    -------
    ndarray, broadcast shape, sr^-1
    """
    mu0 = np.asarray(mu0, dtype=float)
    mu = np.asarray(mu, dtype=float)
    ok = (mu0 > 0) & (mu > 0)
    k = brdf.reflectance_550
    if brdf.kind == "lambert":
        f = np.full(np.broadcast(mu0, mu).shape, k / math.pi)
    elif brdf.kind == "lommel_seeliger":
        with np.errstate(divide="ignore", invalid="ignore"):
            f = k / (4.0 * math.pi * (mu0 + mu))
    else:
        a, b = brdf.oren_nayar_ab
        s0 = np.sqrt(np.clip(1.0 - mu0 * mu0, 0.0, None))
        s1 = np.sqrt(np.clip(1.0 - mu * mu, 0.0, None))
        # sin(alpha) tan(beta) with alpha = max(i, e), beta = min(i, e)
        with np.errstate(divide="ignore", invalid="ignore"):
            sin_a = np.maximum(s0, s1)
            tan_b = np.where(mu0 > mu, s0 / mu0, s1 / mu)
        f = k / math.pi * (a + b * np.maximum(0.0, np.asarray(cos_psi, dtype=float)) * sin_a * tan_b)
    return np.where(ok, f, 0.0)


@functools.lru_cache(maxsize=8)
def _disk_grid(n: int):
    """The half of the unit disk with ``Y >= 0``, on Gauss-Legendre nodes in polar coordinates
    (r, t), and the parts of the integrand that do not depend on the phase angle.

    The disk integrand of :func:`far_field_disk` depends on ``Y`` only through ``Y^2`` (the
    normal's ``Z``); the ``t`` nodes are symmetric about ``pi``, so the nodes with ``t < pi`` are
    summed with twice their weight (a node at ``t = pi``, for odd ``n``, once). Cached: the nodes
    cost an eigenvalue problem, the cosines and roots one pass each; the arrays are read-only.

    Returns
    -------
    X, Z, sin_e, W : ndarray, shape (n, ceil(n / 2))
        ``X = r cos t``, ``Z = sqrt(1 - X^2 - Y^2)`` (= ``mu``), ``sqrt(1 - mu^2)`` and the weights
        ``r dr dt`` (doubled off the axis).
    """
    x, w = np.polynomial.legendre.leggauss(n)
    half = (n + 1) // 2
    r = 0.5 * (x + 1.0)
    wr = 0.5 * w
    t = np.pi * (x[:half] + 1.0)
    wt = np.pi * w[:half] * np.where(np.arange(half) < n // 2, 2.0, 1.0)
    R, T = np.meshgrid(r, t, indexing="ij")
    W = (wr * r)[:, None] * wt[None, :]
    X, Y = R * np.cos(T), R * np.sin(T)
    Z = np.sqrt(np.clip(1.0 - X * X - Y * Y, 0.0, None))
    se = np.sqrt(np.clip(1.0 - Z * Z, 0.0, None))
    for a in (X, Z, se, W):
        a.flags.writeable = False
    return X, Z, se, W


def far_field_disk(brdf: BRDF, phase_angle_rad: float, *, n: int = 400) -> tuple[float, float]:
    """Disk-integrated brightness and photocentre of a sphere seen from infinity.

    Orthographic disk coordinates ``(X, Y)`` in units of the radius, ``X`` towards the Sun's
    projection on the sky, observer along +Z; the surface normal is
    ``(X, Y, sqrt(1 - X^2 - Y^2))``, the Sun ``(sin g, 0, cos g)``.

    Parameters
    ----------
    brdf : BRDF
    phase_angle_rad : float
    n : int
        Gauss-Legendre order per polar axis (the terminator kink limits the accuracy to
        ~1e-5 of the radius at n = 400).

    Returns
    -------
    intensity : float
        ``integral f mu0 dX dY`` (radius 1): the disk brightness relative to a flat Lambert disk
        of reflectance 1 at normal incidence (the geometric albedo at g = 0; times the phase
        function at g).
    photocentre_x : float
        Photocentre offset towards the Sun's projection, in units of the radius.
    """
    g = float(phase_angle_rad)
    X, Z, se, W = _disk_grid(n)  # the half disk Y >= 0: the integrand is even in Y
    mu = Z
    mu0 = X * math.sin(g) + Z * math.cos(g)
    if brdf.kind == "oren_nayar":  # the only law with an azimuth term
        si = np.sqrt(np.clip(1.0 - mu0 * mu0, 0.0, None))
        with np.errstate(divide="ignore", invalid="ignore"):
            cos_psi = np.where(si * se > 1e-12, (math.cos(g) - mu0 * mu) / (si * se), 1.0)
    else:
        cos_psi = 1.0
    # projected area element is dX dY, and L = f E mu0 (radiance), so intensity ~ f mu0 dX dY
    lum = brdf_value(brdf, mu0, mu, cos_psi) * np.clip(mu0, 0.0, None) * W
    total = float(lum.sum())
    return total, float((lum * X).sum() / total) if total > 0 else 0.0


@functools.lru_cache(maxsize=4)
def _gauss_legendre(n: int) -> tuple[np.ndarray, np.ndarray]:
    x, w = np.polynomial.legendre.leggauss(n)
    x.flags.writeable = False
    w.flags.writeable = False
    return x, w


def sphere_geometric_albedo(brdf: BRDF) -> float:
    """Geometric albedo of a sphere with this law: ``2 pi integral_0^1 f(mu, mu, 1) mu^2 dmu``."""
    x, w = _gauss_legendre(64)
    m = 0.5 * (x + 1.0)
    return float(2.0 * math.pi * np.sum(0.5 * w * brdf_value(brdf, m, m, 1.0) * m * m))


def lambert_phase_function(phase_angle_rad) -> np.ndarray:
    """Lambert sphere phase function ``(sin g + (pi - g) cos g) / pi`` (Russell 1916)."""
    g = np.asarray(phase_angle_rad, dtype=float)
    return (np.sin(g) + (np.pi - g) * np.cos(g)) / np.pi


def lambert_photocentre_offset(phase_angle_rad) -> np.ndarray:
    """Far-field photocentre offset of a Lambert sphere towards the Sun, in radii.

    ``3 pi / 16 * sin g (1 + cos g) / (sin g + (pi - g) cos g)`` (Lindegren 1977, A&A 57, 55;
    it is the first moment of the Lambert disk over its zeroth moment).
    """
    g = np.asarray(phase_angle_rad, dtype=float)
    return 3.0 * np.pi / 16.0 * np.sin(g) * (1.0 + np.cos(g)) / (np.sin(g) + (np.pi - g) * np.cos(g))


def photocentre_offset_xy(projection, R_cam_icrs, body, brdf: BRDF | None = None, *, n: int = 200) -> np.ndarray:
    """Far-field photocentre minus centre of figure of a body on the image, px.

    What the point-source path must add to ``body.xy`` so that an unresolved body's centroid
    continues the resolved rendering's photocentre across the resolved threshold: the
    :func:`far_field_disk` offset (in radii) of ``brdf`` at the body's phase angle, times the
    apparent radius, along the image direction of the Sun's projection. The apparent radius is
    ``f tan(asin(R / d))`` for a :class:`~skynav.scenes.camera.Camera` (its on-axis value; the
    offset is under a pixel where the resolved threshold puts it), and for another projection the
    local image scale along that direction (a finite difference of ``projection.project``) times
    ``tan(asin(R / d))``.

    Parameters
    ----------
    projection : skynav.scenes.camera.Camera or skynav.scenes.projection.Projection
    R_cam_icrs : ndarray, shape (3, 3)
    body : skynav.scenes.scene.BodyInView
    brdf : BRDF, optional (default :func:`default_brdf` of the body)

    Returns
    -------
    ndarray, shape (2,), px
    """
    brdf = brdf or default_brdf(body.name)
    u = np.asarray(body.u_icrs, dtype=float)
    u = u / np.linalg.norm(u)
    s = np.asarray(body.sun_position_km, dtype=float) - np.asarray(body.position_km, dtype=float)
    s = s / np.linalg.norm(s)
    e = s - (s @ u) * u
    ne = float(np.linalg.norm(e))
    if ne < 1e-12:
        return np.zeros(2)
    e /= ne
    alpha = math.acos(float(np.clip(-(u @ s), -1.0, 1.0)))
    R = np.asarray(R_cam_icrs, dtype=float)
    eps = 1e-6
    xy = projection.project(np.stack([R @ u, R @ (u + eps * e)]))
    d = xy[1] - xy[0]
    step = np.linalg.norm(d)
    d /= step
    scale = projection.focal_length_px if isinstance(projection, Camera) else step / eps  # px per rad
    radius_px = scale * math.tan(math.asin(body.radius_km / body.distance_km))
    return d * far_field_disk(brdf, alpha, n=n)[1] * radius_px
