"""Pixel-integrated PSF and streak rasteriser: flux identities, centroids, batch = loop.

Oracles: flux conservation (rendered sum equals input electrons), the analytic Gaussian
(scipy.stats.norm CDF for pixel fractions), a brute-force 2-D numerical integration of the
Gaussian over a pixel, and the time-mean position of a streak path.
"""

from __future__ import annotations

import pickle

import numpy as np
import pytest
from scipy import integrate
from scipy.stats import norm

from skynav.infra.errors import ConfigValueError
from skynav.renderer.kernels import GaussianKernel, Kernel, stamp_origin
from skynav.renderer.raster import rasterize


def _centroid(img):
    yy, xx = np.mgrid[: img.shape[0], : img.shape[1]]
    s = img.sum()
    return (img * xx).sum() / s, (img * yy).sum() / s


# ------------------------------------------------------------------------------------ PSF
def test_gaussian_psf_value_semantics():
    psf = GaussianKernel(0.5)
    assert isinstance(psf, Kernel)
    assert psf == GaussianKernel(0.5) and hash(psf) == hash(GaussianKernel(0.5)) and psf != GaussianKernel(0.6)
    assert eval(repr(psf)) == psf
    assert pickle.loads(pickle.dumps(psf)) == psf
    with pytest.raises(ConfigValueError):
        GaussianKernel(-0.1)
    with pytest.raises(ValueError):
        GaussianKernel(float("nan"))


def test_pixel_fraction_matches_scipy_norm_and_2d_quadrature():
    psf = GaussianKernel(0.7)
    x0, y0 = 0.23, -0.41
    edges = np.arange(-3.5, 4.0, 1.0)
    w = psf.pixel_weights(edges - x0, edges - y0)
    wx = np.diff(norm.cdf(edges, loc=x0, scale=0.7))
    wy = np.diff(norm.cdf(edges, loc=y0, scale=0.7))
    np.testing.assert_allclose(w, np.outer(wy, wx), atol=1e-15)
    # one pixel by brute-force 2-D quadrature of the circular Gaussian
    g = lambda y, x: np.exp(-((x - x0) ** 2 + (y - y0) ** 2) / (2 * 0.49)) / (2 * np.pi * 0.49)
    val, _ = integrate.dblquad(g, 0.5, 1.5, -0.5, 0.5, epsabs=1e-12)
    assert w[3, 4] == pytest.approx(val, abs=1e-10)


@pytest.mark.parametrize("sigma", [0.0, 0.3, 0.5, 1.3])
@pytest.mark.parametrize("lost", [1e-4, 1e-6])
def test_stamp_sums_to_one_within_flux_fraction_lost(sigma, lost):
    psf = GaussianKernel(sigma)
    h = psf.half_size_px(lost)
    rng = np.random.default_rng(11)
    xy = rng.uniform(-50, 50, (200, 2))
    s = psf.stamps(xy, h).sum(axis=(1, 2))
    assert np.all(s <= 1.0 + 1e-12)
    assert np.all(1.0 - s < lost)
    if sigma > 0:  # the stamp is the smallest that does it: h - 1 loses too much somewhere
        s_small = psf.stamps(xy, h - 1).sum(axis=(1, 2))
        assert np.max(1.0 - s_small) > 0.5 * lost or h == 1


def test_delta_psf_puts_everything_in_the_containing_pixel():
    psf = GaussianKernel(0.0)
    img = rasterize((8, 8), [[[3.49, 4.5], [3.49, 4.5]]], [10.0], psf)
    # pixel [row 5, col 3] covers x in [2.5, 3.5), y in [4.5, 5.5)
    assert img[5, 3] == 10.0 and img.sum() == 10.0


# ------------------------------------------------------------------------------------ raster
def _random_paths(rng, n, shape, length_px, curved=False, s=2):
    h, w = shape
    c = rng.uniform(30, min(h, w) - 30, (n, 2))
    if curved:
        # rotation about the image centre by a small angle: an arc sampled at s instants
        centre = np.array([(w - 1) / 2, (h - 1) / 2])
        ang = np.linspace(-0.5, 0.5, s) * np.deg2rad(length_px)
        rel = c - centre
        ca, sa = np.cos(ang), np.sin(ang)
        x = centre[0] + rel[:, 0:1] * ca - rel[:, 1:2] * sa
        y = centre[1] + rel[:, 0:1] * sa + rel[:, 1:2] * ca
        return np.stack([x, y], -1)
    a = rng.uniform(0, 2 * np.pi, n)
    d = 0.5 * length_px * np.stack([np.cos(a), np.sin(a)], -1)
    return np.stack([c - d, c + d], 1)


@pytest.mark.parametrize("kind", ["static", "straight", "curved"])
def test_flux_conservation_away_from_border(kind):
    rng = np.random.default_rng(3)
    shape = (256, 300)
    if kind == "curved":
        paths = _random_paths(rng, 200, shape, 6.0, curved=True, s=9)
    else:
        paths = _random_paths(rng, 200, shape, 0.0 if kind == "static" else 17.0)
    e = rng.uniform(10.0, 1e5, 200)
    img = rasterize(shape, paths, e, GaussianKernel(0.5), flux_fraction_lost=1e-6)
    # 1e-4 (brief); flux lost outside each stamp is < 1e-6 by construction
    assert img.sum() == pytest.approx(e.sum(), rel=1e-4)
    assert img.min() >= 0.0


def test_static_centroid_unbiased_over_subpixel_positions():
    rng = np.random.default_rng(5)
    psf = GaussianKernel(0.5)
    worst = 0.0
    for x0, y0 in rng.uniform(20, 21, (40, 2)):
        img = rasterize((41, 41), [[[x0, y0], [x0, y0]]], [1.0], psf)
        cx, cy = _centroid(img)  # window = whole 41 px frame, stamp is 7x7
        worst = max(worst, abs(cx - x0), abs(cy - y0))
    # 0.005 px (brief); pixel-phase bias of the intensity centroid of a sigma=0.5 Gaussian is ~1e-4
    assert worst < 0.005


@pytest.mark.parametrize("sigma", [0.5, 1.0])
def test_streak_centroid_is_mid_exposure_position(sigma):
    rng = np.random.default_rng(9)
    for _ in range(5):
        c = rng.uniform(60, 70, 2)
        a = rng.uniform(0, 2 * np.pi)
        d = 10.0 * np.array([np.cos(a), np.sin(a)])
        img = rasterize((130, 130), [[c - d, c + d]], [5e4], GaussianKernel(sigma))
        cx, cy = _centroid(img)
        # 0.01 px (brief): straight streak, uniform speed -> centroid at the mid-exposure point
        assert abs(cx - c[0]) < 0.01 and abs(cy - c[1]) < 0.01


def test_curved_streak_centroid_is_time_mean_position():
    # an arc about a point: the time-mean of the piecewise-linear path, not its mid-point
    t = np.linspace(0, 1, 17)
    ang = 1.2 * t
    path = np.stack([60 + 25 * np.cos(ang), 40 + 25 * np.sin(ang)], -1)
    img = rasterize((120, 120), path[None], [1e4], GaussianKernel(0.5))
    seg_mid = 0.5 * (path[1:] + path[:-1])
    cx, cy = _centroid(img)
    assert abs(cx - seg_mid[:, 0].mean()) < 0.01 and abs(cy - seg_mid[:, 1].mean()) < 0.01


def test_streak_quadrature_converged():
    # default panel length vs a 100x finer one: the image differs by < 1e-4 of the flux per pixel
    path = np.array([[[40.3, 50.7], [63.1, 59.2]]])
    a = rasterize((100, 100), path, [1.0], GaussianKernel(0.5))
    b = rasterize((100, 100), path, [1.0], GaussianKernel(0.5), step_px=0.005)
    assert np.abs(a - b).max() < 1e-4


def test_batch_equals_per_source_loop():
    rng = np.random.default_rng(21)
    shape = (64, 80)
    paths = np.concatenate([_random_paths(rng, 10, shape, 0.0), _random_paths(rng, 10, shape, 8.0)])
    paths[0] = [[-1.2, 10.0], [-1.2, 10.0]]  # partly off the left edge
    paths[15] = [[70.0, 60.0], [90.0, 70.0]]  # streak leaving the image
    e = rng.uniform(1, 1e3, 20)
    psf = GaussianKernel(0.8)
    batch = rasterize(shape, paths, e, psf)
    loop = sum(rasterize(shape, paths[i : i + 1], e[i : i + 1], psf) for i in range(20))
    np.testing.assert_allclose(batch, loop, rtol=1e-12, atol=1e-12)


def test_clipping_at_edges_loses_only_off_image_flux():
    # a static star centred on the left edge (x = -0.5): exactly half its flux is on the image
    img = rasterize((40, 40), [[[-0.5, 20.0], [-0.5, 20.0]]], [1000.0], GaussianKernel(0.6))
    assert img.sum() == pytest.approx(500.0, rel=1e-6)
    # wholly off-image and non-finite sources contribute nothing
    img2 = rasterize((40, 40), [[[-50, 5], [-40, 5]], [[np.nan, 1], [2, 2]]], [1.0, 1.0], GaussianKernel(0.6))
    assert img2.sum() == 0.0


def test_stamp_origin_convention():
    # pixel [i, j] covers x in [j-0.5, j+0.5): the containing pixel of x=2.5 is column 3
    assert stamp_origin(np.array([[2.5, -0.5]]), 0).tolist() == [[3, 0]]
    assert stamp_origin(np.array([[2.49, 0.49]]), 2).tolist() == [[0, -2]]


def test_bad_inputs_raise():
    with pytest.raises(ValueError):
        rasterize((10, 10), np.zeros((3, 1, 2)), np.ones(3), GaussianKernel(0.5))
    with pytest.raises(ValueError):
        rasterize((10, 10), np.zeros((3, 2, 2)), np.ones(2), GaussianKernel(0.5))


def test_sparse_accumulation_matches_the_full_bincount_and_reports_its_support():
    """A few stamps on a large image (a bench screen) are summed over their own pixels, not a
    full-size bincount: the image must be the same within 2 ulps per pixel (two code paths that
    add each pixel's weights in the same order, so today equal; a pixel missed or counted twice
    is off by a whole stamp value), zero exactly where the reference is, and ``support`` must
    hold every nonzero pixel."""
    from skynav.renderer import raster
    from skynav.renderer.kernels import GaussianKernel

    rng = np.random.default_rng(5)
    paths = np.repeat(rng.uniform(-3.0, 803.0, (300, 1, 2)), 2, axis=1)  # some over the edges
    paths[:20, 1] += rng.uniform(-6.0, 6.0, (20, 2))  # streaks
    e = rng.uniform(10.0, 1e5, 300)
    support = []
    img = raster.rasterize((800, 800), paths, e, GaussianKernel(0.5), support=support)
    assert sum(map(len, support)) * 16 < img.size  # the sparse path
    orig = raster._accumulate
    try:  # the same sums through the full-size bincount
        raster._accumulate = lambda images, flat, ws, sup=None: [im.__iadd__(np.bincount(flat, weights=w, minlength=im.size))
                                                                 for im, w in zip(images, ws)]
        ref = raster.rasterize((800, 800), paths, e, GaussianKernel(0.5))
    finally:
        raster._accumulate = orig
    np.testing.assert_array_max_ulp(img, ref, maxulp=2)
    assert np.array_equal(img == 0, ref == 0)
    nz = np.flatnonzero(img)
    assert np.all(np.isin(nz, np.concatenate(support)))


@pytest.mark.parametrize("shape", [(64, 80), (900, 900)])  # the full bincount and the sparse path
def test_also_draws_a_second_quantity_as_a_second_call(shape):
    """``also=(values, image)`` draws a second quantity with the stamps of the first: the same
    code on the same stamps, so each image is the one a call of its own gives, to the bit (the
    render draws electrons and irradiance this way); centres of light are the first quantity's.
    Sources drawn by one quantity and not the other (a zero or NaN in one) go through two calls,
    and the support then holds the pixels of both (a source with irradiance and no electrons is
    drawn in the irradiance image only: a pixel missed there would be lost from the frame's
    float32 irradiance and left in the render's reused zero images)."""
    rng = np.random.default_rng(8)
    paths = np.concatenate([_random_paths(rng, 30, (64, 80), 0.0), _random_paths(rng, 10, (64, 80), 8.0)])
    paths[0] = [[-1.2, 10.0], [-1.2, 10.0]]  # partly off the left edge
    paths[5] = [[shape[1] - 2.0, shape[0] + 0.3], [shape[1] - 2.0, shape[0] + 0.3]]  # alone, on the bottom edge
    e = rng.uniform(1, 1e3, 40)
    irr = e * 3.7e-15 * rng.uniform(0.5, 2.0, 40)
    psf = GaussianKernel(0.8)
    for first, second in ((e, irr), (e, np.where(np.arange(40) == 3, 0.0, irr)), (np.where(np.arange(40) == 5, 0.0, e), irr)):
        s1, s2 = [], []
        c1, c2 = np.zeros((40, 2)), np.zeros((40, 2))
        ref_e = rasterize(shape, paths, first, psf, support=s1, centre_of_light=c1)
        ref_i = rasterize(shape, paths, second, psf)
        img_i = np.zeros(shape)
        img_e = rasterize(shape, paths, first, psf, support=s2, centre_of_light=c2, also=(second, img_i))
        assert np.array_equal(img_e, ref_e) and np.array_equal(img_i, ref_i)
        assert np.array_equal(c1, c2, equal_nan=True)
        if second is irr and first is e:  # one call: the same support
            assert np.array_equal(np.concatenate(s1), np.concatenate(s2))
        for img in (img_e, img_i):
            assert np.isin(np.flatnonzero(img), np.concatenate(s2)).all()
    with pytest.raises(ValueError, match="raster.also"):
        rasterize(shape, paths, e, psf, also=(irr[:5], np.zeros(shape)))
    with pytest.raises(ValueError, match="raster.also"):
        rasterize(shape, paths, e, psf, also=(irr, np.zeros(shape, np.float32)))


def test_unique_inverse_is_numpys():
    """The raster's distinct stamp pixels and each entry's index among them are numpy's
    ``unique(return_inverse=True)`` answer (the same arrays: integers, no rounding), for stamps
    that overlap, an empty array and repeated runs."""
    from skynav.renderer.raster import _unique_inverse

    rng = np.random.default_rng(3)
    base = rng.integers(0, 60, 300) * 256 + rng.integers(0, 60, 300)
    stamps = (base[:, None] + (np.arange(5)[:, None] * 256 + np.arange(5)).ravel()[None, :]).ravel()
    for flat in (stamps, np.zeros(0, np.int64), np.array([7, 7, 3, 7, 3, 0])):
        u, inv = _unique_inverse(flat)
        ref_u, ref_inv = np.unique(flat, return_inverse=True)
        assert np.array_equal(u, ref_u) and np.array_equal(inv, ref_inv.ravel())
        assert np.array_equal(u[inv], flat)
