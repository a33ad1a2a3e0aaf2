"""PSF models in the renderer: flux, measured tables, field grids, streaks, the truth's centre of light."""

import numpy as np
import pytest

from skynav.renderer.optics import airy_intensity, kernel_for
from skynav.renderer.raster import rasterize
from skynav.scenes.camera import Camera

PITCH_UM, F_NUMBER, WL_NM = 5.0, 20.0, 550.0
LF_PX = WL_NM * 1e-3 * F_NUMBER / PITCH_UM
COMA = {4: 0.3, 7: 0.2, 8: -0.1}


def _camera(psf, size=64):
    return Camera(width=size, height=size, focal_length_mm=100.0, pixel_pitch_um=PITCH_UM, f_number=F_NUMBER, psf=psf)


def _airy_image(path, oversampling, half_px=12, shift=(0.0, 0.0)):
    """An Airy image sampled every 1/oversampling px, centred on its middle sample (+ shift px)."""
    n = 2 * half_px * oversampling + 1
    u = (np.arange(n) - n // 2) / oversampling
    img = airy_intensity(np.hypot(u[None, :] - shift[0], u[:, None] - shift[1]), LF_PX, 0.0)
    if str(path).endswith(".npy"):
        np.save(path, img)
    else:
        from astropy.io import fits

        fits.PrimaryHDU(img).writeto(path)
    return str(path)


def _read_fits(path):
    from astropy.io import fits

    with fits.open(path) as hdul:
        return np.asarray(hdul[0].data, dtype=float)


MODELS = {
    "gaussian": {"model": "gaussian", "sigma_px": 0.7},
    "airy": {"model": "airy", "obscuration": 0.3, "wavelength_nm": WL_NM},
    "airy-poly": {"model": "airy", "obscuration": 0.1},
    "optical": {"model": "optical", "obscuration": 0.2, "wavelength_nm": WL_NM, "zernike_waves": COMA},
}


@pytest.mark.parametrize("name", list(MODELS) + ["tabulated", "field"])
def test_flux_is_conserved_for_points_and_streaks(name, tmp_path):
    """Every model, static points and 25 px streaks (straight and curved) wholly on the image: the
    image holds what the stamps hold (``drawn_e``, to 1e-12), the sources' electrons times the
    fraction of the PSF's light inside the stamps: all but 2e-6 for the Gaussian (its stamps are
    sized for 1e-6 per point), and for a table kernel the same fraction for a point and a streak
    to 1e-2 (the stamp's edge moves through the wing with the sub-pixel phase: 5e-3 for the
    coma): 0.97 for the Airy here (lambda F = 2.2 px, 33 x 33 px), 0.89 for the coma (the fraction
    itself is checked against GalSim in ``test_psf_models_against_galsim.py``)."""
    if name == "tabulated":
        psf = {"model": "tabulated", "file": _airy_image(tmp_path / "a.npy", 4), "oversampling": 4}
    elif name == "field":
        pts = [{"x_px": x, "y_px": y, "file": _airy_image(tmp_path / f"a{x}_{y}.npy", 4, shift=(0.01 * x, 0.0))}
               for x in (0.0, 100.0) for y in (0.0, 100.0)]
        psf = {"model": "tabulated", "field": pts, "oversampling": 4}
    else:
        psf = MODELS[name]
    cam = _camera(psf, size=128)
    k = kernel_for(cam, None, 1e-6)
    lam = {"wavelength_nm": [600.0, 700.0]} if name == "airy-poly" else {}  # between nodes: two tables blended
    t = np.linspace(0.0, 1.0, 9)
    paths = np.array([[[40.3, 50.7], [40.3, 50.7]],      # static
                      [[30.2, 30.9], [55.2, 34.0]]])     # straight 25 px streak
    curved = np.column_stack([70.0 + 20.0 * t, 80.0 + 8.0 * np.sin(3.0 * t)])[None]  # sampled arc
    e = np.array([1000.0, 2500.0])
    d, d2 = np.zeros(2), np.zeros(1)
    img = rasterize((128, 128), paths, e, k, flux_fraction_lost=1e-6, drawn_e=d, **lam)
    img2 = rasterize((128, 128), curved, [4000.0], k, flux_fraction_lost=1e-6, drawn_e=d2,
                     **{k_: v[:1] for k_, v in lam.items()})
    assert abs(img.sum() - d.sum()) < 1e-12 * e.sum() and abs(img2.sum() - d2.sum()) < 1e-12 * 4000.0
    frac = np.concatenate([d / e, d2 / 4000.0])
    if name == "gaussian":  # the Gaussian's stamps are cut, not normalised: 1e-6 may be missing
        assert np.all(np.abs(frac - 1.0) < 2e-6)
    else:
        assert np.all((frac > 0.85) & (frac < 1.0 + 1e-4)), frac  # a measured image holds its whole light
        same = frac if name != "airy-poly" else frac[[0, 2]]  # airy-poly: the straight streak at 700 nm
        assert np.ptp(same) < 1e-2


def test_tabulated_image_reproduces_the_analytic_airy(tmp_path):
    """A measured image that IS an Airy pattern (sampled 4 per px, in .npy and in .fits) gives the
    Airy model's stamps to 2e-4 of the peak on a 21 x 21 stamp (independent paths: a table sampled from the
    formula and pixel-integrated by FFT, versus the model's own table); even-sized images are
    re-centred by half a sample. Not normalised on the stamp: a measured image is the whole PSF
    (normalised to a sum of 1 on load), so the tabulated stamps are the Airy's divided by the
    light the image holds of it (its samples' sum / 16: 0.96 within its 12 px)."""
    airy = kernel_for(_camera({"model": "airy", "obscuration": 0.0, "wavelength_nm": WL_NM}), None, 1e-6)
    for fname in ("a.npy", "a.fits"):
        path = _airy_image(tmp_path / fname, 4)
        held = float(np.sum(np.load(path) if fname.endswith(".npy") else _read_fits(path))) / 16.0
        tab = kernel_for(_camera({"model": "tabulated", "file": path, "oversampling": 4}), None, 1e-6)
        h = 10  # inside the measured image's 12 px
        for xy in ([20.0, 20.0], [20.3, 19.8]):
            a, b = airy.stamp(xy, h), tab.stamp(xy, h)
            assert np.max(np.abs(a / held - b)) < 2e-4 * a.max()
    # an even-sized image whose centre falls between samples
    n = 96
    u = (np.arange(n) - (n - 1) / 2) / 4.0
    np.save(tmp_path / "even.npy", airy_intensity(np.hypot(u[None, :], u[:, None]), LF_PX, 0.0))
    tab = kernel_for(_camera({"model": "tabulated", "file": str(tmp_path / "even.npy"), "oversampling": 4}), None, 1e-6)
    h = 10
    held = float(np.sum(np.load(tmp_path / "even.npy"))) / 16.0
    a, b = airy.stamp([20.1, 20.2], h), tab.stamp([20.1, 20.2], h)
    assert np.max(np.abs(a / held - b)) < 2e-3 * a.max()


def test_field_grid_reproduces_each_grid_psf_and_varies_smoothly(tmp_path):
    """At a grid point the stamp is that point's table's to 1e-6 (measured 0: weight exactly 1);
    between grid points it is the bilinear blend (at the centre the mean of the four), and a
    0.01 px move changes no pixel by more than 1e-3 of the peak."""
    shifts = {(0.0, 0.0): (0.0, 0.0), (100.0, 0.0): (0.4, 0.0), (0.0, 80.0): (0.0, 0.4), (100.0, 80.0): (0.4, 0.4)}
    pts = [{"x_px": x, "y_px": y, "file": _airy_image(tmp_path / f"f{x}_{y}.npy", 4, shift=s)} for (x, y), s in shifts.items()]
    grid = kernel_for(_camera({"model": "tabulated", "field": pts, "oversampling": 4}, size=128), None, 1e-6)
    h = grid.half
    singles = {}
    for p in pts:
        one = kernel_for(_camera({"model": "tabulated", "file": p["file"], "oversampling": 4}, size=128), None, 1e-6)
        singles[(p["x_px"], p["y_px"])] = one
        for frac in ((0.0, 0.0), (0.25, -0.3)):
            xy = np.array([p["x_px"] + frac[0], p["y_px"] + frac[1]])
            if frac != (0.0, 0.0):  # off the grid point by a fraction of a pixel: still inside
                xy = np.clip(xy, [0.0, 0.0], [100.0, 80.0])
            w = grid.stamp(xy, h)
            ref = one.stamp(xy, one.half if one.half == h else h)
            if tuple(xy) == (p["x_px"], p["y_px"]):
                assert np.max(np.abs(w - ref)) < 1e-6
    mid = np.array([50.0, 40.0])
    blend = sum(s.stamp(mid, h) for s in singles.values()) / 4.0
    got = grid.stamp(mid, h)
    assert np.max(np.abs(got - blend)) < 1e-12 * got.max()
    # smooth: a small move gives a small change (no jumps between cells)
    xs = np.linspace(45.0, 55.0, 1001)
    st = grid.stamps(np.column_stack([xs, np.full_like(xs, 40.0)]), h)
    # compare shifted-origin-free: the stamp content moves with the point; look at the cell edge
    for x0 in (49.995, 50.0, 50.005):
        a = grid.stamp([x0, 40.0], h)
        b = grid.stamp([x0 + 0.001, 40.0], h)
        assert np.max(np.abs(a - b)) < 1e-3 * a.max()
    assert np.all(np.isfinite(st))


def test_streak_quadrature_of_a_table_psf_has_converged():
    """The streak quadrature's panel (0.35 px for table PSFs) against a 0.02 px reference:
    every pixel within 1e-5 of the source's flux (measured 2e-6 for the coma PSF)."""
    k = kernel_for(_camera({"model": "optical", "obscuration": 0.2, "wavelength_nm": WL_NM, "zernike_waves": COMA}), None, 1e-6)
    path = np.array([[[20.3, 30.1], [43.9, 36.2]]])
    a = rasterize((64, 64), path, [1.0], k)
    b = rasterize((64, 64), path, [1.0], k, step_px=0.02)
    assert np.max(np.abs(a - b)) < 1e-5


def test_centre_of_light_in_the_truth_is_the_moment_of_the_drawn_image():
    """A coma camera's frame: each isolated star's ``centre_of_light_xy`` against the first
    moment of the noise-free image in a window around it (an independent sum over the image),
    to 1e-3 px; and it differs from the geometric ``xy`` by the coma's bias (> 0.5 px)."""
    from skynav.renderer.render import RenderOptions, render
    from skynav.scenes import frames
    from skynav.scenes.scene import build_scene

    cam = Camera(width=160, height=160, focal_length_mm=2000.0, pixel_pitch_um=PITCH_UM, f_number=F_NUMBER,
                 psf={"model": "optical", "obscuration": 0.2, "wavelength_nm": WL_NM, "zernike_waves": COMA})
    R = frames.radec_twist_to_dcm(np.radians(84.05), np.radians(-1.2), 0.0)  # Orion's belt
    scene = build_scene("2027-02-01T00:00:00", position_km=[1.5e8, 0.0, 0.0], velocity_km_s=[0.0, 30.0, 0.0],
                        R_cam_icrs=R, camera=cam, catalog_limiting_v_mag=11.0)
    frame = render(scene, seed=1, options=RenderOptions(noise=False, cosmic_rays_per_frame=0.0, resolved=False))
    stars = frame.truth["stars"]
    img = frame.electrons.astype(float)
    h = kernel_for(cam, None, 1e-6).half
    checked = 0
    xy_all = np.array([s["xy"] for s in stars])
    for s in stars:
        x, y = s["xy"]
        others = np.hypot(*(xy_all - [x, y]).T)
        if np.sum(others < 2 * h + 4) > 1 or not (h + 2 < x < 160 - h - 3 and h + 2 < y < 160 - h - 3) or s["electrons"] < 1e3:
            continue
        x0, y0 = int(round(x)) - h, int(round(y)) - h
        win = img[y0:y0 + 2 * h + 1, x0:x0 + 2 * h + 1]
        yy, xx = np.indices(win.shape)
        m = np.array([(win * xx).sum() / win.sum() + x0, (win * yy).sum() / win.sum() + y0])
        c = np.array(s["centre_of_light_xy"])
        assert np.max(np.abs(c - m)) < 1e-3
        assert np.hypot(*(c - [x, y])) > 0.5
        checked += 1
    assert checked >= 1
    assert frame.truth["camera"]["psf"]["model"] == "optical" and frame.truth["schema"] == "skynav.frame/2"


def test_default_gaussian_frame_is_drawn_by_the_same_code_as_before():
    """The Gaussian through the model plumbing is the pre-model path: the same code
    (``rasterize`` with ``GaussianKernel(defocus_sigma_px)`` on the same paths) gives the same bits,
    for the shorthand and for an explicit ``{model: gaussian}``; the frame with the same seed is
    the same too. (Against the code before this change, the default, a streaked and a Mitsuba
    frame kept their PNG and EXR SHA-256: docs/conventions.md.)"""
    from skynav.renderer.kernels import GaussianKernel
    from skynav.renderer.radiometry import Radiometry
    from skynav.renderer.expected import source_paths
    from skynav.renderer.render import RenderOptions, expected_image, render
    from skynav.scenes import frames
    from skynav.scenes.camera import paper_camera
    from skynav.scenes.scene import build_scene

    opts = RenderOptions(resolved=False)
    R = frames.radec_twist_to_dcm(np.radians(84.05), np.radians(-1.2), 0.0)
    images = []
    for cam in (paper_camera(width=256, height=256), paper_camera(width=256, height=256, psf={"model": "gaussian", "sigma_px": 0.5})):
        scene = build_scene("2027-02-01T00:00:00", position_km=[1.5e8, 0.0, 0.0], velocity_km_s=[0.0, 30.0, 0.0],
                            R_cam_icrs=R, camera=cam, angular_velocity_rad_s=[0.002, -0.001, 0.003])
        assert not any(b.in_fov for b in scene.bodies)
        img = expected_image(scene, rng=np.random.default_rng(1), options=opts).electrons
        rad = Radiometry.for_camera(cam)
        e = np.asarray(rad.star_electrons_per_s(scene.stars.v_mag, scene.stars.teff_k)) * cam.exposure_s
        direct = rasterize((256, 256), source_paths(scene, scene.stars.u_icrs, opts), e, GaussianKernel(0.5),
                           flux_fraction_lost=opts.flux_fraction_lost)
        assert np.array_equal(img, direct)
        images.append(render(scene, seed=5, options=opts).dn)
    assert np.array_equal(images[0], images[1])


def _paper_camera(psf):
    from skynav.scenes import presets
    from skynav.scenes.scene import build_from_spec

    return build_from_spec(presets.default_scene_spec()).camera.replace(width=128, height=128, psf=psf)


@pytest.mark.parametrize("name", ["airy-paper", "airy-paper-poly", "airy", "optical", "field"])
def test_a_faint_star_s_smaller_stamp_keeps_its_flux_and_centre_of_light(name, tmp_path):
    """Stars of 100 e- to 1e6 e- at random sub-pixel phases (static and 6 px streaks), drawn with
    stamps sized by their charge (``stamp_e``) and with the kernel's full stamps: each cut image
    holds no more than the full one (the light beyond the cut is not drawn), each source's centre of light is the
    full stamp's to 1e-3 px (the cut is refused where it would move more than 5e-4 px: the other
    half for phases off the 1/16 px grid the limit is found on), and a static star changes no
    pixel by more than 1.25 x 0.1 of its noise (read noise and its own shot noise; 0.1 on the
    phase grid, the 1.25 for phases between). On the paper camera (lambda F = 0.09 px) the faint
    stars are drawn with smaller stamps than the table's; a coma's asymmetric wing keeps its
    full stamps."""
    from skynav.renderer.table_kernels import STAMP_NOISE_FRACTION

    if name.startswith("airy-paper"):
        cam = _paper_camera({"model": "airy", "obscuration": 0.2} | ({} if name.endswith("poly") else {"wavelength_nm": 550.0}))
    elif name == "field":
        pts = [{"x_px": x, "y_px": y, "file": _airy_image(tmp_path / f"a{x}_{y}.npy", 4, shift=(0.01 * x, 0.0))}
               for x in (0.0, 128.0) for y in (0.0, 128.0)]
        cam = _camera({"model": "tabulated", "field": pts, "oversampling": 4}, size=128)
    else:
        cam = _camera(MODELS[name], size=128)
    k = kernel_for(cam, None, 1e-6)
    rng = np.random.default_rng(3)
    e = np.array([100.0, 300.0, 1e3, 3e3, 1e4, 1e5, 1e6])
    xy = np.column_stack([np.linspace(25.0, 100.0, e.size), np.full(e.size, 30.0)]) + rng.uniform(-0.5, 0.5, (e.size, 2))
    static = np.stack([xy, xy], axis=1)
    streak = np.stack([xy + [0.0, 50.0], xy + [4.0, 54.5]], axis=1)
    lam = {"wavelength_nm": np.full(e.size, 640.0)} if name.endswith("poly") else {}
    sigma = cam.sensor.read_noise_e
    for paths in (static, streak):
        for i in range(e.size):  # one star at a time: the image is its own
            one = {kk: v[i:i + 1] for kk, v in lam.items()}
            c_full, c_cut = np.zeros((1, 2)), np.zeros((1, 2))
            full = rasterize((128, 128), paths[i:i + 1], e[i:i + 1], k, centre_of_light=c_full, **one)
            cut = rasterize((128, 128), paths[i:i + 1], e[i:i + 1], k, centre_of_light=c_cut, stamp_e=e[i:i + 1], **one)
            assert cut.sum() <= full.sum() * (1.0 + 1e-12)
            assert np.max(np.abs(c_cut - c_full)) < 1e-3
            if paths is static:
                assert np.all(np.abs(cut - full) <= 1.25 * STAMP_NOISE_FRACTION * np.sqrt(sigma**2 + full))
    sizes = k.half_sizes_px(e)
    assert np.all(np.diff(sizes) >= 0) and sizes[-1] == k.half
    if name.startswith("airy-paper"):
        assert sizes[0] < k.half  # the faint stars are cut
    if name == "optical":
        assert np.all(sizes == k.half)  # the coma's wing would move the centre of light


def test_sized_stamps_draw_the_second_image_as_a_second_call_would():
    """``also=`` with ``stamp_e``: the irradiance drawn with the electrons' stamps, sized by their
    charge, equals a second call with ``out=`` (same code, same inputs: the same bits)."""
    cam = _paper_camera({"model": "airy", "obscuration": 0.2, "wavelength_nm": 550.0})
    k = kernel_for(cam, None, 1e-6)
    rng = np.random.default_rng(11)
    e = 10.0 ** rng.uniform(2.0, 6.0, 40)
    irr = e * 3.7e-15
    xy = rng.uniform(5.0, 123.0, (40, 2))
    paths = np.stack([xy, xy + rng.uniform(-3.0, 3.0, (40, 2))], axis=1)
    second = np.zeros((128, 128))
    one = rasterize((128, 128), paths, e, k, stamp_e=e, also=(irr, second))
    alone = rasterize((128, 128), paths, e, k, stamp_e=e)
    again = rasterize((128, 128), paths, irr, k, stamp_e=e)
    assert len(np.unique(k.half_sizes_px(e, 1e-6))) > 1  # the faint and the bright stamps differ
    assert np.array_equal(one, alone)
    assert np.array_equal(second, again)
