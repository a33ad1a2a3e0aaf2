"""The optics half of a render: a scene's noise-free electrons and in-band pupil irradiance per
pixel, through any :class:`~skynav.scenes.projection.Projection` (default: the scene's camera):

1. every point source (stars, unresolved bodies) gets electrons and in-band pupil irradiance from
   :mod:`radiometry`; its pixel path over the exposure is the projection of its apparent
   direction under the attitude kinematics (:func:`source_paths`);
2. the pixel-integrated PSF is integrated along each path (:mod:`raster`);
3. resolved bodies are ray-traced by Mitsuba (:mod:`mitsuba_backend`) in crop windows, with rays
   from the projection's lines of sight, blurred by the same PSF and added;
4. a uniform sky background.

The sensor half is :func:`skynav.renderer.render.detect`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from skynav.infra.errors import ConfigValueError
from skynav.scenes import frames
from skynav.scenes.camera import Camera
from skynav.scenes.projection import Projection
from skynav.scenes.scene import Scene

from .brdf import photocentre_offset_xy
from .mitsuba_backend import render_resolved_body
from .optics import is_polychromatic, kernel_for, star_effective_wavelengths_nm
from .options import RenderOptions
from .radiometry import Radiometry
from .raster import rasterize

__all__ = ["ExpectedImage", "expected_image", "source_paths", "sample_times", "blur_crop", "TracedBody",
           "record_resolved_body"]


@dataclass(frozen=True, kw_only=True, eq=False)
class ExpectedImage:
    """The noise-free image of a scene through a projection, before any detector.

    Attributes
    ----------
    electrons : ndarray, shape (H, W), float64
        Expected photo-electrons per pixel over the exposure (sources + background), e-.
    irradiance_w_m2 : ndarray, shape (H, W), float64, or None
        In-band irradiance at the pupil per pixel from the sources, W/m^2 (None when not asked for).
    exposure_s : float
        Exposure the electrons are integrated over, s.
    star_electrons : ndarray, shape (N,), e-
        Electrons of each star of ``scene.stars`` (whether on the image or not).
    body_electrons : dict of str -> float
        Electrons of each body, e- (a resolved body: its rendered crop's total).
    body_photocentre : dict of str -> ndarray, shape (2,)
        Where each body drawn as a point was drawn (centre + far-field photocentre offset), px.
    resolved : dict of str -> ResolvedBodyImage
        The Mitsuba crops of the ray-traced bodies.
    mitsuba_variant : str or None
        The Mitsuba variant that ray-traced them (None: no body was ray-traced).
    projection : Projection
        The projection the image was made through.
    star_centre_of_light : ndarray, shape (N, 2), or None
        Centre of light of each star's drawn image (first moment of its PSF-blurred, streaked
        stamps), px; NaN for a star not drawn.
    body_centre_of_light : dict of str -> ndarray, shape (2,)
        The same for each drawn body (a resolved one: its blurred crop's first moment).
    support : ndarray of int, or None
        Flat indices (an index may repeat) holding every nonzero pixel of ``electrons`` and
        ``irradiance_w_m2`` as :func:`expected_image` drew them (None: not known; every pixel
        with a background), so that a dark image is converted to float32 without a full pass
        (:func:`~skynav.renderer.sparse_images.float32_image`). A caller who draws more into the images must drop it
        (``dataclasses.replace(expected, support=None)``) before :func:`detect`.
    star_fraction_drawn : ndarray, shape (N,), or None
        The fraction of each star's electrons its stamps hold (a truncated kernel's: every model
        but the Gaussian draws its PSF as it is, the light beyond the stamps not drawn); NaN for
        a star without light; None for the Gaussian, whose stamps hold all but
        ``flux_fraction_lost``.
    body_fraction_drawn : dict of str -> float, or None
        The same for each drawn body (a resolved one: its blurred crop's total over its
        electrons).

    Examples
    --------
    >>> import dataclasses
    >>> from skynav.renderer import RenderOptions, render
    >>> from skynav.scenes import build_from_spec, default_scene_spec
    >>> spec = default_scene_spec()   # the paper camera, pointing at Mars
    >>> camera = spec.camera.replace(width=64, height=64, pixel_pitch_um=spec.camera.pixel_pitch_um * 16)
    >>> scene = build_from_spec(dataclasses.replace(spec, camera=camera))   # 64 px, 20 deg
    >>> from skynav.renderer import expected_image
    >>> ex = expected_image(scene, rng=np.random.default_rng(1))
    >>> ex.electrons.shape, ex.exposure_s, ex.star_electrons.shape == (len(scene.stars.xy),)
    ((64, 64), 0.4, True)
    >>> ex.mitsuba_variant is None   # nothing resolved at 64 px: no ray tracing
    True
    """

    electrons: np.ndarray
    irradiance_w_m2: np.ndarray
    exposure_s: float
    star_electrons: np.ndarray
    body_electrons: dict
    body_photocentre: dict
    resolved: dict
    mitsuba_variant: str | None
    projection: object
    star_centre_of_light: np.ndarray | None = None
    body_centre_of_light: dict | None = None
    support: np.ndarray | None = None
    star_fraction_drawn: np.ndarray | None = None
    body_fraction_drawn: dict | None = None


def sample_times(exposure_s: float, n: int) -> np.ndarray:
    """``n`` instants spread evenly over the exposure, relative to mid-exposure, s."""
    return np.linspace(-0.5 * exposure_s, 0.5 * exposure_s, n)


def _max_sweep_px(scene: Scene, projection, w: np.ndarray) -> float:
    """Upper bound of how far a source moves on the image over the exposure, px.

    A :class:`Camera`: cross-boresight rate x focal length, plus twist rate x the tangent of the
    corner angle (the closed form of a pinhole). Another projection: the largest local scale
    (px/rad) at the image centre and corners, from finite differences of its line of sight, times
    the cross-boresight rate plus the twist rate x the sine of the largest corner angle.
    """
    T = scene.camera.exposure_s
    if isinstance(projection, Camera):
        return T * projection.focal_length_px * (math.hypot(w[0], w[1]) + abs(w[2]) * math.tan(projection.half_diagonal_fov_rad))
    W, H = projection.width, projection.height
    pts = np.array([[(W - 1) / 2, (H - 1) / 2], [-0.5, -0.5], [W - 1.5, -0.5], [-0.5, H - 1.5], [W - 1.5, H - 1.5]])
    los = projection.line_of_sight(pts)
    dx = projection.line_of_sight(pts + [1.0, 0.0])
    dy = projection.line_of_sight(pts + [0.0, 1.0])
    step = np.concatenate([np.linalg.norm(dx - los, axis=-1), np.linalg.norm(dy - los, axis=-1)])
    scale = 1.0 / float(np.min(step))  # px per rad (chord = angle to 1e-8 over one pixel)
    sin_corner = float(np.max(np.linalg.norm(los[:, :2], axis=-1)))
    return T * scale * (math.hypot(w[0], w[1]) + abs(w[2]) * sin_corner)


def path_samples(scene: Scene, projection, n_sources: int, options: RenderOptions) -> int:
    """Instants a path of :func:`source_paths` is sampled at: 0 for a still camera (or no
    source: each path is one point, twice), else one every ``options.path_step_px`` along the
    largest sweep, 2 to 512."""
    w = np.asarray(scene.angular_velocity_rad_s, dtype=float)
    if float(np.linalg.norm(w)) == 0.0 or n_sources == 0:
        return 0
    sweep_px = _max_sweep_px(scene, projection, w)
    return int(min(512, max(2, math.ceil(sweep_px / options.path_step_px) + 1)))


def source_paths(scene: Scene, u_icrs: np.ndarray, options: RenderOptions, projection=None) -> np.ndarray:
    """Pixel paths of apparent directions over the exposure.

    Without rotation every path is two equal points. With a body rate the path is sampled every
    ``options.path_step_px`` along the largest sweep (rotation about the boresight makes arcs).

    Parameters
    ----------
    scene : Scene
    u_icrs : ndarray, shape (N, 3)
        Apparent unit vectors, ICRS.
    options : RenderOptions
    projection : Projection, optional
        Camera-frame direction -> pixel (default ``scene.camera``).

    Returns
    -------
    ndarray, shape (N, S, 2), px
    """
    proj = scene.camera if projection is None else projection
    u = np.atleast_2d(np.asarray(u_icrs, dtype=float))
    w = np.asarray(scene.angular_velocity_rad_s, dtype=float)
    n = path_samples(scene, proj, len(u), options)
    if n == 0:
        xy = proj.project(u @ scene.R_cam_icrs.T)
        return np.stack([xy, xy], axis=1)
    Rs = frames.propagate_attitude(scene.R_cam_icrs, w, sample_times(scene.camera.exposure_s, n))
    v = np.einsum("sij,nj->nsi", Rs, u)
    return proj.project(v)


def _check_projection(scene: Scene, projection, own_size: bool = False):
    if projection is None:
        return scene.camera
    if not isinstance(projection, Projection):
        raise ConfigValueError("projection", type(projection).__name__, "an object with width, height, project() and line_of_sight()")
    cam = scene.camera
    if not own_size and (int(projection.width), int(projection.height)) != (cam.width, cam.height):
        raise ConfigValueError("projection.size", (projection.width, projection.height),
                               f"the camera's image size ({cam.width}, {cam.height})")
    return projection


def _body_track_xy(scene: Scene, projection, body) -> np.ndarray:
    """A body's apparent pixel positions at mid-exposure, start and end; shape (3, 2), px."""
    if projection is scene.camera:  # the scene computed them with this camera
        return np.array([body.xy, body.xy_start, body.xy_end], dtype=float)
    half = 0.5 * scene.camera.exposure_s
    w = np.asarray(scene.angular_velocity_rad_s, dtype=float)
    Rs = np.stack([scene.R_cam_icrs, frames.propagate_attitude(scene.R_cam_icrs, w, -half),
                   frames.propagate_attitude(scene.R_cam_icrs, w, half)])
    return projection.project(np.einsum("sij,j->si", Rs, np.asarray(body.u_icrs, dtype=float)))


def expected_image(scene: Scene, *, projection=None, rng: np.random.Generator, options: RenderOptions = RenderOptions(),
                   own_size: bool = False, with_irradiance: bool = True, support: list | None = None,
                   zeros: tuple | None = None, traced_out: list | None = None) -> ExpectedImage:
    """Noise-free electrons and pupil irradiance of a scene through a projection.

    Parameters
    ----------
    scene : Scene
        Sources, attitude and the camera's optics (aperture, spectral response, exposure, PSF).
    projection : Projection, optional
        Camera-frame line of sight <-> pixel of the image (default ``scene.camera``); its size
        must be the camera's unless ``own_size``. Point sources are placed with ``projection.project``; resolved
        bodies are ray-traced along ``projection.line_of_sight``.
    rng : numpy.random.Generator
        The frame's stream. Only resolved bodies use it, through ``rng.spawn(1)[0]`` (the Mitsuba
        seeds), so ``rng``'s own draws are left for :func:`detect`.
    options : RenderOptions
        Accuracy of the stamps and paths, background, Mitsuba sampling.
    own_size : bool
        True: the image has the projection's size (a bench screen seen through its collimator),
        not the camera's; the camera still sets the optics, radiometry and PSF (in image px).
    with_irradiance : bool
        False: skip the irradiance image (``irradiance_w_m2`` is None), e.g. for a screen frame,
        which needs the electrons only.
    support : list, optional
        Arrays of flat indices are appended to it that hold every nonzero pixel of ``electrons``
        (the point sources' stamps, the resolved bodies' crops; every pixel with a background).
    zeros : (ndarray, ndarray), optional
        Two float64 zero images of the image's shape, C-contiguous, drawn into as the electrons
        and the irradiance (:func:`render` hands back images it has used, set to zero again).
    traced_out : list, optional
        Resolved bodies traced (same ``rng`` draws) but not blurred, drawn nor recorded: appended
        to it as :class:`TracedBody` for the caller (:mod:`~skynav.renderer.bodies_jit`; no irradiance).

    Returns
    -------
    ExpectedImage
        Electrons (e-) and irradiance (W/m^2) per pixel, float64, and each source's share.

    Examples
    --------
    The electrons of the image are those of its sources (nothing leaves the image here but
    the stars beyond the edges):

    >>> import dataclasses
    >>> from skynav.renderer import RenderOptions, render
    >>> from skynav.scenes import build_from_spec, default_scene_spec
    >>> spec = default_scene_spec()   # the paper camera, pointing at Mars
    >>> camera = spec.camera.replace(width=64, height=64, pixel_pitch_um=spec.camera.pixel_pitch_um * 16)
    >>> scene = build_from_spec(dataclasses.replace(spec, camera=camera))   # 64 px, 20 deg
    >>> from skynav.renderer import expected_image
    >>> ex = expected_image(scene, rng=np.random.default_rng(1), options=RenderOptions(backend="numpy"))
    >>> ex.electrons.shape, ex.irradiance_w_m2.shape, ex.electrons.dtype.name
    ((64, 64), (64, 64), 'float64')
    >>> bool(ex.electrons.sum() <= ex.star_electrons.sum() + sum(ex.body_electrons.values()))
    True
    """
    proj = _check_projection(scene, projection, own_size)
    support = [] if support is None else support  # the pixels drawn: ExpectedImage.support (and the caller's list)
    cam = scene.camera
    shape = (int(proj.height), int(proj.width)) if own_size else (cam.height, cam.width)
    rad = Radiometry.for_camera(cam)
    psf = kernel_for(cam, None, options.flux_fraction_lost)
    T = cam.exposure_s

    # --- point sources: stars + bodies not ray-traced
    stars = scene.stars
    star_e = np.asarray(rad.star_electrons_per_s(stars.v_mag, stars.teff_k), dtype=float) * T
    star_irr = np.asarray(rad.star_irradiance_w_m2(stars.v_mag, stars.teff_k), dtype=float)
    track, traced, points = _split_bodies(scene, proj, options)
    body_e = {b.name: float(rad.body_electrons_per_s(b.name, b.v_mag)) * T if np.isfinite(b.v_mag) else 0.0
              for b in scene.bodies}
    body_irr = {b.name: float(rad.body_irradiance_w_m2(b.name, b.v_mag)) if np.isfinite(b.v_mag) else 0.0
                for b in scene.bodies}
    if zeros is not None:
        electrons, irradiance = zeros[0], zeros[1] if with_irradiance else None
    else:
        electrons, irradiance = np.zeros(shape), np.zeros(shape) if with_irradiance else None
    drawn = _draw_point_sources(scene, proj, options, psf, points, track, (star_e, star_irr), (body_e, body_irr),
                                (electrons, irradiance), support)
    star_centre, body_centre, body_photocentre, star_fraction, body_fraction = drawn

    # --- resolved bodies (Mitsuba), blurred by the same PSF; seeds from a child of the frame stream
    resolved, variant = _resolved_bodies(scene, proj, options, psf, traced, track, rng, (body_e, body_irr),
                                         (electrons, irradiance), support, body_centre, body_fraction, traced_out)

    background = options.background_e_per_px_s > 0
    if background:
        electrons += options.background_e_per_px_s * T
        support.append(np.arange(electrons.size))
    sparse = not background and sum(a.size for a in support) * 4 < electrons.size
    return ExpectedImage(electrons=electrons, irradiance_w_m2=irradiance, exposure_s=T, star_electrons=star_e,
                         body_electrons=body_e, body_photocentre=body_photocentre, resolved=resolved,
                         mitsuba_variant=variant, projection=proj, star_centre_of_light=star_centre,
                         body_centre_of_light=body_centre, star_fraction_drawn=star_fraction,
                         body_fraction_drawn=body_fraction,
                         support=(np.concatenate(support) if support else np.zeros(0, np.int64)) if sparse else None)


def _split_bodies(scene: Scene, proj, options: RenderOptions):
    """Each body's track ({name: (3, 2)}, px: mid-exposure, start, end), the bodies to ray-trace
    (resolved, near the image) and those to draw as points (the others near the image, at a
    finite position)."""
    track = {b.name: _body_track_xy(scene, proj, b) for b in scene.bodies}
    near = {b.name: _near_image(proj, track[b.name], b) for b in scene.bodies}
    traced = [b for b in scene.bodies if b.resolved and options.resolved and near[b.name]]
    points = [b for b in scene.bodies if b not in traced and near[b.name] and all(map(math.isfinite, track[b.name][0].tolist()))]
    return track, traced, points


def _to_photocentres(scene: Scene, proj, bodies, track: dict, paths: np.ndarray) -> dict:
    """Move the paths ``paths`` (B, S, 2), px, of ``bodies`` drawn as points to their
    photocentres, in place; returns {name: photocentre drawn at (2,), px}.

    An unresolved body is drawn at its photocentre (the far-field BRDF's offset along the Sun's
    projection), so its centroid is continuous across the resolved threshold; a body without a
    finite offset stays at its centre."""
    body_photocentre = {}
    for j, b in enumerate(bodies):
        off = np.asarray(photocentre_offset_xy(proj, scene.R_cam_icrs, b), dtype=float)
        if np.all(np.isfinite(off)):
            paths[j] += off
            body_photocentre[b.name] = track[b.name][0] + off
    return body_photocentre


def _draw_point_sources(scene, proj, options, psf, points, track, star_light, body_light, images, support):
    """Stars and the bodies drawn as points (``points``), rasterised into ``images`` =
    (electrons, irradiance or None) along their paths, each body at its photocentre; returns
    (star centres of light (N, 2), {body: centre of light}, {body: photocentre drawn at}, star
    fractions drawn (N,) or None, {body: fraction drawn} or None)."""
    cam = scene.camera
    ffl = options.flux_fraction_lost
    stars = scene.stars
    (star_e, star_irr), (body_e, body_irr), (electrons, irradiance) = star_light, body_light, images
    u_pts = np.concatenate([stars.u_icrs.reshape(-1, 3), np.array([b.u_icrs for b in points]).reshape(-1, 3)])
    e_pts = np.concatenate([star_e, np.array([body_e[b.name] for b in points])])
    irr_pts = np.concatenate([star_irr, np.array([body_irr[b.name] for b in points])])
    paths = source_paths(scene, u_pts, options, proj)
    body_photocentre = _to_photocentres(scene, proj, points, track, paths[len(star_e):])
    centre = np.full((len(e_pts), 2), np.nan)
    drawn = np.zeros(len(e_pts)) if psf.truncated else None  # the charge each source's stamps hold
    shape = electrons.shape
    with_irradiance = irradiance is not None
    if not is_polychromatic(cam):
        rasterize(shape, paths, e_pts, psf, flux_fraction_lost=ffl, support=support, centre_of_light=centre, out=electrons,
                  also=(irr_pts, irradiance) if with_irradiance else None, stamp_e=e_pts, drawn_e=drawn)
    else:  # stars: the spectral nodes blended at each star's effective wavelength; bodies: their own spectrum
        n_s = len(star_e)
        lam = star_effective_wavelengths_nm(cam, stars.teff_k)
        rasterize(shape, paths[:n_s], e_pts[:n_s], psf, flux_fraction_lost=ffl, support=support, out=electrons,
                  centre_of_light=centre[:n_s], wavelength_nm=lam, stamp_e=e_pts[:n_s], drawn_e=drawn[:n_s],
                  also=(irr_pts[:n_s], irradiance) if with_irradiance else None)
        for j, b in enumerate(points):
            kern = kernel_for(cam, ("body", b.name), ffl)
            sel = slice(n_s + j, n_s + j + 1)
            rasterize(shape, paths[sel], e_pts[sel], kern, flux_fraction_lost=ffl, support=support,
                      centre_of_light=centre[sel], out=electrons, stamp_e=e_pts[sel], drawn_e=drawn[sel],
                      also=(irr_pts[sel], irradiance) if with_irradiance else None)
    star_centre = centre[: len(star_e)]
    body_centre = {b.name: centre[len(star_e) + j] for j, b in enumerate(points)}
    star_fraction = body_fraction = None
    if drawn is not None:  # a truncated kernel: what its stamps hold of each source's light
        with np.errstate(invalid="ignore", divide="ignore"):
            fraction = np.where(e_pts > 0, drawn / e_pts, np.nan)
        star_fraction = fraction[: len(star_e)]
        body_fraction = {b.name: float(fraction[len(star_e) + j]) for j, b in enumerate(points)}
    return star_centre, body_centre, body_photocentre, star_fraction, body_fraction


@dataclass(frozen=True, kw_only=True, eq=False)
class TracedBody:
    """A ray-traced body of a frame before its blur: what :func:`expected_image` hands a caller
    who draws the bodies itself (its ``traced_out``).

    Attributes
    ----------
    name : str
    image : ResolvedBodyImage
        Mitsuba's crop (electrons, e-) and where it lies.
    kernel : Kernel
        The PSF the crop is blurred with (a polychromatic camera's: the body's own).
    at_xy : ndarray, shape (2,), px
        The body's pixel at mid-exposure (the field point of a varying PSF).
    """

    name: str
    image: object
    kernel: object
    at_xy: np.ndarray


def _trace_resolved_bodies(scene, proj, options, psf, traced, track, rng):
    """The ray-traced bodies (``traced``) as :class:`TracedBody`: Mitsuba's crops, seeded from a
    child of the frame's stream (one ``rng.spawn`` when any body is traced), and their kernels."""
    if not traced:
        return []
    cam = scene.camera
    poly = is_polychromatic(cam)
    body_rng = rng.spawn(1)[0]
    out = []
    for b in traced:
        img = render_resolved_body(scene, b, spp=options.mitsuba_spp, time_samples=options.mitsuba_time_samples,
                                   rng=body_rng, projection=proj)
        kern = kernel_for(cam, ("body", b.name), options.flux_fraction_lost) if poly else psf
        out.append(TracedBody(name=b.name, image=img, kernel=kern, at_xy=track[b.name][0]))
    return out


def _resolved_bodies(scene, proj, options, psf, traced, track, rng, body_light, images, support, body_centre,
                     body_fraction, traced_out):
    """The ray-traced bodies (``traced``) traced, then drawn into ``images`` with their truth
    (:func:`_draw_resolved_bodies`), or handed to the caller in ``traced_out`` (a list; the
    irradiance not asked for); returns ({body: ResolvedBodyImage}, Mitsuba variant or None)."""
    if traced_out is not None and images[1] is not None:
        raise ConfigValueError("traced_out", "with the irradiance", "with_irradiance=False (the caller draws the bodies)")
    bodies = _trace_resolved_bodies(scene, proj, options, psf, traced, track, rng)
    if traced_out is None:
        _draw_resolved_bodies(bodies, options, body_light, images, support, body_centre, body_fraction)
    else:  # the caller blurs and draws them, and records their truth (record_resolved_body)
        traced_out.extend(bodies)
    return {t.name: t.image for t in bodies}, (bodies[-1].image.variant if bodies else None)


def _draw_resolved_bodies(bodies, options, body_light, images, support, body_centre, body_fraction):
    """The traced ``bodies`` blurred by their PSF and added to ``images`` = (electrons,
    irradiance or None); fills ``body_centre``, ``body_fraction`` (if not None) and the body
    electrons (``body_light[0]``: :func:`record_resolved_body`)."""
    (body_e, body_irr), (electrons, irradiance) = body_light, images
    for t in bodies:
        img = t.image
        crop, pad = blur_crop(img.electrons, t.kernel, options.flux_fraction_lost, at_xy=t.at_xy)
        _add_crop(electrons, crop, img.x0 - pad, img.y0 - pad, support=support)
        yy, xx = np.indices(crop.shape)
        scale = body_irr[t.name] / body_e[t.name] if body_e[t.name] > 0 else 0.0
        if irradiance is not None:
            _add_crop(irradiance, crop * scale, img.x0 - pad, img.y0 - pad)
        moments = (float(crop.sum()), (crop * xx).sum(), (crop * yy).sum())
        record_resolved_body(t, moments, pad, body_e, body_centre, body_fraction)


def record_resolved_body(body: TracedBody, moments, pad: int, body_e: dict, body_centre: dict,
                         body_fraction: dict | None) -> None:
    """A ray-traced body's truth from its blurred crop's moments ``(total, sum x, sum y)`` (e-,
    e- px, with x, y the column and row within the blurred crop, padded by ``pad`` px): its
    centre of light into ``body_centre``, its electrons (the ray-traced crop's total) into
    ``body_e``, and the fraction the blurred crop holds of them into ``body_fraction`` (if not
    None)."""
    tot, m1x, m1y = moments
    img = body.image
    if tot > 0:
        body_centre[body.name] = np.array([m1x / tot + img.x0 - pad, m1y / tot + img.y0 - pad])
    body_e[body.name] = float(img.electrons_total)
    if body_fraction is not None and body_e[body.name] > 0:
        body_fraction[body.name] = tot / body_e[body.name]


def blur_crop(crop: np.ndarray, psf, flux_fraction_lost: float, at_xy=None, wavelength_nm=None):
    """Convolve a pixel-binned crop with the PSF kernel, padded so that no drawn light is cut:
    :meth:`blur_crop` of the kernel (the Gaussian's separable erf kernel, normalised to 1; a
    table kernel's stamp of a point at a pixel centre, as it is, by FFT). ``at_xy`` (px) picks
    the pixel, for a PSF that varies across the field (default: (0, 0)); ``wavelength_nm`` the
    body's effective wavelength, for a polychromatic PSF. Returns (blurred crop, pad in px).
    """
    return psf.blur_crop(crop, flux_fraction_lost, at_xy=at_xy, wavelength_nm=wavelength_nm)


def _near_image(projection, track_xy: np.ndarray, body, margin_px: float = 50.0) -> bool:
    """True if any of a body's positions (mid-exposure, start, end; (3, 2) px) is within
    ``margin_px`` plus its apparent radius of the image (Python floats: three points, nine
    bodies a frame, too few for numpy's per-call cost to pay)."""
    margin = margin_px + 0.5 * body.angular_diameter_px
    x_hi, y_hi = projection.width - 0.5 + margin, projection.height - 0.5 + margin
    lo = -0.5 - margin
    for x, y in np.asarray(track_xy, dtype=float).tolist():
        if math.isfinite(x) and math.isfinite(y) and lo <= x < x_hi and lo <= y < y_hi:
            return True
    return False


def _add_crop(image: np.ndarray, crop: np.ndarray, x0: int, y0: int, support: list | None = None) -> None:
    """Add a crop whose top-left pixel is (row y0, col x0), clipped to the image (``support``: the
    flat indices of the pixels covered are appended to it)."""
    h, w = crop.shape
    H, W = image.shape
    ys, xs = max(0, y0), max(0, x0)
    ye, xe = min(H, y0 + h), min(W, x0 + w)
    if ye <= ys or xe <= xs:
        return
    image[ys:ye, xs:xe] += crop[ys - y0:ye - y0, xs - x0:xe - x0]
    if support is not None:
        support.append((np.arange(ys, ye)[:, None] * W + np.arange(xs, xe)[None, :]).ravel())
