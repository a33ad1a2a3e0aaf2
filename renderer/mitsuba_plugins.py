"""Mitsuba plugins of the resolved-body renderer, written in Python: the diffuse BSDFs of planetary
surfaces (Lommel-Seeliger, Oren-Nayar) and the ``skynav_projection`` sensor, whose rays follow a
table of lines of sight (any :class:`~skynav.scenes.projection.Projection`, a distorted camera or
a bench's collimator). :func:`register_plugins` registers them for a variant, once; the classes
are made inside functions because they derive from the variant's own ``mi.BSDF`` and
``mi.Sensor``, which exist only once a variant is set.
"""

from __future__ import annotations

import numpy as np

__all__ = ["register_plugins"]

_registered: set = set()


def register_plugins(variant: str) -> None:
    """Register the Python plugins for the current variant (once per variant): the BSDFs
    ``skynav_lommel_seeliger`` and ``skynav_oren_nayar`` and the sensor ``skynav_projection``."""
    if variant in _registered:
        return
    # Mitsuba only when a body is ray-traced: import skynav.renderer loads neither Mitsuba nor Dr.Jit
    import drjit as dr
    import mitsuba as mi

    lommel_seeliger, oren_nayar = _diffuse_bsdfs(mi, dr)
    projection_sensor = _projection_sensor(mi, dr)
    mi.register_bsdf("skynav_lommel_seeliger", lambda props: lommel_seeliger(props))
    mi.register_bsdf("skynav_oren_nayar", lambda props: oren_nayar(props))
    mi.register_sensor("skynav_projection", lambda props: projection_sensor(props))
    _registered.add(variant)


def _diffuse_bsdfs(mi, dr) -> tuple:
    """The Lommel-Seeliger and Oren-Nayar BSDF classes of the current variant: cosine-weighted
    hemisphere sampling, ``eval`` the BRDF times the cosine of the outgoing direction."""

    class _PyDiffuseBase(mi.BSDF):
        def __init__(self, props):
            mi.BSDF.__init__(self, props)
            self.reflectance = props["reflectance"]
            flags = mi.BSDFFlags.DiffuseReflection | mi.BSDFFlags.FrontSide
            self.m_components = [flags]
            self.m_flags = flags

        def _f_cos(self, si, wo, active):  # BRDF x cos(wo), Spectrum
            raise NotImplementedError

        def sample(self, ctx, si, sample1, sample2, active):
            cos_i = mi.Frame3f.cos_theta(si.wi)
            bs = dr.zeros(mi.BSDFSample3f)
            bs.wo = mi.warp.square_to_cosine_hemisphere(sample2)
            bs.pdf = mi.warp.square_to_cosine_hemisphere_pdf(bs.wo)
            bs.eta = 1.0
            bs.sampled_type = mi.UInt32(+mi.BSDFFlags.DiffuseReflection)
            bs.sampled_component = mi.UInt32(0)
            ok = active & (cos_i > 0) & (bs.pdf > 0)
            value = self._f_cos(si, bs.wo, ok) / dr.select(ok, bs.pdf, 1.0)
            return bs, dr.select(ok, value, 0.0)

        def eval(self, ctx, si, wo, active):
            ok = active & (mi.Frame3f.cos_theta(si.wi) > 0) & (mi.Frame3f.cos_theta(wo) > 0)
            return dr.select(ok, self._f_cos(si, wo, ok), 0.0)

        def pdf(self, ctx, si, wo, active):
            ok = active & (mi.Frame3f.cos_theta(si.wi) > 0) & (mi.Frame3f.cos_theta(wo) > 0)
            return dr.select(ok, mi.warp.square_to_cosine_hemisphere_pdf(wo), 0.0)

        def eval_pdf(self, ctx, si, wo, active):
            return self.eval(ctx, si, wo, active), self.pdf(ctx, si, wo, active)

        def traverse(self, callback):
            callback.put("reflectance", self.reflectance, mi.ParamFlags.Differentiable)

        def parameters_changed(self, keys):
            pass

    class LommelSeeliger(_PyDiffuseBase):
        """f = w / (4 pi (mu0 + mu)); eval returns f mu0 (mu0 = cos of the light direction)."""

        def _f_cos(self, si, wo, active):
            mu = dr.maximum(mi.Frame3f.cos_theta(si.wi), 0.0)
            mu0 = dr.maximum(mi.Frame3f.cos_theta(wo), 0.0)
            k = self.reflectance.eval(si, active)
            return k * (dr.inv_four_pi * mu0 / dr.maximum(mu0 + mu, 1e-12))

    class OrenNayar(_PyDiffuseBase):
        """Qualitative Oren-Nayar (1994, eq. 30); ``roughness`` is the slope deviation, rad."""

        def __init__(self, props):
            super().__init__(props)
            s2 = float(props["roughness"]) ** 2
            self.a = 1.0 - 0.5 * s2 / (s2 + 0.33)
            self.b = 0.45 * s2 / (s2 + 0.09)

        def _f_cos(self, si, wo, active):
            wi = si.wi
            c0 = dr.clip(mi.Frame3f.cos_theta(wo), 0.0, 1.0)
            c1 = dr.clip(mi.Frame3f.cos_theta(wi), 0.0, 1.0)
            s0 = dr.safe_sqrt(1.0 - c0 * c0)
            s1 = dr.safe_sqrt(1.0 - c1 * c1)
            pw = dr.safe_sqrt((wo.x * wo.x + wo.y * wo.y) * (wi.x * wi.x + wi.y * wi.y))
            cos_psi = dr.select(pw > 1e-12, (wo.x * wi.x + wo.y * wi.y) / dr.maximum(pw, 1e-12), 1.0)
            sin_a = dr.maximum(s0, s1)
            tan_b = dr.select(c0 > c1, s0 / dr.maximum(c0, 1e-12), s1 / dr.maximum(c1, 1e-12))
            k = self.reflectance.eval(si, active)
            return k * (dr.inv_pi * (self.a + self.b * dr.maximum(cos_psi, 0.0) * sin_a * tan_b) * c0)

    return LommelSeeliger, OrenNayar


def _projection_sensor(mi, dr):
    """The ``skynav_projection`` sensor class of the current variant."""

    class ProjectionSensor(mi.Sensor):
        """Rays along a table of lines of sight at the film's pixel corners (module notes).

        Parameters (set per frame, never literals in a kernel): ``a``, ``b``, the ``(h+1) x (w+1)``
        corner table of tangent-plane coordinates, each flattened row-major; ``basis``, the
        crop-to-world rotation (columns ``R^T e1, R^T e2, R^T c``); ``origin``, the observer.
        """

        def __init__(self, props):
            mi.Sensor.__init__(self, props)
            w, h = self.film().crop_size()
            self.w, self.h = int(w), int(h)
            self.m_needs_sample_3 = False  # a pinhole-like sensor: no aperture sample
            # a Dr.Jit array in the JIT variants; in the scalar ones (one ray per call, mi.Float is
            # a float) a NumPy array read by index
            self._jit = dr.is_jit_v(mi.Float)
            self.set_table(np.zeros((self.h + 1, self.w + 1, 2)))
            self.basis = mi.Matrix3f(mi.ScalarMatrix3f(np.eye(3)))
            self.origin = mi.Point3f(0.0, 0.0, -1.0)
            dr.make_opaque(self.basis, self.origin)

        def set_table(self, ab) -> None:
            """Corner table, ndarray (h + 1, w + 1, 2)."""
            # two flat arrays gathered with the pixel index itself (a gather of (a, b) pairs from
            # one interleaved array let Dr.Jit emit two forms of the index arithmetic, i.e. two
            # kernels, from one frame to the next)
            a = np.ascontiguousarray(np.asarray(ab)[..., 0], dtype=np.float32).ravel()
            b = np.ascontiguousarray(np.asarray(ab)[..., 1], dtype=np.float32).ravel()
            self.a, self.b = (mi.Float(a), mi.Float(b)) if self._jit else (a, b)

        def _corner(self, k, active):
            if self._jit:
                return mi.Point2f(dr.gather(mi.Float, self.a, k, active), dr.gather(mi.Float, self.b, k, active))
            return mi.Point2f(float(self.a[k]), float(self.b[k]))

        def set_view(self, basis, origin) -> None:
            """Crop-to-world rotation (3, 3) and observer position (3,), world units."""
            self.basis = mi.Matrix3f(mi.ScalarMatrix3f(np.asarray(basis, dtype=np.float64)))
            self.origin = mi.Point3f(*(float(v) for v in origin))
            dr.make_opaque(self.basis, self.origin)

        def sample_ray(self, time, wavelength_sample, position_sample, aperture_sample, active=True):
            wavelengths, weight = self.sample_wavelengths(dr.zeros(mi.SurfaceInteraction3f), wavelength_sample, active)
            u = position_sample.x * self.w
            v = position_sample.y * self.h
            i = dr.clip(mi.Int32(dr.floor(u)), 0, self.w - 1)
            j = dr.clip(mi.Int32(dr.floor(v)), 0, self.h - 1)
            fu = u - mi.Float(i)
            fv = v - mi.Float(j)
            k = mi.UInt32(j * (self.w + 1) + i)
            c00 = self._corner(k, active)
            c10 = self._corner(k + 1, active)
            c01 = self._corner(k + (self.w + 1), active)
            c11 = self._corner(k + (self.w + 2), active)
            p = dr.lerp(dr.lerp(c00, c10, fu), dr.lerp(c01, c11, fu), fv)
            d = dr.normalize(self.basis @ mi.Vector3f(p.x, p.y, 1.0))
            return mi.Ray3f(self.origin, d, time, wavelengths), weight

        def sample_ray_differential(self, time, wavelength_sample, position_sample, aperture_sample, active=True):
            ray, weight = self.sample_ray(time, wavelength_sample, position_sample, aperture_sample, active)
            return mi.RayDifferential3f(ray), weight

        def traverse(self, callback):
            super().traverse(callback)
            if self._jit:
                callback.put("table_a", self.a, mi.ParamFlags.NonDifferentiable)
                callback.put("table_b", self.b, mi.ParamFlags.NonDifferentiable)

        def parameters_changed(self, keys):
            pass

        def to_string(self):
            return f"ProjectionSensor[{self.w} x {self.h}]"

    return ProjectionSensor
