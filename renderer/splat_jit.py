"""The point sources of a batch of frames drawn by Dr.Jit: the stars and the bodies drawn as
points, every PSF model's pixel-integrated stamps along each source's streak, added into the
batch's sensor input on the device, with each source's centre of light and the charge drawn.

What it computes: the point sources of :func:`~skynav.renderer.expected.expected_image` (the
numpy reference), for every kernel of the renderer (:func:`~skynav.renderer.optics.kernel_for`:
the Gaussian; the Airy, optical, tabulated and field-grid tables; a polychromatic camera's
spectral nodes for the stars at their effective wavelengths and each body's own table). The
host makes, per frame (:func:`frame_optics`), the sources' electrons and paths (each body drawn
as a point at its photocentre), sizes each source's stamps by its charge
(``half_sizes_px``: a faint source of a table kernel gets a smaller stamp, the light beyond not
drawn), keeps the sources that may touch the image and cuts their paths into the sub-samples
of :func:`~skynav.renderer.raster.streak_subsamples` with the kernel's quadrature step, as
:func:`~skynav.renderer.raster.rasterize` does; the points are grouped by kernel and half size
(:class:`PointGroup`). Then :func:`splat_points` runs one kernel per group of the whole batch
over its (point, stamp pixel) lanes (in launches of at most 2^24 lanes): the stamp value
(:mod:`~skynav.renderer.splat_tables_jit`), in float64, times the point's electrons,
scatter-added in float64 into the (N * H * W) sensor input (the pixels off the image dropped,
as the reference drops them; a pixel of a streak sums hundreds of sub-samples) and rounded to
float32 once; each point's stamp is also summed over its own lanes into its zeroth and first
moments (the parts off the image included, as the reference's; a block reduction, no atomics).
The points' sums come back with the launch and are added per source on the host in the points'
order (:class:`PointMoments`), so the truth's figures of a frame do not depend on the batch it
was drawn in; :func:`with_moments` makes its centres of light (first moments over zeroth) and
fractions drawn.

What stays per frame on the host: the ray tracing of the resolved bodies (Mitsuba;
:func:`~skynav.renderer.expected.expected_image` of the scene without its stars and point-drawn
bodies, with the same ``rng`` draws: only the ray-traced bodies draw), whose crops are handed
over for :mod:`~skynav.renderer.bodies_jit` to blur and composite into the same input.

The result differs from the numpy reference by roundings: the float64 sums in another order
(atomic adds), the input's float32 part (the bodies drawn on the host) and the stamps' sum
rounded apart, the Gaussian's erf differences written without the reference's
``0.5 (1 + erf)`` (tested to 1e-5 relative per pixel, measured 6e-8 to 1e-7, and the centres of
light to 1e-9 px: tests/renderer/test_batch_splat.py and test_batch_tables.py). One Python body
is traced for Dr.Jit's LLVM and CUDA backends.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from .expected import _split_bodies, _to_photocentres, expected_image, source_paths
from .kernels import stamp_origin
from .optics import is_polychromatic, kernel_for, star_effective_wavelengths_nm
from .radiometry import Radiometry
from .raster import _touching, streak_subsamples
from .sensor_jit import _module_of
from .splat_tables_jit import stamp_values

__all__ = ["PointGroup", "FramePoints", "PointMoments", "star_points", "frame_optics", "splat_points", "with_moments"]


@dataclasses.dataclass(frozen=True, kw_only=True, eq=False)
class PointGroup:
    """Sub-samples of a frame's sources drawn with one kernel and one stamp half size.

    Attributes
    ----------
    kernel : GaussianKernel or TableKernel
    half : int
        The stamps' half size, px (``2 half + 1`` a side).
    xy : ndarray, shape (M, 2), px
    flux_e : ndarray, shape (M,), e-
    source : ndarray, shape (M,), int
        Each point's source, among the frame's (:class:`FramePoints`).
    wavelength_nm : ndarray, shape (M,), or None
        Each point's effective wavelength, nm (a kernel of spectral nodes).
    """

    kernel: object
    half: int
    xy: np.ndarray
    flux_e: np.ndarray
    source: np.ndarray
    wavelength_nm: np.ndarray | None = None


@dataclasses.dataclass(frozen=True, kw_only=True, eq=False)
class FramePoints:
    """A frame's point sources as the splat draws them: the stars, then the bodies drawn as
    points (``bodies``, by name).

    Attributes
    ----------
    groups : tuple of PointGroup
    electrons : ndarray, shape (S,), e-
        Each source's electrons.
    drawn : ndarray, shape (S,), bool
        The sources that may touch the image (their stamps drawn).
    n_stars : int
    bodies : tuple of str
    truncated : bool
        Whether the kernels are table kernels (the truth records the fraction drawn).
    """

    groups: tuple
    electrons: np.ndarray
    drawn: np.ndarray
    n_stars: int
    bodies: tuple = ()
    truncated: bool = False

    @property
    def n_sources(self) -> int:
        return int(self.electrons.size)


def _groups(kernel, paths, e, index, lam, shape, flux_fraction_lost):
    """The :class:`PointGroup` of sources ``index`` (their ``paths``, electrons ``e``, effective
    wavelengths ``lam`` or None) drawn with ``kernel``, one per stamp half size, as
    :func:`~skynav.renderer.raster.rasterize` with ``stamp_e`` cuts them; and which of them are
    drawn (bool, like ``index``)."""
    sizes = kernel.half_sizes_px(e, flux_fraction_lost)
    step = float(kernel.quadrature_step_px())
    groups, drawn = [], np.zeros(e.size, bool)
    for h in np.unique(sizes).tolist():
        sel = np.flatnonzero(sizes == h)
        ok = sel[_touching(paths[sel], e[sel], int(h), shape)]
        if not ok.size:
            continue
        xy, flux, src = streak_subsamples(paths[ok], e[ok], step)
        groups.append(PointGroup(kernel=kernel, half=int(h), xy=xy, flux_e=flux, source=index[ok][src],
                                 wavelength_nm=None if lam is None else lam[ok][src]))
        drawn[ok] = True
    return groups, drawn


def star_points(scene, options, bodies=(), paths=None, body_paths=None) -> FramePoints:
    """A frame's stars, and ``bodies`` (drawn as points: ``body_paths`` (B, S, 2), px, at their
    photocentres), as :class:`FramePoints`; ``paths``: the stars' paths (N, S, 2), px
    (default :func:`~skynav.renderer.expected.source_paths` of the scene's stars)."""
    cam = scene.camera
    ffl = options.flux_fraction_lost
    stars = scene.stars
    rad = Radiometry.for_camera(cam)
    star_e = np.asarray(rad.star_electrons_per_s(stars.v_mag, stars.teff_k), dtype=float) * cam.exposure_s
    body_e = np.array([float(rad.body_electrons_per_s(b.name, b.v_mag)) * cam.exposure_s if np.isfinite(b.v_mag)
                       else 0.0 for b in bodies])
    n_s, shape = star_e.size, (cam.height, cam.width)
    if paths is None:
        paths = source_paths(scene, stars.u_icrs.reshape(-1, 3), options)
    psf = kernel_for(cam, None, ffl)
    poly = is_polychromatic(cam)
    groups, drawn = [], np.zeros(n_s + len(bodies), bool)
    if n_s:
        lam = star_effective_wavelengths_nm(cam, stars.teff_k) if poly else None
        g, d = _groups(psf, np.asarray(paths, dtype=float), star_e, np.arange(n_s), lam, shape, ffl)
        groups += g
        drawn[:n_s] = d
    for j, b in enumerate(bodies):  # a polychromatic camera draws each body with its own spectrum's table
        kern = kernel_for(cam, ("body", b.name), ffl) if poly else psf
        g, d = _groups(kern, body_paths[j:j + 1], body_e[j:j + 1], np.array([n_s + j]), None, shape, ffl)
        groups += g
        drawn[n_s + j] = d[0]
    return FramePoints(groups=tuple(groups), electrons=np.concatenate([star_e, body_e]), drawn=drawn, n_stars=n_s,
                       bodies=tuple(b.name for b in bodies), truncated=bool(psf.truncated))


def _point_bodies(scene, options):
    """The bodies :func:`~skynav.renderer.expected.expected_image` draws as points, as it picks
    them, and their paths at their photocentres ((B, S, 2), px) and photocentres ({name: (2,)})."""
    cam = scene.camera
    track, _, bodies = _split_bodies(scene, cam, options)
    if not bodies:
        return [], None, {}
    paths = source_paths(scene, np.array([b.u_icrs for b in bodies]).reshape(-1, 3), options)
    return bodies, paths, _to_photocentres(scene, cam, bodies, track, paths)


def frame_optics(scene, rng, options, support, paths=None, traced_out=None):
    """A frame's optics with its point sources left to :func:`splat_points`: the ray-traced
    bodies (no background) into the returned image and ``support``, as
    :func:`~skynav.renderer.expected.expected_image` makes them (same ``rng`` draws); returns
    ``(expected image for the truth, FramePoints)``, the point sources' electrons and
    photocentres filled in, their centres of light and fractions drawn left to
    :func:`with_moments`. ``paths``: the stars' paths, px (default: projected here);
    ``traced_out``: a list, the ray-traced bodies left out of the image too, handed over in it
    (``expected_image``'s; :mod:`~skynav.renderer.bodies_jit` draws them)."""
    bodies, body_paths, photocentre = _point_bodies(scene, options)
    names = {b.name for b in bodies}
    stars = scene.stars
    no_stars = dataclasses.replace(stars, **{f.name: getattr(stars, f.name)[:0] for f in dataclasses.fields(stars)})
    rest_scene = dataclasses.replace(scene, stars=no_stars, bodies=tuple(b for b in scene.bodies if b.name not in names))
    rest = expected_image(rest_scene, rng=rng, options=dataclasses.replace(options, background_e_per_px_s=0.0),
                          with_irradiance=False, support=support, traced_out=traced_out)
    points = star_points(scene, options, bodies, paths, body_paths)
    body_e = dict(rest.body_electrons)
    body_e.update({name: float(e) for name, e in zip(points.bodies, points.electrons[points.n_stars:])})
    return dataclasses.replace(rest, star_electrons=points.electrons[:points.n_stars], body_electrons=body_e,
                               body_photocentre={**rest.body_photocentre, **photocentre}), points


def with_moments(expected, points: FramePoints, m0, m1):
    """``expected`` with its point sources' centres of light (``m1 / m0``, NaN where not drawn)
    and, for table kernels, fractions drawn (``m0`` over the electrons; NaN without light), from
    each source's zeroth ``m0`` (S,) and first moments ``m1`` (S, 2) of its drawn stamps."""
    centre = np.full((points.n_sources, 2), np.nan)
    with np.errstate(invalid="ignore", divide="ignore"):
        centre[points.drawn] = m1[points.drawn] / m0[points.drawn, None]
    n_s = points.n_stars
    body_centre = dict(expected.body_centre_of_light or {})
    body_centre.update({name: centre[n_s + j] for j, name in enumerate(points.bodies)})
    star_fraction, body_fraction = None, expected.body_fraction_drawn
    if points.truncated:
        e = points.electrons
        with np.errstate(invalid="ignore", divide="ignore"):
            fraction = np.where(e > 0, np.where(points.drawn, m0, 0.0) / e, np.nan)
        star_fraction = fraction[:n_s]
        body_fraction = dict(body_fraction or {})
        body_fraction.update({name: float(fraction[n_s + j]) for j, name in enumerate(points.bodies)})
    return dataclasses.replace(expected, star_centre_of_light=centre[:n_s], body_centre_of_light=body_centre,
                               star_fraction_drawn=star_fraction, body_fraction_drawn=body_fraction)


def _batch_groups(frames):
    """The groups of every frame, joined by (kernel, half size): ``{(kernel, half): [(frame,
    source offset, group), ...]}``, and each frame's first source in the batch's moments."""
    joined, first, total = {}, [], 0
    for i, fp in enumerate(frames):
        first.append(total)
        for g in fp.groups:
            joined.setdefault((g.kernel, g.half), []).append((i, total, g))
        total += fp.n_sources
    return joined, first, total


@dataclasses.dataclass(frozen=True, eq=False)
class PointMoments:
    """The moments :func:`splat_points` makes on the device: for each launch, its points'
    sources (numpy) and the three sums of each point's stamp (zeroth, first x, first y: Dr.Jit
    Float64 arrays, one value a point). :meth:`numpy` sums them per source on the host."""

    n_sources: int
    launches: list

    def arrays(self) -> list:
        """The device arrays (to evaluate with the launch)."""
        return [v for _, sums in self.launches for v in sums]

    def numpy(self) -> list:
        """The sources' zeroth, first x and first y moments, three numpy arrays (S,): each
        source's points added in their order (one ``bincount`` over every launch's points), so
        a source's moments do not depend on the other frames of its batch."""
        src = np.concatenate([s for s, _ in self.launches])
        return [np.bincount(src, weights=np.concatenate([sums[k].numpy()[:s.size] for s, sums in self.launches]),
                            minlength=self.n_sources) for k in range(3)]


def splat_points(sig, frames, shape, background_e: float = 0.0):
    """Add the point sources of each frame (``frames``, one :class:`FramePoints` per frame) and
    ``background_e`` per pixel into the batch's sensor input ``sig`` (a Dr.Jit Float of N * H *
    W, frame-major). Returns ``(new input, moments)``: the input lazy, ``moments`` a
    :class:`PointMoments` of the batch's sources (see :func:`frame_moments`), or None without a
    source."""
    # Dr.Jit only for the JIT backends: import skynav.renderer loads neither Dr.Jit nor Mitsuba
    import drjit as dr

    jt = _module_of(sig)
    joined, _, total = _batch_groups(frames)
    if total == 0:
        return (sig + jt.Float(background_e) if background_e else sig), None
    # the stamps summed in float64 (a pixel of a streak sums hundreds of sub-samples), rounded once
    acc = jt.Float64(sig) + background_e
    moments = PointMoments(total, [])
    backend = "cuda" if jt.__name__.endswith("cuda") else "llvm"
    for (kernel, half), parts in joined.items():
        _splat_group(jt, acc, moments.launches, kernel, half, parts, shape, backend)
    return jt.Float(acc), moments


#: Most (point, stamp pixel) lanes of one launch of a group (a long streak of a table kernel
#: has hundreds of sub-samples of a thousand pixels each): the stamp sums are reduced from the
#: lanes' values held in memory, three float64 arrays, 384 MiB at this size.
_LANES_PER_LAUNCH = 1 << 24


def _splat_group(jt, acc, moments, kernel, h, parts, shape, backend):
    """The (point, stamp pixel) lanes of a joined group (``parts``: (frame, source offset,
    PointGroup)), in launches of at most :data:`_LANES_PER_LAUNCH`: the stamps into ``acc``
    (float64), each launch's points' sources and stamp sums appended to ``moments``."""
    per_point = (2 * h + 1) ** 2
    cols = {"xy": np.concatenate([g.xy for _, _, g in parts]),
            "flux": np.concatenate([g.flux_e for _, _, g in parts]),
            "frame": np.concatenate([np.full(g.flux_e.size, i, np.uint32) for i, _, g in parts]),
            "source": np.concatenate([(g.source + off).astype(np.uint32) for _, off, g in parts]),
            "lam": None if parts[0][2].wavelength_nm is None else np.concatenate([g.wavelength_nm for _, _, g in parts])}
    step = max(2, _LANES_PER_LAUNCH // per_point)
    for a in range(0, cols["flux"].size, step):
        part = {k: None if v is None else v[a:a + step] for k, v in cols.items()}
        if part["flux"].size == 1:  # a one-element source would be a constant of the kernel: drawn twice, each half
            part = {k: None if v is None else np.repeat(v, 2, axis=0) for k, v in part.items()}
            part["flux"] = 0.5 * part["flux"]
        _splat_lanes(jt, acc, moments, kernel, h, part, shape, backend)


def _splat_lanes(jt, acc, moments, kernel, h, part, shape, backend):
    """One kernel over the lanes of the points ``part`` (xy, flux, frame, source, lam)."""
    # Dr.Jit only for the JIT backends: import skynav.renderer loads neither Dr.Jit nor Mitsuba
    import drjit as dr

    h_img, w_img = shape
    n_side = 2 * h + 1
    per_point = n_side * n_side
    xy = part["xy"]
    origin = stamp_origin(xy, h)
    lane = dr.arange(jt.UInt32, part["flux"].size * per_point)
    point, cell = lane // per_point, lane % per_point
    row = dr.gather(jt.Int32, jt.Int32(origin[:, 1].astype(np.int32)), point) + jt.Int32(cell // n_side)
    col = dr.gather(jt.Int32, jt.Int32(origin[:, 0].astype(np.int32)), point) + jt.Int32(cell % n_side)
    value = stamp_values(jt, kernel, xy, part["lam"], h, point, cell, col, row, backend)
    e = dr.gather(jt.Float64, jt.Float64(part["flux"]), point) * value
    inside = (row >= 0) & (row < h_img) & (col >= 0) & (col < w_img)
    f = dr.gather(jt.UInt32, jt.UInt32(part["frame"]), point)
    dr.scatter_add(acc, e, f * (h_img * w_img) + jt.UInt32(row) * w_img + jt.UInt32(col), inside)
    # each point's stamp summed over its own lanes, in one order whatever the batch (no atomics)
    sums = dr.block_sum((e, e * jt.Float64(col), e * jt.Float64(row)), per_point, mode="evaluated")
    moments.append((part["source"], sums))


def frame_moments(frames, moments):
    """Each frame's sources' zeroth (S,) and first (S, 2) moments out of :func:`splat_points`'s
    ``moments`` (three numpy arrays, brought from the device), as ``[(m0, m1), ...]``."""
    _, first, _ = _batch_groups(frames)
    m = [np.asarray(v, dtype=float) for v in moments]
    out = []
    for fp, a in zip(frames, first):
        s = slice(a, a + fp.n_sources)
        out.append((m[0][s], np.stack([m[1][s], m[2][s]], axis=1)))
    return out
