"""Point-spread functions, integrated exactly over pixels.

Pixel convention (CONVENTIONS.md): pixel ``[i, j]`` covers ``x in [j-0.5, j+0.5]``,
``y in [i-0.5, i+0.5]``. A stamp for a point at ``(x, y)`` is centred on the pixel that
contains it, ``(floor(x + 0.5), floor(y + 0.5))``, and spans ``2 h + 1`` pixels per axis.

A kernel implements the :class:`PSF` protocol; :class:`GaussianPSF` is separable and computes
its stamps as outer products of 1-D erf differences; :class:`TablePSF` reads them out of fine
tables of the pixel-integrated PSF (:mod:`skynav.renderer.optics`: Airy, pupil FFT, measured
images, a field grid of them), normalised so that every stamp holds the point's whole flux.
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np
from scipy.special import erf, erfinv

from skynav.scenes.errors import ConfigValueError

__all__ = ["PSF", "GaussianPSF", "TablePSF", "stamp_origin"]


def stamp_origin(xy, half_size: int) -> np.ndarray:
    """Integer pixel (column, row) of the top-left corner of the stamps of points ``xy``.

    Parameters
    ----------
    xy : ndarray, shape (M, 2), px
    half_size : int

    Returns
    -------
    ndarray, shape (M, 2), int: ``floor(xy + 0.5) - half_size``
    """
    return np.floor(np.asarray(xy, dtype=float) + 0.5).astype(np.int64) - int(half_size)


@runtime_checkable
class PSF(Protocol):
    """What the rasteriser needs from a kernel (a value object: hashable, comparable)."""

    def half_size_px(self, flux_fraction_lost: float) -> int:
        """Smallest stamp half size ``h`` whose (2h+1)^2 stamp holds all but
        ``flux_fraction_lost`` of the flux of any point inside its centre pixel."""
        ...

    def stamps(self, xy, half_size: int) -> np.ndarray:
        """Pixel-integrated weights, shape (M, 2h+1, 2h+1) (row, column), of points ``xy``
        (M, 2), on the stamps whose origin is :func:`stamp_origin`."""
        ...


@dataclass(frozen=True)
class GaussianPSF:
    """Circular Gaussian PSF of standard deviation ``sigma_px`` (px), pixel-integrated exactly.

    ``sigma_px = 0`` is a delta: all the flux goes into the pixel containing the point (a point
    on an edge belongs to the pixel on its right/below, ``j - 0.5 <= x < j + 0.5``).

    Positional ``sigma_px`` (deviation from the kw_only rule for value objects: the PSF is a
    one-number value, ``GaussianPSF(0.5)`` reads best); the repr evals back to an equal object.

    Parameters
    ----------
    sigma_px : float, px, >= 0

    Examples
    --------
    >>> psf = GaussianPSF(0.5)
    >>> round(float(psf.integrate_1d(np.array([-0.5, 0.5]))[0]), 6)
    0.682689
    """

    sigma_px: float

    def __post_init__(self):
        s = self.sigma_px
        if not (isinstance(s, (int, float, np.floating)) and math.isfinite(s) and s >= 0):
            raise ConfigValueError("psf.sigma_px", s, "a finite number >= 0 (px)")
        object.__setattr__(self, "sigma_px", float(s))

    # ------------------------------------------------------------------ 1-D
    def cdf_1d(self, u_px) -> np.ndarray:
        """Fraction of the 1-D marginal below offset ``u_px`` from the centre.

        Parameters
        ----------
        u_px : array_like, px

        Returns
        -------
        ndarray, same shape, in [0, 1] (a step ``u > 0`` for sigma 0)
        """
        u = np.asarray(u_px, dtype=float)
        if self.sigma_px == 0.0:
            return (u > 0.0).astype(float)
        return 0.5 * (1.0 + erf(u * (1.0 / (math.sqrt(2.0) * self.sigma_px))))

    def integrate_1d(self, edges_px) -> np.ndarray:
        """Fractions of the 1-D marginal between consecutive edges (offsets from the centre).

        Parameters
        ----------
        edges_px : ndarray, shape (..., n + 1), px, ascending along the last axis

        Returns
        -------
        ndarray, shape (..., n)
        """
        return np.diff(self.cdf_1d(edges_px), axis=-1)

    def pixel_weights(self, dx_edges_px, dy_edges_px) -> np.ndarray:
        """Flux fractions in the pixels of a grid, edges given as offsets from the centre.

        Parameters
        ----------
        dx_edges_px : ndarray, shape (..., n + 1), px (column edges minus x of the point)
        dy_edges_px : ndarray, shape (..., m + 1), px (row edges minus y of the point)

        Returns
        -------
        ndarray, shape (..., m, n) (row, column)
        """
        wx = self.integrate_1d(dx_edges_px)
        wy = self.integrate_1d(dy_edges_px)
        return wy[..., :, None] * wx[..., None, :]

    # ------------------------------------------------------------------ PSF protocol
    def half_size_px(self, flux_fraction_lost: float) -> int:
        """Stamp half size so that the flux outside the stamp is < ``flux_fraction_lost``.

        The stamp's edges are at least ``h`` px from any point inside its centre pixel, and
        the flux of a Gaussian outside a centred square of half-width ``r`` is
        ``1 - erf(r / (sqrt 2 sigma))^2``; so ``h = ceil(sqrt 2 sigma erfinv(sqrt(1 - f)))``.
        """
        f = float(flux_fraction_lost)
        if not (0.0 < f < 1.0):
            raise ConfigValueError("flux_fraction_lost", f, "in (0, 1)")
        if self.sigma_px == 0.0:
            return 0
        r = math.sqrt(2.0) * self.sigma_px * float(erfinv(math.sqrt(1.0 - f)))
        return max(0, int(math.ceil(r - 1e-12)))

    def stamps(self, xy, half_size: int) -> np.ndarray:
        """Pixel-integrated stamps of points ``xy`` (see :class:`PSF`).

        Parameters
        ----------
        xy : ndarray, shape (M, 2), px
        half_size : int

        Returns
        -------
        ndarray, shape (M, 2h+1, 2h+1), float64 (row, column)
        """
        xy = np.asarray(xy, dtype=float).reshape(-1, 2)
        h = int(half_size)
        origin = stamp_origin(xy, h)
        k = np.arange(2 * h + 2, dtype=float) - 0.5  # edges relative to the origin pixel centre
        dx = origin[:, 0:1] + k[None, :] - xy[:, 0:1]
        dy = origin[:, 1:2] + k[None, :] - xy[:, 1:2]
        return self.pixel_weights(dx, dy)

    def stamp(self, xy, half_size: int) -> np.ndarray:
        """Stamp of one point ``xy`` (2,), shape (2h+1, 2h+1); origin ``stamp_origin(xy, h)``."""
        return self.stamps(np.asarray(xy, dtype=float).reshape(1, 2), half_size)[0]

    def quadrature_step_px(self) -> float:
        """Panel length for the rasteriser's streak quadrature (2-point Gauss-Legendre per
        panel), px: ``1.5 sigma`` capped at 0.75 px, floored at 0.01 px for near-delta kernels.
        Measured against a 0.002 px reference (sigma 0.3-1 px, 20 px streaks), the image
        differs by < 1.1e-5 of the source's flux in any pixel."""
        return min(max(1.5 * self.sigma_px, 0.01), 0.75)


class TablePSF:
    """A PSF given as fine tables of its pixel-integrated image (see :mod:`.optics`).

    ``tables[k][iy, ix]`` is the fraction of the flux of a point in the pixel whose centre is
    offset ``((ix - c) / n, (iy - c) / n)`` px from the point, ``c = shape // 2``. A stamp reads
    the table at the integer pixel offsets minus the point's sub-pixel phase, bilinearly
    between fine samples, and is normalised to a sum of 1 (flux conserved: the wings beyond the
    stamp, at most the ``flux_fraction_lost`` it was sized for or the cap
    :data:`~skynav.scenes.psf.MAX_HALF_SIZE_PX`, are folded back in proportion).

    With a field grid (``grid = (xs, ys, index[iy][ix])``) a point's stamp is the bilinear blend
    in ``(x, y)`` of the stamps of the four grid tables around it (clamped at the grid's edge):
    exactly a grid table's stamp at its grid point.

    Value semantics: equal and hashing alike when their tables are equal (sha256 of the bytes).
    """

    def __init__(self, tables, n: int, half: int, grid=None):
        # FFT ringing leaves values of ~1e-16 of the peak below 0: a charge is never negative
        self.tables = tuple(np.ascontiguousarray(np.maximum(t, 0.0), dtype=float) for t in tables)
        self.n = int(n)
        self.half = int(half)
        self.grid = grid
        self._block_cache = {}
        self._last = None

        h = hashlib.sha256()
        for t in self.tables:
            h.update(t.tobytes())
        h.update(repr((self.n, self.half, grid)).encode())
        self._key = h.hexdigest()

    def __eq__(self, other):
        return isinstance(other, TablePSF) and other._key == self._key

    def __hash__(self):
        return hash(self._key)

    def __repr__(self):
        return f"TablePSF(<{len(self.tables)} table(s) {self.tables[0].shape}>, n={self.n}, half={self.half})"

    def half_size_px(self, flux_fraction_lost: float) -> int:
        """The stamp half size the model gave for the render's ``flux_fraction_lost``."""
        return self.half

    def quadrature_step_px(self) -> float:
        """Panel length of the streak quadrature, px: 0.35 (the pixel-integrated kernel is at
        least a pixel wide; see ``tests/renderer/test_psf_models.py`` for the convergence)."""
        return 0.35

    def _blocks(self, k_table: int, h: int) -> tuple:
        """The table as phase blocks ``B[my, mx] = P[c + ky n + my, c + kx n + mx]`` for
        ``ky, kx`` in ``-h..h`` (cached per table and h): a stamp then reads 4 contiguous
        blocks, not 4 (2h+1)^2 scattered elements."""
        key = (k_table, h)
        got = self._block_cache.get(key)
        if got is None:
            n, table = self.n, self.tables[k_table]
            c = table.shape[0] // 2
            m_lo = int(np.floor(-n / 2.0))
            m = np.arange(m_lo, m_lo + n + 3)
            k = np.arange(-h, h + 1)
            idx = c + k[None, :] * n + m[:, None]  # (n + 3, 2h + 1)
            blocks = table[idx[:, None, :, None], idx[None, :, None, :]]  # (my, mx, ky, kx)
            got = (blocks, m_lo, blocks.sum(axis=(2, 3)))  # + each block's sum, (my, mx)
            self._block_cache[key] = got
        return got

    def _stamps_one(self, k_table, f, h):
        """Unnormalised stamps and their sums (the same bilinear blend of the blocks' sums)."""
        blocks, m_lo, sums = self._blocks(k_table, h)
        q = -f * self.n  # fine-sample offset of the phase, (M, 2) (x, y)
        m0 = np.floor(q).astype(np.int64)
        t = q - m0
        ix, iy = m0[:, 0] - m_lo, m0[:, 1] - m_lo
        tx = t[:, 0][:, None, None]
        ty = t[:, 1][:, None, None]
        # bilinear as three in-place lerps, a + t (b - a): fewer temporaries than the weights
        top = blocks[iy, ix]
        top += tx * (blocks[iy, ix + 1] - top)
        bottom = blocks[iy + 1, ix]
        bottom += tx * (blocks[iy + 1, ix + 1] - bottom)
        bottom -= top
        bottom *= ty
        top += bottom
        tx, ty = tx[:, 0, 0], ty[:, 0, 0]
        s_top = sums[iy, ix] + tx * (sums[iy, ix + 1] - sums[iy, ix])
        s_bot = sums[iy + 1, ix] + tx * (sums[iy + 1, ix + 1] - sums[iy + 1, ix])
        return top, s_top + ty * (s_bot - s_top)

    def _field_weights(self, xy):
        """Bilinear weights (M, K) of the grid tables at points ``xy``."""
        xs, ys, index = self.grid
        xs, ys = np.asarray(xs), np.asarray(ys)
        w = np.zeros((xy.shape[0], len(self.tables)))

        def axis(g, v):
            if g.size == 1:
                return np.zeros(v.shape, np.int64), np.zeros(v.shape, np.int64), np.zeros(v.shape)
            v = np.clip(v, g[0], g[-1])
            i = np.clip(np.searchsorted(g, v, side="right") - 1, 0, g.size - 2)
            return i, i + 1, (v - g[i]) / (g[i + 1] - g[i])

        i0, i1, fx = axis(xs, xy[:, 0])
        j0, j1, fy = axis(ys, xy[:, 1])
        idx = np.asarray(index)
        rows = np.arange(xy.shape[0])
        for jj, wy in ((j0, 1.0 - fy), (j1, fy)):
            for ii, wx in ((i0, 1.0 - fx), (i1, fx)):
                np.add.at(w, (rows, idx[jj, ii]), wy * wx)
        return w

    def stamps(self, xy, half_size: int) -> np.ndarray:
        """Pixel-integrated stamps of points ``xy`` (see :class:`PSF`), each summing to 1.

        Read-only: the last call's result is kept and returned again for the same points (the
        irradiance pass of a frame repeats the electrons' pass)."""
        xy = np.asarray(xy, dtype=float).reshape(-1, 2)
        key = (xy.tobytes(), int(half_size))
        last = self._last  # one read: another thread may replace it
        if last is not None and last[0] == key:
            return last[1]
        out = self._stamps(xy, half_size)
        out.flags.writeable = False
        self._last = (key, out)
        return out

    def _stamps(self, xy, half_size):
        if int(half_size) > self.half:  # beyond the table: no light (zeros around the table's stamp)
            pad = int(half_size) - self.half
            return np.pad(self.stamps(xy, self.half), ((0, 0), (pad, pad), (pad, pad)))
        h = int(half_size)
        f = xy - np.floor(xy + 0.5)  # phase in [-0.5, 0.5)
        if self.grid is None:
            s, tot = self._stamps_one(0, f, h)
        else:
            w = self._field_weights(xy)
            s = np.zeros((xy.shape[0], 2 * h + 1, 2 * h + 1))
            tot = np.zeros(xy.shape[0])
            for k in range(len(self.tables)):
                sel = np.flatnonzero(w[:, k] > 0.0)
                if sel.size:
                    sk, tk = self._stamps_one(k, f[sel], h)
                    s[sel] += w[sel, k][:, None, None] * sk
                    tot[sel] += w[sel, k] * tk
        s *= (1.0 / np.where(tot > 0, tot, 1.0))[:, None, None]  # the blend's sum is the blend of the sums
        return s

    def stamp(self, xy, half_size: int) -> np.ndarray:
        """Stamp of one point ``xy`` (2,), shape (2h+1, 2h+1); origin ``stamp_origin(xy, h)``."""
        return self.stamps(np.asarray(xy, dtype=float).reshape(1, 2), half_size)[0]
