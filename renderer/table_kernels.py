"""Table kernels: PSFs given as fine tables of their pixel-integrated image.

:class:`TableKernel` reads a point's stamp out of the tables that :mod:`skynav.renderer.optics`
makes of every model but the Gaussian (Airy, pupil FFT, measured images, a field grid of them),
as they are: a stamp holds the light the PSF puts in its pixels, the light beyond it is not
drawn. :class:`CutKernel` is one drawn with smaller stamps, for faint points. Both implement
:class:`skynav.renderer.kernels.Kernel`; pixel convention and stamp origin as there
(:func:`~skynav.renderer.kernels.stamp_origin`).
"""

from __future__ import annotations

import hashlib
import math

import numpy as np
from scipy.ndimage import map_coordinates
from scipy.signal import fftconvolve

from skynav.infra.errors import ConfigValueError

__all__ = ["TableKernel", "CutKernel", "STAMP_NOISE_FRACTION", "STAMP_CENTRE_TOLERANCE_PX"]

#: Largest change of any pixel, in units of its noise (the read noise and the point's own shot
#: noise), that drawing a faint point with a stamp smaller than its kernel's table may make
#: (:meth:`TableKernel.half_sizes_px`): the light beyond the smaller stamp is not drawn.
STAMP_NOISE_FRACTION = 0.1

#: Largest move of a point's centre of light, px, that drawing it with a smaller stamp than its
#: kernel's table may make (leaving out an asymmetric wing moves it): half the 1e-3 px
#: the truth's centre of light is checked to (tests/renderer/test_psf_models.py), the other
#: half left to phases between the 1/16 px grid the limit is found on.
STAMP_CENTRE_TOLERANCE_PX = 5e-4



class TableKernel:
    """A PSF given as fine tables of its pixel-integrated image (see :mod:`.optics`).

    ``tables[k][iy, ix]`` is the fraction of the flux of a point in the pixel whose centre is
    offset ``((ix - c) / n, (iy - c) / n)`` px from the point, ``c = shape // 2``. A stamp reads
    the table at the integer pixel offsets minus the point's sub-pixel phase, bilinearly
    between fine samples, and is not normalised: its sum is the share of the point's light
    inside it (all but the ``flux_fraction_lost`` it was sized for, or less where the model's
    half size is capped at ``max_half_px``: diffraction's far wings).

    With a field grid (``grid = (xs, ys, index[iy][ix])``) a point's stamp is the bilinear blend
    in ``(x, y)`` of the stamps of the four grid tables around it (clamped at the grid's edge):
    exactly a grid table's stamp at its grid point. With spectral nodes (``wavelengths_nm``, the
    effective wavelength of each table, ascending: a polychromatic Airy) a point's stamp is the
    linear blend, in log wavelength, of the two tables around its own effective wavelength
    (``wavelength_nm`` of :meth:`stamps`; clamped at the ends).

    With ``noise_floor_e`` (the camera's read noise, e-) a faint point may be drawn with a smaller
    stamp (:meth:`half_sizes_px`, :meth:`cut`; the rasteriser's ``stamp_e``). The limits are found
    for every table alone; a blend's change of a pixel is the blend of its tables' changes.

    Value semantics: equal and hashing alike when their tables are equal (sha256 of the bytes).

    Parameters
    ----------
    tables : sequence of ndarray, each shape (S, S)
        Fine tables of the pixel-integrated PSF, fraction of a point's flux per pixel, sampled
        ``n`` times per pixel.
    n : int
        Fine samples per pixel.
    half : int
        Largest stamp half size, px (stamps are at most ``(2 half + 1)^2`` px).
    grid : tuple, optional
        ``(xs, ys, index[iy][ix])``: the field points (px) of the tables, for a PSF that varies
        across the field.
    wavelengths_nm : sequence of float, optional
        Effective wavelength of each table, nm, ascending (a polychromatic Airy).
    noise_floor_e : float, optional
        The camera's read noise, e-: faint points may get smaller stamps.

    Examples
    --------
    The Airy kernel of the paper camera at 550 nm:

    >>> from skynav.renderer import TableKernel
    >>> from skynav.renderer.optics import kernel_for
    >>> from skynav.scenes import AiryPSFModel, paper_camera
    >>> kernel = kernel_for(paper_camera(psf=AiryPSFModel(wavelength_nm=550.0)))
    >>> isinstance(kernel, TableKernel), kernel.n, kernel.half
    (True, 32, 16)
    >>> stamp = kernel.stamps(np.array([[10.2, 20.7]]), 3)
    >>> stamp.shape, bool(stamp.sum() <= 1.0 + 1e-12)
    ((1, 7, 7), True)
    """

    def __init__(self, tables, n: int, half: int, grid=None, wavelengths_nm=None, noise_floor_e=None):
        # FFT ringing leaves values of ~1e-16 of the peak below 0: a charge is never negative
        self.tables = tuple(np.ascontiguousarray(np.maximum(t, 0.0), dtype=float) for t in tables)
        self.n = int(n)
        self.half = int(half)
        self.grid = grid
        self.wavelengths_nm = None if wavelengths_nm is None else tuple(float(w) for w in wavelengths_nm)
        if self.wavelengths_nm is not None and (grid is not None or len(self.wavelengths_nm) != len(self.tables)):
            raise ValueError("TableKernel: one effective wavelength per table, and no field grid with them")
        self.noise_floor_e = None if noise_floor_e is None else float(noise_floor_e)
        self._block_cache = {}
        self._limits = None
        self._last = {}

        h = hashlib.sha256()
        for t in self.tables:
            h.update(t.tobytes())
        h.update(repr((self.n, self.half, grid, self.wavelengths_nm, self.noise_floor_e)).encode())
        self._key = h.hexdigest()

    def __eq__(self, other):
        return isinstance(other, TableKernel) and other._key == self._key

    def __hash__(self):
        return hash(self._key)

    def __repr__(self):
        return f"TableKernel(<{len(self.tables)} table(s) {self.tables[0].shape}>, n={self.n}, half={self.half})"

    def half_size_px(self, flux_fraction_lost: float) -> int:
        """The stamp half size the model gave for the render's ``flux_fraction_lost``."""
        return self.half

    def quadrature_step_px(self) -> float:
        """Panel length of the streak quadrature, px: 0.35 (the pixel-integrated kernel is at
        least a pixel wide; see ``tests/renderer/test_psf_models.py`` for the convergence)."""
        return 0.35

    #: Its stamps hold the PSF as it is: the light beyond them (the model's half size is capped
    #: at ``max_half_px``) is not drawn, and the truth records the fraction drawn per source.
    truncated = True

    def blur_stamp(self, flux_fraction_lost: float, at_xy=None, wavelength_nm=None) -> np.ndarray:
        """The kernel :meth:`blur_crop` convolves a crop with, shape (2 half + 1, 2 half + 1):
        the stamp of a point at the centre of the pixel ``at_xy`` (px; the body's pixel, for a
        field grid; default (0, 0)), as it is (``wavelength_nm``: a polychromatic kernel's)."""
        at = np.zeros(2) if at_xy is None or not np.all(np.isfinite(at_xy)) else np.round(np.asarray(at_xy, dtype=float))
        return self.stamp(at, self.half, wavelength_nm)

    def blur_crop(self, crop: np.ndarray, flux_fraction_lost: float, at_xy=None, wavelength_nm=None):
        """A pixel-binned crop convolved, by FFT, with :meth:`blur_stamp`: the crop's light
        beyond the stamp is not drawn, as for a point. Padded by :attr:`half`; returns (blurred
        crop, half)."""
        k = self.blur_stamp(flux_fraction_lost, at_xy, wavelength_nm)
        return np.maximum(fftconvolve(np.asarray(crop, dtype=float), k, mode="full"), 0.0), self.half  # FFT ringing < 0

    def _blocks(self, k_table: int, h: int) -> tuple:
        """The table as phase blocks ``B[my, mx] = P[c + ky n + my, c + kx n + mx]`` for
        ``ky, kx`` in ``-h..h``: a stamp then reads 4 contiguous blocks, not 4 (2h+1)^2 scattered
        elements. Built once per table at :attr:`half`; a smaller ``h`` is a view of its middle."""
        got = self._block_cache.get(k_table)
        if got is None:
            n, table, big = self.n, self.tables[k_table], self.half
            c = table.shape[0] // 2
            m_lo = int(np.floor(-n / 2.0))
            m = np.arange(m_lo, m_lo + n + 3)
            k = np.arange(-big, big + 1)
            idx = c + k[None, :] * n + m[:, None]  # (n + 3, 2 half + 1)
            got = (table[idx[:, None, :, None], idx[None, :, None, :]], m_lo)  # (my, mx, ky, kx)
            self._block_cache[k_table] = got
        blocks, m_lo = got
        d = self.half - int(h)
        return (blocks if d == 0 else blocks[:, :, d:blocks.shape[2] - d, d:blocks.shape[3] - d]), m_lo

    def _stamps_one(self, k_table, f, h):
        """Stamps of table ``k_table`` at phases ``f`` (M, 2) (x, y): the bilinear read of its
        phase blocks, the table's values as they are (their sum is the light inside the stamp)."""
        blocks, m_lo = self._blocks(k_table, h)
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
        return top

    def _noise_limits(self) -> np.ndarray:
        """``F_max[h]``, e-: the largest charge of a point that may be drawn with its stamp cut
        to ``h`` < :attr:`half` (the light beyond the cut not drawn), from every table alone at
        every phase on a grid of 1/16 px:

        - no pixel of the full stamp changes by more than ``kappa`` =
          :data:`STAMP_NOISE_FRACTION` of its noise ``sqrt(sigma^2 + F s)`` (``sigma``
          :attr:`noise_floor_e`, ``s`` the full stamp's fraction there: the point's own shot
          noise); the pixels beyond the cut lose their whole value ``d = s``, those inside keep
          theirs. Per pixel, ``F s <= kappa sqrt(sigma^2 + F s)`` holds up to
          ``F = (kappa^2 s + sqrt(kappa^4 s^2 + 4 s^2 kappa^2 sigma^2)) / (2 s^2)``;
        - the centre of light (the first moment over the stamp's own light) moves by at most
          :data:`STAMP_CENTRE_TOLERANCE_PX` (else 0: never cut to ``h``; a coma's asymmetric
          wings move it most).
        """
        if self._limits is None:
            kap, sig = STAMP_NOISE_FRACTION, self.noise_floor_e
            g = (np.arange(16) + 0.5) / 16.0 - 0.5
            f = np.stack(np.meshgrid(g, g), axis=-1).reshape(-1, 2)
            big = self.half
            lim = np.full(big + 1, np.inf)
            lim[0] = 0.0
            for k in range(len(self.tables)):
                full = self._stamps_one(k, f, big)
                tot = full.sum(axis=(1, 2))
                kb = np.arange(-big, big + 1, dtype=float)
                centre_full = [full.sum(axis=1) @ kb / tot, full.sum(axis=2) @ kb / tot]
                for h in range(1, big):
                    inner = full[:, big - h:big + h + 1, big - h:big + h + 1]
                    it = inner.sum(axis=(1, 2))
                    kk = np.arange(-h, h + 1, dtype=float)
                    moved = max(float(np.max(np.abs(inner.sum(axis=1) @ kk / it - centre_full[0]))),
                                float(np.max(np.abs(inner.sum(axis=2) @ kk / it - centre_full[1]))))
                    if moved > STAMP_CENTRE_TOLERANCE_PX:
                        lim[h] = 0.0
                        continue
                    d = full.copy()
                    d[:, big - h:big + h + 1, big - h:big + h + 1] = 0.0
                    d = d.reshape(-1)
                    d = d[d > 0]
                    root = (kap * kap * d + np.sqrt((kap * kap * d) ** 2 + 4.0 * d * d * kap * kap * sig * sig)) / (2.0 * d * d)
                    lim[h] = min(lim[h], float(root.min()) if root.size else np.inf)
            self._limits = lim
        return self._limits

    def half_sizes_px(self, flux_e, flux_fraction_lost: float = 1e-6) -> np.ndarray:
        """Stamp half size of each point of charge ``flux_e`` (N,), e-: the smallest ``h`` whose
        cut stamp (:meth:`stamps` at ``h`` < :attr:`half`, the light beyond not drawn) changes no pixel by more
        than ``kappa`` of its noise nor its centre of light by more than
        :data:`STAMP_CENTRE_TOLERANCE_PX` (:meth:`_noise_limits`); :attr:`half` for
        every point without a :attr:`noise_floor_e`."""
        e = np.abs(np.asarray(flux_e, dtype=float).reshape(-1))
        out = np.full(e.shape, self.half, dtype=np.int64)
        if self.noise_floor_e is None or self.half < 2:
            return out
        lim = self._noise_limits()
        for h in range(self.half - 1, 0, -1):  # smallest admissible: overwrite downwards
            out[e <= lim[h]] = h
        return out

    def cut(self, half_size: int) -> "CutKernel":
        """This kernel drawn with stamps of ``half_size`` (see :class:`CutKernel`)."""
        return CutKernel(self, int(half_size))

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

    def _spectral_pair(self, wavelength_nm, m: int):
        """Lower node ``i`` (M,) and fraction ``t`` (M,) towards node ``i + 1`` of each point's
        effective wavelength, linear in log wavelength, clamped to the nodes (K >= 2)."""
        if wavelength_nm is None:
            raise ConfigValueError("psf.wavelength_nm", None, "each point's effective wavelength, nm (a polychromatic PSF)")
        lam = np.broadcast_to(np.asarray(wavelength_nm, dtype=float), (m,))
        g = np.log(np.asarray(self.wavelengths_nm))
        v = np.clip(np.log(lam), g[0], g[-1])
        i = np.clip(np.searchsorted(g, v, side="right") - 1, 0, g.size - 2)
        return i, (v - g[i]) / (g[i + 1] - g[i])

    def _spectral_weights(self, wavelength_nm, m: int):
        """Linear weights (M, K) in log wavelength of the spectral tables at each point's
        effective wavelength (clamped to the nodes)."""
        w = np.zeros((m, len(self.tables)))
        if len(self.tables) == 1:
            w[:, 0] = 1.0
            return w
        i, t = self._spectral_pair(wavelength_nm, m)
        rows = np.arange(m)
        w[rows, i] = 1.0 - t
        w[rows, i + 1] += t
        return w

    def weights(self, xy, wavelength_nm=None) -> np.ndarray:
        """Blend weights (M, K) of the tables for points ``xy`` (M, 2), px, and their effective
        wavelengths (M,), nm (polychromatic kernels only): the field grid's bilinear weights,
        the spectral nodes' linear ones, or 1 for a single table."""
        xy = np.asarray(xy, dtype=float).reshape(-1, 2)
        if self.grid is not None:
            return self._field_weights(xy)
        if self.wavelengths_nm is not None:
            return self._spectral_weights(wavelength_nm, xy.shape[0])
        return np.ones((xy.shape[0], 1))

    def on_grid(self, k_table: int, jacobian) -> np.ndarray:
        """Table ``k_table`` sampled on another pixel grid, normalised to a sum of 1.

        ``jacobian`` (2, 2): that grid's offsets per px of this one (``d_other = J d_self``,
        columns the images of this grid's x and y steps), e.g. screen pixels per camera pixel
        of a bench's collimator; sample ``[i, j]`` of the result is the table at offset
        ``J^-1 (j - c, i - c)`` px (``c`` the middle sample), bilinear between fine samples,
        zero beyond the stamps' reach (offsets over ``half + 0.5`` px in x or y: the pixels a
        stamp covers), normalised to a sum of 1 (a bench camera keeps a dot's whole light,
        where :meth:`stamps` draws the share inside the stamp). Convolving an image on the other
        grid with it and reading the result at a pixel's point there draws, up to that
        normalisation, what this PSF draws in that pixel.
        """
        J = np.asarray(jacobian, dtype=float).reshape(2, 2)
        table = self.tables[k_table]
        c = table.shape[0] // 2
        reach = min((c - 1) / self.n, self.half + 0.5)  # px of this grid the stamps reach from the centre
        corners = J @ np.array([[1, 1, -1, -1], [1, -1, 1, -1]], dtype=float) * reach
        m = int(math.ceil(np.max(np.abs(corners))))
        d = np.arange(-m, m + 1, dtype=float)
        dx, dy = np.meshgrid(d, d)  # [i, j] -> (dx = j - m, dy = i - m)
        u = np.linalg.solve(J, np.stack([dx.ravel(), dy.ravel()]))  # offsets in this grid's px
        vals = map_coordinates(table, [c + self.n * u[1], c + self.n * u[0]], order=1, mode="constant", cval=0.0)
        vals[np.max(np.abs(u), axis=0) > self.half + 0.5] = 0.0
        g = vals.reshape(dx.shape)
        return g / g.sum()

    def stamps(self, xy, half_size: int, wavelength_nm=None) -> np.ndarray:
        """Pixel-integrated stamps of points ``xy`` (see :class:`~skynav.renderer.kernels.Kernel`), each summing to the share
        of the PSF's light inside it; ``wavelength_nm`` (M,) or scalar, nm: the points' effective
        wavelengths (required by a polychromatic kernel, ignored by others).

        A stamp smaller than the table's (``half_size`` < :attr:`half`) is the middle of the full
        one: the light beyond it is not drawn.

        Read-only: the last call's result per half size is kept and returned again for the same
        points (the irradiance pass of a frame repeats the electrons' pass)."""
        xy = np.asarray(xy, dtype=float).reshape(-1, 2)
        lam = None
        if self.wavelengths_nm is not None and wavelength_nm is not None:
            lam = np.ascontiguousarray(np.broadcast_to(np.asarray(wavelength_nm, dtype=float), (xy.shape[0],)))
        key = (xy.tobytes(), int(half_size), None if lam is None else lam.tobytes())
        last = self._last.get(int(half_size))  # one read: another thread may replace it
        if last is not None and last[0] == key:
            return last[1]
        out = self._stamps(xy, half_size, lam)
        out.flags.writeable = False
        self._last[int(half_size)] = (key, out)
        return out

    def _stamps(self, xy, half_size, lam=None):
        if int(half_size) > self.half:  # beyond the table: no light (zeros around the table's stamp)
            pad = int(half_size) - self.half
            return np.pad(self.stamps(xy, self.half, lam), ((0, 0), (pad, pad), (pad, pad)))
        h = int(half_size)
        f = xy - np.floor(xy + 0.5)  # phase in [-0.5, 0.5)
        if len(self.tables) == 1:
            return self._stamps_one(0, f, h)
        if self.wavelengths_nm is not None:  # two neighbouring nodes per point: one write each
            i, t = self._spectral_pair(lam, xy.shape[0])
            s = np.empty((xy.shape[0], 2 * h + 1, 2 * h + 1))
            for k in np.unique(i):
                sel = np.flatnonzero(i == k)
                sa = self._stamps_one(k, f[sel], h)
                tk = t[sel]
                if np.any(tk > 0.0):
                    sb = self._stamps_one(k + 1, f[sel], h)
                    sb -= sa
                    sb *= tk[:, None, None]
                    sa += sb
                s[sel] = sa
            return s
        w = self.weights(xy, lam)
        s = np.zeros((xy.shape[0], 2 * h + 1, 2 * h + 1))
        for k in range(len(self.tables)):
            sel = np.flatnonzero(w[:, k] > 0.0)
            if sel.size:
                s[sel] += w[sel, k][:, None, None] * self._stamps_one(k, f[sel], h)
        return s

    def stamp(self, xy, half_size: int, wavelength_nm=None) -> np.ndarray:
        """Stamp of one point ``xy`` (2,), shape (2h+1, 2h+1); origin ``stamp_origin(xy, h)``."""
        return self.stamps(np.asarray(xy, dtype=float).reshape(1, 2), half_size, wavelength_nm)[0]


class CutKernel:
    """A :class:`TableKernel` drawn with stamps of one (smaller) half size.

    What the rasteriser draws a class of faint points with, once :meth:`TableKernel.half_sizes_px`
    has sized their stamps by their charge: :meth:`TableKernel.stamps` at ``half``, the middle
    of the full stamp (the light beyond it not drawn).

    Parameters
    ----------
    psf : TableKernel
        The full kernel.
    half : int
        The stamps' half size, px (``2 half + 1`` px a side).

    Examples
    --------
    >>> from skynav.renderer.optics import kernel_for
    >>> from skynav.scenes import AiryPSFModel, paper_camera
    >>> full = kernel_for(paper_camera(psf=AiryPSFModel(wavelength_nm=550.0)))
    >>> cut = full.cut(8)
    >>> cut.half_size_px(1e-6), cut.stamps(np.array([[10.2, 20.7]]), 8).shape
    (8, (1, 17, 17))
    """

    def __init__(self, psf: TableKernel, half: int):
        self.psf = psf
        self.half = int(half)

    def __eq__(self, other):
        return isinstance(other, CutKernel) and other.psf == self.psf and other.half == self.half

    def __hash__(self):
        return hash((self.psf, self.half))

    def __repr__(self):
        return f"CutKernel({self.psf!r}, half={self.half})"

    def half_size_px(self, flux_fraction_lost: float) -> int:
        return self.half

    def quadrature_step_px(self) -> float:
        return self.psf.quadrature_step_px()

    truncated = True

    def stamps(self, xy, half_size: int, wavelength_nm=None) -> np.ndarray:
        return self.psf.stamps(xy, half_size, wavelength_nm)
