"""The stamp values of a batch's points on the Dr.Jit device, for every kernel of the renderer:
the Gaussian's erf differences and the table kernels' bilinear reads of their fine tables.

What it computes: for each (point, stamp pixel) lane of a group of points drawn with one kernel
and one stamp half size ``h`` (:class:`~skynav.renderer.splat_jit.PointGroup`), the fraction of
the point's light in that pixel, in float64, as the numpy kernels compute their stamps:

- :class:`~skynav.renderer.kernels.GaussianKernel`: the product of two erf differences over the
  pixel's edges (the reference writes them ``0.5 (1 + erf)``; sigma 0: the whole light in the
  point's pixel);
- :class:`~skynav.renderer.table_kernels.TableKernel`: the fine table read at offset
  ``c + k n + m`` from its middle sample ``c`` (``k`` the stamp pixel's offset, ``m`` the fine
  sample of the phase ``q = -f n``, ``f = xy - floor(xy + 0.5)``), bilinearly between fine
  samples as ``TableKernel._stamps_one`` reads its phase blocks (three lerps, same order), and
  blended over the tables with the point's weights: one table as it is, two spectral nodes
  ``a + t (b - a)`` in log wavelength at the point's effective wavelength, up to four tables of
  a field grid summed with their bilinear weights in ``(x, y)`` (the tables in their order).

The per-point quantities (the table index of the stamp's corner, the bilinear fractions, the
blend weights) are made on the host, once per point; a lane makes only its pixel's reads. The
tables of a kernel go to the device once per process (:func:`_device_tables`).
"""

from __future__ import annotations

import functools
import math

import numpy as np

from .kernels import GaussianKernel
from .sensor_jit import _jit_module

__all__ = ["stamp_values"]


@functools.lru_cache(maxsize=16)
def _device_tables(kernel, backend: str):
    """A table kernel's fine tables on ``backend``'s device, one copy per process: the tables
    (padded about their middle sample to one size ``S``) raveled one after the other, and
    ``S``."""
    shapes = {t.shape for t in kernel.tables}
    size = max(max(s) for s in shapes)
    out = []
    for t in kernel.tables:
        before = (size // 2 - t.shape[0] // 2, size // 2 - t.shape[1] // 2)
        out.append(np.pad(t, ((before[0], size - t.shape[0] - before[0]), (before[1], size - t.shape[1] - before[1]))))
    return _jit_module(backend).Float64(np.concatenate([t.ravel() for t in out])), size


def _blend(kernel, xy, lam):
    """The tables each point reads and their weights: ``(tables (M, P) int, weights (M, P) or
    None, spectral)``: one table (P = 1, no weights), two spectral nodes (P = 2, the weights
    ``(1 - t, t)``: blended ``a + t (b - a)``), or a field grid's tables of nonzero weight in
    their order (P = min(K, 4), zero weights after them)."""
    m = xy.shape[0]
    k = len(kernel.tables)
    if k == 1:
        return np.zeros((m, 1), np.int64), None, False
    if kernel.wavelengths_nm is not None:
        i, t = kernel._spectral_pair(lam, m)
        return np.stack([i, i + 1], axis=1), np.stack([1.0 - t, t], axis=1), True
    w = kernel.weights(xy, lam)
    order = np.argsort(w == 0.0, axis=1, kind="stable")[:, :min(k, 4)]  # nonzero first, in table order
    return order, np.take_along_axis(w, order, axis=1), False


def _table_corner(kernel, xy, h: int, size: int):
    """Per point: the flat index, in a table of side ``size``, of the fine sample its stamp's
    top-left pixel reads first (``c + (-h) n + m0``, rows and columns), and the bilinear
    fractions ``(tx, ty)``, as ``TableKernel._stamps_one``."""
    n = kernel.n
    f = xy - np.floor(xy + 0.5)  # phase in [-0.5, 0.5)
    q = -f * n
    m0 = np.floor(q)
    t = q - m0
    c = size // 2
    first = c - h * n + m0.astype(np.int64)  # (M, 2) (x, y)
    return first[:, 1] * size + first[:, 0], t[:, 0].copy(), t[:, 1].copy()


def _gaussian_values(jt, kernel: GaussianKernel, xy, h, point, col, row):
    """The Gaussian's pixel-integrated weight of each lane's pixel (``col``, ``row``: Int32)."""
    # Dr.Jit only for the JIT backends: import skynav.renderer loads neither Dr.Jit nor Mitsuba
    import drjit as dr

    if kernel.sigma_px == 0.0:  # a delta: the whole light in the point's pixel (h = 0)
        return jt.Float64(1.0)
    scale = 1.0 / (math.sqrt(2.0) * kernel.sigma_px)
    x = dr.gather(jt.Float64, jt.Float64(xy[:, 0].copy()), point)
    y = dr.gather(jt.Float64, jt.Float64(xy[:, 1].copy()), point)
    dx = (jt.Float64(col) - 0.5 - x) * scale
    dy = (jt.Float64(row) - 0.5 - y) * scale
    return 0.25 * (dr.erf(dx + scale) - dr.erf(dx)) * (dr.erf(dy + scale) - dr.erf(dy))


def _table_values(jt, kernel, xy, lam, h, point, cell, backend):
    """A table kernel's stamp value of each lane (``cell``: the pixel's index in its stamp)."""
    # Dr.Jit only for the JIT backends: import skynav.renderer loads neither Dr.Jit nor Mitsuba
    import drjit as dr

    table, size = _device_tables(kernel, backend)
    n, n_side = kernel.n, 2 * h + 1
    corner, tx, ty = _table_corner(kernel, xy, h, size)
    tables, weights, spectral = _blend(kernel, xy, lam)
    # a lane's first sample: its point's corner plus its pixel's whole pixels (n samples each)
    offset = jt.UInt32((cell // n_side) * (n * size) + (cell % n_side) * n)
    tx = dr.gather(jt.Float64, jt.Float64(tx), point)
    ty = dr.gather(jt.Float64, jt.Float64(ty), point)

    def read(j):
        first = (corner + tables[:, j] * (size * size)).astype(np.uint32)
        i = dr.gather(jt.UInt32, jt.UInt32(first), point) + offset
        a, b = dr.gather(jt.Float64, table, i), dr.gather(jt.Float64, table, i + 1)
        c, d = dr.gather(jt.Float64, table, i + size), dr.gather(jt.Float64, table, i + size + 1)
        top = a + tx * (b - a)
        bottom = c + tx * (d - c)
        return top + ty * (bottom - top)

    if weights is None:
        return read(0)
    if spectral:
        t = dr.gather(jt.Float64, jt.Float64(weights[:, 1].copy()), point)
        va = read(0)
        return va + t * (read(1) - va)
    s = jt.Float64(0.0)
    for j in range(weights.shape[1]):
        s = s + dr.gather(jt.Float64, jt.Float64(weights[:, j].copy()), point) * read(j)
    return s


def stamp_values(jt, kernel, xy, lam, h, point, cell, col, row, backend):
    """The fraction of each point's light in each lane's pixel, float64, lazy: lane ``j`` is
    pixel ``cell[j]`` (row-major in its ``(2h + 1)^2`` stamp; at ``col``, ``row`` on the image)
    of point ``point[j]`` of ``xy`` (M, 2), px (``lam`` (M,), nm: the points' effective
    wavelengths, for spectral nodes)."""
    if isinstance(kernel, GaussianKernel):
        return _gaussian_values(jt, kernel, xy, h, point, col, row)
    return _table_values(jt, kernel, xy, lam, h, point, cell, backend)
