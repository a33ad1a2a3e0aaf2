"""The bench display model (hardware-in-the-loop mode): a scene rendered straight into screen
pixels, mapped to the screen digital counts that make the real camera collect the electrons the
rendered source would give it.

- Geometry at the line-of-sight level: :func:`~skynav.renderer.expected.expected_image` draws
  through the facility's :class:`~skynav.scenes.screen.ScreenProjection` (``own_size``), so
  every point source (and its streak) lands at the screen position whose calibrated line of
  sight is its apparent direction, and resolved bodies are ray-traced by Mitsuba along the
  screen pixels' lines of sight. Nothing is resampled from a camera image.
- The camera's own defocus and noise are left to the real camera: the screen image uses a small
  screen-space PSF (``screen_psf_sigma_px``, default 0.5 screen px) only to encode sub-pixel
  positions.
- Radiometry: intended camera electrons per screen pixel -> electrons/s -> power-meter W/m^2
  (``Facility.electrons_per_s_per_w_m2``: screen spectrum, meter responsivity, camera QE) ->
  divided by the flat field at that pixel -> inverse radiometric curve (above the black level,
  which the camera sees as a uniform pedestal) -> rounded digital counts, clipped to the screen.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
from scipy import ndimage, signal

from .render import RenderOptions, expected_image


@dataclass(frozen=True)
class ScreenFrame:
    """A screen frame: ``dn`` (H, W) uint8/uint16 at the screen's bit depth, and what went in.

    Made by :func:`screen_frame`.

    Attributes
    ----------
    dn : ndarray, shape (H, W), uint8 or uint16
        Screen digital counts (screen px), DN.
    electrons : ndarray, shape (H, W)
        Intended camera electrons per screen pixel over the exposure, e-.
    stars_xy : ndarray, shape (N, 2)
        Screen positions of the stars at mid-exposure, screen px.
    stars_electrons : ndarray, shape (N,)
        Intended camera electrons of each star, e-.
    stars_peak_dn : ndarray, shape (N,)
        Largest screen DN of each star.
    bodies : list of dict
        ``name``, ``xy`` (screen px), ``electrons`` (e-), ``peak_dn``.
    clipped_bright_px : int
        Screen pixels asked brighter than the screen's full scale.
    clipped_faint_sources : int
        Sources too faint for one screen DN.
    black_pedestal_e_per_camera_px : float
        Electrons per camera pixel of the screen's black level (a uniform pedestal), e-.

    Examples
    --------
    >>> import dataclasses
    >>> from skynav.renderer import RenderOptions, screen_frame
    >>> from skynav.scenes import build_from_spec, default_scene_spec, screen_small_preset
    >>> bench = screen_small_preset()
    >>> scene = build_from_spec(dataclasses.replace(default_scene_spec(), camera=bench.camera))
    >>> sf = screen_frame(scene, bench, rng=np.random.default_rng(1), options=RenderOptions(backend="numpy"))
    >>> mars = sf.bodies[0]
    >>> mars["name"], [round(c, 1) for c in mars["xy"]]   # the screen's centre, screen px
    ('mars', [319.5, 319.5])
    >>> int(sf.dn.max()) <= bench.screen.max_dn, len(sf.stars_xy) == len(sf.stars_electrons)
    (True, True)
    """

    dn: np.ndarray
    electrons: np.ndarray          # intended camera electrons per screen pixel
    stars_xy: np.ndarray           # (N, 2) screen xy of the stars (mid-exposure)
    stars_electrons: np.ndarray    # (N,)
    stars_peak_dn: np.ndarray      # (N,)
    bodies: list                   # dicts: name, xy, electrons, peak_dn
    clipped_bright_px: int
    clipped_faint_sources: int
    black_pedestal_e_per_camera_px: float


def dn_of_electrons(facility, electrons, xy_grid=None):
    """Real-valued screen DN giving ``electrons`` (per screen pixel over the exposure) in the camera.

    Parameters
    ----------
    facility : skynav.scenes.facility.Facility
        The bench: camera exposure, spectra, radiometric curve, flat field.
    electrons : array_like, shape (...)
        Intended camera electrons per screen pixel over the exposure, e-.
    xy_grid : array_like, shape (..., 2), optional
        Screen pixels of the values, for the flat field (None: flat).

    Returns
    -------
    dn : numpy.ndarray, shape (...)
        Real-valued screen DN (the inverse radiometric curve above the black level).
    bright : numpy.ndarray of bool, shape (...)
        True where the screen's full scale is not enough.

    Examples
    --------
    >>> from skynav.renderer import dn_of_electrons
    >>> from skynav.scenes import screen_small_preset
    >>> dn, bright = dn_of_electrons(screen_small_preset(), np.array([0.0, 100.0, 1e5]))
    >>> dn.round(2).tolist(), bright.tolist()
    ([0.0, 12.06, 278.66], [False, False, False])
    """
    cam = facility.camera
    rate = np.asarray(electrons, dtype=float) / cam.exposure_s
    w = rate / facility.electrons_per_s_per_w_m2()
    if xy_grid is not None:
        w = w / facility.flat(xy_grid)
    rm = facility.radiometric
    return rm.digital_count(rm.black_w_m2 + np.maximum(w, 0.0)), w > (rm.peak_w_m2 - rm.black_w_m2)


def _full_scale_e(facility) -> float:
    """Camera electrons (per screen pixel over the exposure) of a screen pixel at full scale, flat field 1."""
    rm = facility.radiometric
    return (rm.peak_w_m2 - rm.black_w_m2) * facility.electrons_per_s_per_w_m2() * facility.camera.exposure_s


def _diffuse_excess(win, lim, max_iterations):
    """Iterative fallback: the excess over ``lim`` convolved with a normalised symmetric 3 x 3 kernel
    and added back until no pixel exceeds its limit (keeps the total and the first moment)."""
    k = np.array([[1.0, 2.0, 1.0], [2.0, 4.0, 2.0], [1.0, 2.0, 1.0]]) / 16.0
    for _ in range(max_iterations):
        ex = np.maximum(win - lim, 0.0)
        if ex.sum() <= 1e-9 * max(win.sum(), 1.0):
            break
        win = win - ex + ndimage.convolve(ex, k, mode="constant")
    return win


def _gaussian_kernel_1d(sigma_px: float) -> np.ndarray:
    r = int(np.ceil(4.0 * sigma_px))
    g = np.exp(-0.5 * (np.arange(-r, r + 1) / sigma_px) ** 2)
    return g / g.sum()


def _blur(a, sigma_px: float):
    """``a`` convolved with a normalised, sampled 2-D Gaussian (zero outside ``a``)."""
    if sigma_px <= 0.0:
        return a
    g = _gaussian_kernel_1d(sigma_px)
    b = ndimage.convolve1d(a, g, axis=0, mode="constant")
    return ndimage.convolve1d(b, g, axis=1, mode="constant")


def _disc_kernel(radius_px: float) -> np.ndarray:
    """A normalised disc (pillbox) of ``radius_px``, its edge pixels weighted by the part of the
    pixel inside (``clip(radius - r + 1/2, 0, 1)``, r the distance of the pixel's centre): a
    function of the distance alone, so symmetric, and continuous in the radius."""
    n = int(np.ceil(radius_px + 0.5))
    yy, xx = np.mgrid[-n:n + 1, -n:n + 1]
    k = np.clip(radius_px - np.hypot(xx, yy) + 0.5, 0.0, 1.0)
    return k / k.sum()


def _spread_disc(a, radius_px: float):
    """``a`` convolved with :func:`_disc_kernel` (zero outside ``a``)."""
    if radius_px <= 0.0:
        return a
    return signal.fftconvolve(a, _disc_kernel(radius_px), mode="same")


def _over_groups(over_idx, shape, pad: int, block: int = 8):
    """Groups of the pixels ``over_idx`` (flat indices into an image of ``shape``) that lie within
    4 px (4-connected steps) of each other, as ``(r0, r1, c0, c1, labels, n)``: a window padded by
    ``pad`` and the group's label ``n`` in ``labels`` (the window's labels), in the order of the
    groups' boxes. Only the few ``block`` x ``block`` blocks that hold such pixels are labelled at
    full resolution: two pixels within 4 px lie in the same or in adjacent blocks, so every group
    lies in one connected group of blocks."""
    H, W = shape
    rows, cols = np.divmod(np.asarray(over_idx), W)
    coarse = np.zeros((-(-H // block), -(-W // block)), bool)
    coarse[rows // block, cols // block] = True
    clab, _ = ndimage.label(coarse, structure=np.ones((3, 3), bool))
    groups = []
    for m, sl in enumerate(ndimage.find_objects(clab), start=1):
        mine = clab[rows // block, cols // block] == m
        R0, R1 = max(sl[0].start * block - pad, 0), min(sl[0].stop * block + pad, H)
        C0, C1 = max(sl[1].start * block - pad, 0), min(sl[1].stop * block + pad, W)
        sub = np.zeros((R1 - R0, C1 - C0), bool)
        sub[rows[mine] - R0, cols[mine] - C0] = True
        lab, _ = ndimage.label(ndimage.binary_dilation(sub, iterations=2))
        for n, fsl in enumerate(ndimage.find_objects(lab), start=1):
            a0, a1 = max(R0 + fsl[0].start - pad, 0), min(R0 + fsl[0].stop + pad, H)
            b0, b1 = max(C0 + fsl[1].start - pad, 0), min(C0 + fsl[1].stop + pad, W)
            full = np.zeros((a1 - a0, b1 - b0), int)
            # the group's labels in its own window (the window may reach beyond the block group's)
            i0, i1 = max(a0, R0), min(a1, R1)
            j0, j1 = max(b0, C0), min(b1, C1)
            full[i0 - a0:i1 - a0, j0 - b0:j1 - b0] = lab[i0 - R0:i1 - R0, j0 - C0:j1 - C0]
            groups.append((R0 + fsl[0].start, C0 + fsl[1].start, (a0, a1, b0, b1, full, n)))
    groups.sort(key=lambda g: (g[0], g[1]))
    return [g[2] for g in groups]


def spread_over_full_scale(electrons, facility, *, core_dilation_px: int = 4, edge_sigma_px: float = 4.0,
                           max_width_px: float = 40.0, max_iterations: int = 3000):
    """Draw a source that a screen pixel cannot show (above its full scale) wider, around the same centre.

    Each connected group of pixels over the limit, with everything within ``core_dilation_px`` of
    it (the source's whole light: the screen PSF of 0.5 px falls by e^-32 over 4 px), is convolved
    with the narrowest kernel of a one-parameter family that brings every pixel it reaches to its
    limit (full scale times the flat field there; bisection on the width w, to 0.1 %): a
    normalised, sampled Gaussian of sigma w up to ``edge_sigma_px``, beyond that this Gaussian and
    a normalised disc of radius ``w - edge_sigma_px`` (a flat top at full scale with Gaussian
    edges: the camera saturates far below the screen's full scale, so wider Gaussian wings would
    saturate it over a much larger area, beyond its measurement window).

    Every kernel of the family is normalised and a function of the distance alone, so it keeps
    the source's electrons and its first moment exactly and, applied to a source symmetric about
    its sub-pixel position, keeps it symmetric about that position: the spot only grows wider,
    as if defocused. The camera, saturated there anyway, locates it by its unsaturated wings.
    (Plain clipping cuts the core unevenly across the pixels and shifts it; spreading the excess
    charge pixel by pixel to the neighbours keeps the centroid but leaves a plateau whose shape
    follows the pixel grid, not the source, which put the fitted centre of Jupiter 7 arcsec off on
    the bench preset.) A group that would need a wider kernel than ``max_width_px`` (a resolved
    disc far brighter than full scale over its area) falls back to that pixel-by-pixel spreading:
    the excess convolved, again and again, with a normalised symmetric 3 x 3 kernel and added
    back, which also keeps the total and the first moment.

    Parameters
    ----------
    electrons : ndarray, shape (H, W), e-
        Intended camera electrons per screen pixel.
    facility : Facility
        Gives the full scale (radiometric curve, exposure) and the flat field.
    core_dilation_px : int
        Pixels around a group over the limit that are spread with it.
    edge_sigma_px, max_width_px : float
        Widest Gaussian, and widest kernel (Gaussian sigma + disc radius), screen px.

    Returns
    -------
    (ndarray, shape (H, W), e-; int)
        The electrons (``electrons`` itself where nothing is over the limit), and the number of
        pixels that were over the limit.
    """
    out = np.array(electrons, dtype=float)
    n_over, undo = _spread_in_place(out, facility, np.flatnonzero(out), core_dilation_px=core_dilation_px,
                                    edge_sigma_px=edge_sigma_px, max_width_px=max_width_px, max_iterations=max_iterations)
    return (out, n_over) if undo else (electrons, 0)


def _spread_in_place(out, facility, lit_idx, *, core_dilation_px: int = 4, edge_sigma_px: float = 4.0,
                     max_width_px: float = 40.0, max_iterations: int = 3000):
    """:func:`spread_over_full_scale` on ``out`` (float64, modified in place) whose nonzero pixels
    are among the flat indices ``lit_idx``. Returns ``(pixels over the limit, undo)``: the
    windows changed, ``[(r0, r1, c0, c1, original), ...]`` in the order written."""
    e_full = _full_scale_e(facility)
    # candidates against the flat field's lowest grid value (a spline may dip a little below it)
    f_min = 0.9 * min(min(r) for r in facility.flat_field.relative) if facility.flat_field is not None else 1.0
    over_idx = lit_idx[out.ravel()[lit_idx] > e_full * f_min]
    undo = []
    if not len(over_idx):
        return 0, undo
    n_over = 0
    edge = float(edge_sigma_px)

    def spread(a, w):
        # w <= edge: a Gaussian of sigma w; beyond, that Gaussian of sigma edge and a disc of radius w - edge
        return _spread_disc(_blur(a, min(w, edge)), w - edge) if w > edge else _blur(a, w)

    def reach(w):
        return int(np.ceil(4.0 * min(w, edge))) + int(np.ceil(max(w - edge, 0.0))) + 2

    pad = core_dilation_px + reach(max_width_px) + 2
    disc = np.hypot(*np.mgrid[-core_dilation_px:core_dilation_px + 1, -core_dilation_px:core_dilation_px + 1]) <= core_dilation_px
    for r0, r1, c0, c1, lab, n in _over_groups(over_idx, out.shape, pad):
        yy, xx = np.mgrid[r0:r1, c0:c1].astype(float)
        lim = e_full * facility.flat(np.stack([xx, yy], -1))
        win = out[r0:r1, c0:c1]
        hot = (win > lim) & (lab == n)
        if not hot.any():
            continue
        n_over += int(hot.sum())
        core = ndimage.binary_dilation(hot, structure=disc)
        src = np.where(core, win, 0.0)
        rest = win - src
        rr, cc = np.nonzero(core)

        def fits(w):
            # every pixel the spread core reaches (its box + the kernel's reach) within its limit
            r = reach(w)
            box = (slice(max(rr.min() - r, 0), rr.max() + r + 1), slice(max(cc.min() - r, 0), cc.max() + r + 1))
            return bool(np.all(rest[box] + spread(src[box], w) <= lim[box]))

        if fits(max_width_px):
            lo, hi = 0.0, max_width_px
            while hi - lo > 1e-3 * hi:
                mid = 0.5 * (lo + hi)
                lo, hi = (lo, mid) if fits(mid) else (mid, hi)
            new = rest + spread(src, hi)
        else:
            new = _diffuse_excess(win, lim, max_iterations)
        undo.append((r0, r1, c0, c1, win.copy()))
        out[r0:r1, c0:c1] = new
    return n_over, undo


def screen_frame(scene, facility, *, rng: np.random.Generator, options=None, screen_psf_sigma_px: float = 0.5) -> ScreenFrame:
    """Render ``scene`` for the bench ``facility``'s screen (see the module docstring).

    Parameters
    ----------
    scene : skynav.scenes.scene.Scene
        The scene, seen by the facility's camera.
    facility : skynav.scenes.facility.Facility
        The bench: screen, collimator geometry, radiometry.
    rng : numpy.random.Generator
        The frame's stream (the Mitsuba seeds of resolved bodies).
    options : RenderOptions, optional
        Accuracy and ray-tracing options (the background is left to the real sky: 0).
    screen_psf_sigma_px : float
        Gaussian PSF in screen pixels that encodes sub-pixel positions, screen px.

    Returns
    -------
    ScreenFrame
        The screen's DN and what went in.

    References
    ----------
    Andreis et al. (2023b), Sec. 3 (the RETINA bench).

    Examples
    --------
    >>> import dataclasses
    >>> from skynav.renderer import RenderOptions, screen_frame
    >>> from skynav.scenes import build_from_spec, default_scene_spec, screen_small_preset
    >>> bench = screen_small_preset()
    >>> scene = build_from_spec(dataclasses.replace(default_scene_spec(), camera=bench.camera))
    >>> sf = screen_frame(scene, bench, rng=np.random.default_rng(1), options=RenderOptions(backend="numpy"))
    >>> sf.dn.shape, sf.dn.dtype.name, [b["name"] for b in sf.bodies]
    ((640, 640), 'uint16', ['mars'])
    """
    options = options or RenderOptions()
    cam = scene.camera.replace(defocus_sigma_px=screen_psf_sigma_px)
    sc_scene = dataclasses.replace(scene, camera=cam)
    proj = facility.projection
    support = []  # flat indices holding every lit pixel: no scan of the mostly dark screen
    exp = expected_image(sc_scene, projection=proj, rng=rng, options=dataclasses.replace(options, background_e_per_px_s=0.0),
                         own_size=True, with_irradiance=False, support=support)
    H, W = proj.height, proj.width
    # only lit pixels need the curve: the dark sky stays at DN 0 (the black level). A source beyond
    # the screen's full scale is drawn wider about its centre (total and centroid kept), in place
    # in a few windows of the electrons, which are put back afterwards (the frame keeps the
    # intended electrons)
    electrons = exp.electrons
    lit = np.unique(np.concatenate(support)) if support else np.zeros(0, int)
    lit = lit[electrons.ravel()[lit] != 0]
    n_over, undo = _spread_in_place(electrons, facility, lit)
    if undo:
        inside = np.zeros(len(lit), bool)
        parts = []
        for r0, r1, c0, c1, _ in undo:
            r, c = np.divmod(lit, W)
            inside |= (r >= r0) & (r < r1) & (c >= c0) & (c < c1)
            wr, wc = np.nonzero(electrons[r0:r1, c0:c1])
            parts.append((wr + r0) * W + wc + c0)
        lit = np.union1d(lit[~inside], np.concatenate(parts))
    lit = lit[electrons.ravel()[lit] > 0]
    rows, cols = np.divmod(lit, W)
    dn_real, bright = dn_of_electrons(facility, electrons[rows, cols], np.stack([cols, rows], -1).astype(float))
    maxdn = facility.screen.max_dn
    dn = np.zeros((H, W), dtype=np.uint8 if facility.screen.bit_depth <= 8 else np.uint16)
    dn[rows, cols] = np.clip(np.round(dn_real), 0, maxdn)
    for r0, r1, c0, c1, original in reversed(undo):
        electrons[r0:r1, c0:c1] = original
    v = np.einsum("ij,nj->ni", scene.R_cam_icrs, np.asarray(scene.stars.u_icrs, dtype=float).reshape(-1, 3))
    sxy = proj.project(v)

    def peaks(xy):
        """Brightest DN within a pixel of each screen position (0 where not finite)."""
        xy = np.asarray(xy, dtype=float).reshape(-1, 2)
        fin = np.all(np.isfinite(xy), axis=1)
        c = np.where(fin[:, None], xy, 0.0)
        i = np.clip(np.round(c[:, 1]), 0, H - 1).astype(int)[:, None] + np.array([-1, -1, -1, 0, 0, 0, 1, 1, 1])
        j = np.clip(np.round(c[:, 0]), 0, W - 1).astype(int)[:, None] + np.array([-1, 0, 1, -1, 0, 1, -1, 0, 1])
        p = dn[np.clip(i, 0, H - 1), np.clip(j, 0, W - 1)].max(axis=1) if len(xy) else np.zeros(0, int)
        return np.where(fin, p, 0).astype(int)

    peak = lambda xy: int(peaks(xy)[0])  # noqa: E731
    star_peak = peaks(sxy)
    bodies = []
    for b in scene.bodies:
        bxy = proj.project(scene.R_cam_icrs @ np.asarray(b.u_icrs, dtype=float))
        if proj.in_screen(bxy):
            bodies.append({"name": b.name, "xy": [float(bxy[0]), float(bxy[1])], "electrons": float(exp.body_electrons.get(b.name, 0.0)),
                           "peak_dn": peak(bxy), "resolved": b.name in exp.resolved})
    on = proj.in_screen(sxy) if len(sxy) else np.zeros(0, bool)
    faint = int(((star_peak == 0) & on & (exp.star_electrons > 0)).sum())
    rm = facility.radiometric
    scale = facility.geometric.focal_length_mm / (facility.screen.pixel_pitch_um * 1e-3) / scene.camera.focal_length_px
    pedestal = rm.black_w_m2 * facility.electrons_per_s_per_w_m2() * scene.camera.exposure_s * scale ** 2
    return ScreenFrame(dn=dn, electrons=exp.electrons, stars_xy=sxy, stars_electrons=np.asarray(exp.star_electrons, dtype=float),
                       stars_peak_dn=star_peak, bodies=bodies, clipped_bright_px=int(bright.sum()) + n_over, clipped_faint_sources=faint,
                       black_pedestal_e_per_camera_px=float(pedestal))
