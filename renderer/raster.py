"""Analytic rasteriser of point sources (stars, unresolved bodies) with streaks.

Each source moves along a piecewise-linear path sampled at S equally spaced instants over the
exposure; its flux is spread uniformly in time along the path, convolved with the PSF and
integrated over the pixels.

Method: every path segment (equal time, so equal flux ``electrons / (S - 1)``) is cut into
``K = ceil(length / d)`` equal panels and each panel is integrated in time with the 2-point
Gauss-Legendre rule (two points at ``0.5 -+ 0.5/sqrt(3)`` of the panel, half the panel's flux
each; error O(d^4), no end-point error unlike the midpoint rule). This conserves the flux
exactly and the nodes are symmetric in each panel, so the centroid of each segment is exactly
its mid-time position and the centroid of the streak is the time-mean position of the path.
The panel length ``d`` comes from the PSF (``psf.quadrature_step_px()``: ``1.5 sigma`` for a
Gaussian, capped at 0.75 px; < 1.1e-5 of the flux per pixel from the converged image). Every point is drawn with the PSF's exact
pixel-integrated stamp (erf differences for the Gaussian), sized so that less than
``flux_fraction_lost`` of the flux falls outside it. Flux falling off the image is lost.

The points of all the sources are drawn in one batched computation (stamps as an array
(M, 2h+1, 2h+1), then ``np.bincount`` into the image), in chunks to bound memory.
"""

from __future__ import annotations

import numpy as np

from skynav.infra.errors import ConfigValueError

from .kernels import Kernel, stamp_origin

__all__ = ["rasterize", "streak_subsamples"]

_CHUNK_ENTRIES = 1 << 22
_GL2 = 0.5 / np.sqrt(3.0)  # 2-point Gauss-Legendre nodes on a unit panel: 0.5 -+ _GL2  # stamp pixels per batch (~32 MB of float64 per array)


def streak_subsamples(paths_xy, electrons, step_px: float):
    """Cut piecewise-linear paths into midpoint sub-samples of equal time.

    Parameters
    ----------
    paths_xy : ndarray, shape (N, S, 2), px
        Position of each source at S >= 2 equally spaced instants of the exposure.
    electrons : ndarray, shape (N,), e-
        Total charge of each source over the exposure.
    step_px : float
        Largest panel length along a segment, px.

    Returns
    -------
    xy : ndarray, shape (M, 2), px (static segments: one point; moving ones: 2 Gauss-Legendre
        nodes per panel of length <= ``step_px``)
    flux_e : ndarray, shape (M,), e- (sums to ``electrons`` per source)
    source : ndarray, shape (M,), int (index of the source of each sub-sample)
    """
    p = np.asarray(paths_xy, dtype=float)
    e = np.asarray(electrons, dtype=float)
    n, s = p.shape[0], p.shape[1]
    p0 = p[:, :-1, :].reshape(-1, 2)
    dp = (p[:, 1:, :] - p[:, :-1, :]).reshape(-1, 2)
    seg_flux = np.repeat(e / (s - 1), s - 1)
    seg_source = np.repeat(np.arange(n), s - 1)
    length = np.hypot(dp[:, 0], dp[:, 1])
    k = np.maximum(1, np.ceil(length / step_px - 1e-9)).astype(np.int64)
    # points per segment: 1 for a static segment, else 2 Gauss-Legendre nodes per panel
    npts = np.where(length > 0.0, 2 * k, 1)
    if np.all(npts == 1):  # static sources: no expansion needed
        return p0 + 0.5 * dp, seg_flux, seg_source
    seg = np.repeat(np.arange(k.size), npts)
    start = np.cumsum(npts) - npts
    local = np.arange(seg.size) - start[seg]
    moving = npts[seg] > 1
    panel = local // 2
    node = np.where(local % 2 == 0, -_GL2, _GL2)
    t = np.where(moving, (panel + 0.5 + node) / k[seg], 0.5)
    xy = p0[seg] + t[:, None] * dp[seg]
    return xy, seg_flux[seg] / npts[seg], seg_source[seg]


def _unique_inverse(flat: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``np.unique(flat, return_inverse=True)`` of a 1-D integer array: the sorted distinct values
    and each entry's index among them, the same two arrays, by one stable argsort (np.unique
    makes extra passes over the array besides the sort)."""
    order = np.argsort(flat, kind="stable")
    ordered = flat[order]
    first = np.empty(ordered.size, bool)
    first[:1] = True
    np.not_equal(ordered[1:], ordered[:-1], out=first[1:])
    inv = np.empty(ordered.size, np.intp)
    inv[order] = np.cumsum(first) - 1
    return ordered[first], inv


def _accumulate(images, flat, weights, support=None) -> None:
    """``image[flat] += w`` for each image and its weights, summing repeated indices, in place
    (images flat; one index array for all). A few stamps on a large image (a bench screen) are
    summed over their distinct pixels only (found once for all the images), not over a full-size
    ``bincount``; both add each pixel's weights in the same order, then to the image once, so the
    result is the same to the bit. ``support`` (a list): the flat indices written are appended to
    it (once)."""
    if flat.size * 16 < images[0].size:
        u, inv = _unique_inverse(flat)
        for image, w in zip(images, weights):
            image[u] += np.bincount(inv, weights=w, minlength=u.size)
        if support is not None:
            support.append(u)
    else:
        for i, (image, w) in enumerate(zip(images, weights)):
            add = np.bincount(flat, weights=w, minlength=image.size)
            image += add
            if support is not None and i == 0:
                support.append(np.flatnonzero(add))


def rasterize(shape, paths_xy, electrons, psf: Kernel, *, flux_fraction_lost: float = 1e-6, step_px: float | None = None,
              support: list | None = None, centre_of_light: np.ndarray | None = None,
              out: np.ndarray | None = None, wavelength_nm=None, also: tuple | None = None,
              stamp_e=None, drawn_e: np.ndarray | None = None) -> np.ndarray:
    """Noise-free image (e-) of point sources moving along sampled paths.

    Parameters
    ----------
    shape : tuple of int
        ``(H, W)`` of the image, px.
    paths_xy : ndarray, shape (N, S, 2), px
        Pixel position ``(x, y)`` of each source at S >= 2 equally spaced instants over the
        exposure (S = 2 with equal points: a static source; S = 2: a straight streak; more
        points for curved paths). Sources with any non-finite position are skipped.
    electrons : ndarray, shape (N,), e-
        Total charge of each source over the exposure.
    psf : Kernel
        Kernel (e.g. ``GaussianKernel(camera.defocus_sigma_px)``).
    flux_fraction_lost : float
        Largest fraction of a point's flux allowed outside its stamp.
    step_px : float, optional
        Panel length of the streak quadrature, px (default ``psf.quadrature_step_px()`` or 0.05).
    support : list, optional
        Arrays of the flat indices of the pixels drawn are appended to it (every nonzero pixel is
        among them, of ``also``'s image too), so a caller need not scan a large, mostly dark image.
    centre_of_light : ndarray, shape (N, 2), optional
        Filled with each source's centre of light, px: the first moment of its drawn stamps
        (pixel centres weighted by their charge, the parts off the image included), NaN for a
        source not drawn. The PSF's asymmetry (coma) shows in it; the image is unchanged.
    out : ndarray, shape (H, W), float64, C-contiguous, optional
        Add the sources into this image (returned) instead of a new zero image.
    wavelength_nm : ndarray, shape (N,), nm, optional
        Effective wavelength of each source, for a polychromatic kernel (its stamps blend its
        spectral tables there; see :class:`~skynav.renderer.table_kernels.TableKernel`).
    also : tuple (values, image), optional
        A second quantity of each source (``values``, shape (N,), e.g. its irradiance) drawn with
        the same stamps into ``image`` (shape (H, W), float64, C-contiguous), as a second call
        with ``out=image`` would draw it, to the bit, at the cost of one: the stamps, their
        pixels and their order are computed once.
    stamp_e : ndarray, shape (N,), e-, optional
        Each source's charge, to size its stamps by (a kernel with ``half_sizes_px``, e.g. a
        :class:`~skynav.renderer.table_kernels.TableKernel`, draws faint sources with smaller stamps, their
        light beyond not drawn); None: every stamp the kernel's full size. Pass the electrons for the
        irradiance image too, so that both are drawn with the same stamps.
    drawn_e : ndarray, shape (N,), optional
        Filled with the charge each source's stamps hold, e- (the parts off the image included;
        0 for a source not drawn): its electrons times the fraction of the PSF's light its stamps
        hold (a table kernel's stamps hold the PSF as it is, the light beyond them not drawn).

    Returns
    -------
    ndarray, shape (H, W), float64, e- per pixel

    Examples
    --------
    >>> from skynav.renderer import GaussianKernel, rasterize
    >>> img = rasterize((16, 16), [[[7.3, 8.1], [7.3, 8.1]]], [1000.0], GaussianKernel(0.5))
    >>> round(float(img.sum()), 3)
    1000.0
    """
    (h_img, w_img), p, e = _checked_inputs(shape, paths_xy, electrons)
    if out is not None:
        _check_image(out, (h_img, w_img), "raster.out")
        image = out.reshape(-1)
    else:
        image = np.zeros(h_img * w_img, dtype=float)
    if also is not None:
        e2 = np.asarray(also[0], dtype=float).reshape(-1)
        out2 = also[1]
        if e2.shape != e.shape:
            raise ConfigValueError("raster.also", e2.shape, f"values of shape ({p.shape[0]},) to match paths_xy")
        _check_image(out2, (h_img, w_img), "raster.also")
        drawn = np.isfinite(e) & (e != 0)
        if not np.array_equal(drawn, np.isfinite(e2) & (e2 != 0)):  # other sources drawn: two calls
            rasterize(shape, p, e2, psf, flux_fraction_lost=flux_fraction_lost, step_px=step_px, out=out2,
                      wavelength_nm=wavelength_nm, stamp_e=stamp_e, support=support)
            return rasterize(shape, p, e, psf, flux_fraction_lost=flux_fraction_lost, step_px=step_px, support=support,
                             centre_of_light=centre_of_light, out=out, wavelength_nm=wavelength_nm, stamp_e=stamp_e,
                             drawn_e=drawn_e)
    if centre_of_light is not None:
        centre_of_light[...] = np.nan
    if drawn_e is not None:
        drawn_e[...] = 0.0
    if p.shape[0] == 0:
        return image.reshape(h_img, w_img)

    sizes = None
    if stamp_e is not None:
        if np.shape(stamp_e) != e.shape:
            raise ConfigValueError("raster.stamp_e", np.shape(stamp_e), f"shape ({p.shape[0]},) to match paths_xy")
        sizes = psf.half_sizes_px(stamp_e, flux_fraction_lost)
    if sizes is not None and np.any(sizes != psf.half_size_px(flux_fraction_lost)):  # one call per stamp size
        _rasterize_by_size(image.reshape(h_img, w_img), p, e, psf, sizes, flux_fraction_lost=flux_fraction_lost,
                           step_px=step_px, support=support, centre_of_light=centre_of_light, wavelength_nm=wavelength_nm,
                           also=None if also is None else (e2, out2), drawn_e=drawn_e)
        return image.reshape(h_img, w_img)
    _rasterize_one_size(image, (h_img, w_img), p, e, psf, flux_fraction_lost=flux_fraction_lost, step_px=step_px,
                        support=support, centre_of_light=centre_of_light, wavelength_nm=wavelength_nm,
                        also=None if also is None else (e2, out2), drawn_e=drawn_e)
    return image.reshape(h_img, w_img)


def _rasterize_one_size(image, shape, p, e, psf, *, flux_fraction_lost, step_px, support, centre_of_light,
                        wavelength_nm, also, drawn_e) -> None:
    """:func:`rasterize`'s drawing, every stamp of the kernel's one half size, into the flat
    ``image`` (and ``also``'s): the sources that may touch the image, cut into points along
    their paths, their stamps added, their moments written to ``centre_of_light`` and
    ``drawn_e``."""
    half = int(psf.half_size_px(flux_fraction_lost))
    ok = _touching(p, e, half, shape)
    if not np.any(ok):
        return
    if step_px is None:
        step_px = psf.quadrature_step_px()
    xy, flux, source = streak_subsamples(p[ok], e[ok], float(step_px))
    lam = None
    if wavelength_nm is not None:
        lam = np.broadcast_to(np.asarray(wavelength_nm, dtype=float), e.shape)[ok][source]
    images = [image]
    fluxes = [flux]
    if also is not None:
        images.append(also[1].reshape(-1))
        fluxes.append(streak_subsamples(p[ok], also[0][ok], float(step_px))[1])
    moments = centre_of_light is not None or drawn_e is not None
    m = _draw_points(images, shape, xy, fluxes, source if moments else None, int(np.count_nonzero(ok)), psf,
                     half, lam, support)
    if centre_of_light is not None:
        with np.errstate(invalid="ignore", divide="ignore"):
            centre_of_light[np.flatnonzero(ok)] = m[1] / m[0][:, None]
    if drawn_e is not None:
        drawn_e[np.flatnonzero(ok)] = m[0]


def _checked_inputs(shape, paths_xy, electrons):
    """``(H, W)``, the paths (N, S, 2) and the electrons (N,) as arrays, or one line naming the
    bad one."""
    h_img, w_img = (int(v) for v in shape)
    if h_img <= 0 or w_img <= 0:
        raise ConfigValueError("raster.shape", shape, "(H, W) with H, W > 0")
    p = np.asarray(paths_xy, dtype=float)
    if p.ndim != 3 or p.shape[2] != 2 or p.shape[1] < 2:
        raise ConfigValueError("raster.paths_xy", p.shape, "an array of shape (N, S, 2) with S >= 2")
    e = np.asarray(electrons, dtype=float).reshape(-1)
    if e.shape[0] != p.shape[0]:
        raise ConfigValueError("raster.electrons", e.shape, f"shape ({p.shape[0]},) to match paths_xy")
    return (h_img, w_img), p, e


def _touching(p, e, half: int, shape) -> np.ndarray:
    """Which sources may touch the image (N,): finite, with light, and their whole path plus a
    stamp of half size ``half`` not outside it."""
    h_img, w_img = shape
    ok = np.all(np.isfinite(p), axis=(1, 2)) & np.isfinite(e) & (e != 0)
    lo = np.min(p, axis=1)
    hi = np.max(p, axis=1)
    margin = half + 1.0
    ok &= (hi[:, 0] >= -0.5 - margin) & (lo[:, 0] <= w_img - 0.5 + margin)
    ok &= (hi[:, 1] >= -0.5 - margin) & (lo[:, 1] <= h_img - 0.5 + margin)
    return ok


def _check_image(image, shape, key: str) -> None:
    """Refuse an output image that is not a C-contiguous float64 array of ``shape``."""
    if image.shape != shape or image.dtype != np.float64 or not image.flags.c_contiguous:
        what = "array" if key == "raster.out" else "image"
        raise ConfigValueError(key, (image.shape, image.dtype), f"a C-contiguous float64 {what} of shape {shape}")


def _rasterize_by_size(image, p, e, psf, sizes, *, flux_fraction_lost, step_px, support, centre_of_light,
                       wavelength_nm, also, drawn_e) -> None:
    """:func:`rasterize` of sources whose stamps have several half sizes (``sizes``, (N,)): one
    call per size, with the kernel cut to it (``psf.cut(h)``), into ``image`` (and ``also``'s)."""
    lam_all = None if wavelength_nm is None else np.broadcast_to(np.asarray(wavelength_nm, dtype=float), e.shape)
    for h in np.unique(sizes):
        sel = np.flatnonzero(sizes == h)
        c = None if centre_of_light is None else np.empty((sel.size, 2))
        d = None if drawn_e is None else np.empty(sel.size)
        rasterize(image.shape, p[sel], e[sel], psf.cut(h), flux_fraction_lost=flux_fraction_lost, step_px=step_px,
                  support=support, centre_of_light=c, out=image,
                  wavelength_nm=None if lam_all is None else lam_all[sel],
                  also=None if also is None else (also[0][sel], also[1]), drawn_e=d)
        if c is not None:
            centre_of_light[sel] = c
        if d is not None:
            drawn_e[sel] = d


def _draw_points(images, shape, xy, fluxes, source, n_sources: int, psf, half: int, lam, support):
    """Add the stamps of points ``xy`` (M, 2) with fluxes ``fluxes[i]`` (M,) into the flat
    ``images[i]`` of ``shape``, in chunks; ``source`` (M,) or None: the point's source, whose
    zeroth and first moments of the drawn stamps are returned, ``(m0 (n_sources,), m1
    (n_sources, 2))`` (None without ``source``)."""
    h_img, w_img = shape
    if source is not None:
        m0 = np.zeros(n_sources)
        m1 = np.zeros((n_sources, 2))
    n_side = 2 * half + 1
    per_point = n_side * n_side
    chunk = max(1, _CHUNK_ENTRIES // per_point)
    k = np.arange(n_side)
    offsets = (k[:, None] * w_img + k[None, :]).ravel()  # flat offsets of a stamp, (n*n,)
    for a in range(0, xy.shape[0], chunk):
        pts = xy[a : a + chunk]
        st = psf.stamps(pts, half) if lam is None else psf.stamps(pts, half, wavelength_nm=lam[a : a + chunk])
        ws = [(st * f[a : a + chunk, None, None]).reshape(pts.shape[0], per_point) for f in fluxes]
        w = ws[0]
        origin = stamp_origin(pts, half)
        if source is not None:  # zeroth and first moments of the stamps, per source
            w3 = w.reshape(pts.shape[0], n_side, n_side)
            wx, wy = w3.sum(axis=1), w3.sum(axis=2)
            sw = wx.sum(axis=1)
            src = source[a : a + chunk]
            m0 += np.bincount(src, weights=sw, minlength=m0.size)
            m1[:, 0] += np.bincount(src, weights=wx @ k + origin[:, 0] * sw, minlength=m0.size)
            m1[:, 1] += np.bincount(src, weights=wy @ k + origin[:, 1] * sw, minlength=m0.size)
        full = (origin[:, 0] >= 0) & (origin[:, 0] + n_side <= w_img) & (origin[:, 1] >= 0) & (origin[:, 1] + n_side <= h_img)
        base = origin[:, 1] * w_img + origin[:, 0]
        if np.any(full):  # stamps wholly on the image: flat index = base + offsets
            flat = base[full, None] + offsets[None, :]
            _accumulate(images, flat.ravel(), [wi[full].ravel() for wi in ws], support)
        if not np.all(full):  # stamps over an edge: keep the pixels on the image
            o = origin[~full]
            cols = o[:, 0:1] + k[None, :]
            rows = o[:, 1:2] + k[None, :]
            inside = (((rows >= 0) & (rows < h_img))[:, :, None] & ((cols >= 0) & (cols < w_img))[:, None, :]).reshape(o.shape[0], per_point)
            flat = (rows[:, :, None] * w_img + cols[:, None, :]).reshape(o.shape[0], per_point)
            _accumulate(images, flat[inside], [wi[~full][inside] for wi in ws], support)
    return None if source is None else (m0, m1)
