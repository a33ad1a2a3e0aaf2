"""Tracking's window measurements against independent references: the Eq. 7-8 centroid of an
analytic Gaussian spot, :func:`detect_spots` on the same pixels, and numpy's median/MAD."""

from __future__ import annotations

import numpy as np

from skynav.pipeline.centroids import detect_spots
from skynav.pipeline.windows import spots_in_boxes, window_centroids, window_peaks
from skynav.pipeline.levels import robust_level


def _gauss_image(centres, amp=200.0, sigma=1.1, bg=3.0, shape=(128, 160), noise=0.0, seed=0):
    yy, xx = np.mgrid[: shape[0], : shape[1]]
    img = np.full(shape, bg)
    for x, y in centres:
        img = img + amp * np.exp(-((xx - x) ** 2 + (yy - y) ** 2) / (2 * sigma**2))
    if noise:
        img = img + np.random.default_rng(seed).normal(0.0, noise, shape)
    return img


def test_window_centroid_recovers_a_symmetric_spot_centre():
    """Eq. 7-8 weights I^2 are symmetric about the centre of a symmetric spot: the centroid of an
    untruncated Gaussian is its centre (0.01 px: the ROI's sub-threshold cut is symmetric only
    to the pixel grid)."""
    rng = np.random.default_rng(1)
    true = np.column_stack([rng.uniform(20, 140, 30), rng.uniform(20, 108, 30)])
    true = true[np.min(np.linalg.norm(true[:, None] - true[None], axis=-1) + np.eye(30) * 1e9, axis=1) > 12]
    img = _gauss_image(true)
    pred = true + rng.uniform(-3, 3, true.shape)  # a prior a few pixels off
    w = window_centroids(img, pred, threshold_dn=8.0, background_dn=3.0, search_half_px=5)
    assert w.valid.all()
    assert np.abs(w.xy_px - true).max() < 0.01


def test_window_centroids_equal_detect_spots_for_isolated_spots():
    """Same ROI rule (pixels above the threshold and their 8-neighbours) and the same weights as
    the full-frame :func:`detect_spots`: the same centroids and fluxes for isolated spots, with
    noise; a bright spot larger than the first ROI is remeasured in a larger one."""
    rng = np.random.default_rng(2)
    true = np.array([[30.3, 40.7], [80.1, 60.2], [120.6, 30.9], [60.0, 100.4]])
    img = np.rint(_gauss_image(true, amp=400.0, sigma=1.6, noise=1.0)).astype(np.uint16)
    full = detect_spots(img, threshold_dn=9.0, background_dn=3.0, max_regions=100)
    w = window_centroids(img, true + rng.uniform(-1, 1, true.shape), threshold_dn=9.0, background_dn=3.0,
                         search_half_px=2)
    assert w.valid.all()
    for xy, f in zip(w.xy_px, w.flux_dn):
        k = np.argmin(np.linalg.norm(full.xy_px - xy, axis=1))
        assert np.allclose(full.xy_px[k], xy, atol=1e-9)
        assert np.isclose(full.flux_dn[k], f, rtol=1e-6)


def test_window_peaks_find_analytic_spot_centres_to_a_tenth_of_a_pixel():
    """Tracking's first pass: the brightest pixel of a 25 x 25 search box and the I^2-weighted
    centre of its 3 x 3 neighbourhood. Reference: the analytic centres of Gaussian spots (sigma
    1.1 px, the paper camera's PSF scale) placed at random sub-pixel phases, priors up to 8 px
    off. 0.15 px: the 3 x 3 centre of a sampled Gaussian is pulled toward the peak pixel by up
    to ~0.1 px (the next pass measures the Eq. 7-8 centroid in a 1-px search around the
    re-predicted position, so this only has to land within half a pixel)."""
    rng = np.random.default_rng(4)
    true = np.column_stack([rng.uniform(10, 630, 60), rng.uniform(10, 502, 60)])
    # no other spot within reach of a box (8 px prior error + 12 px search + 4 px of PSF)
    true = true[np.min(np.linalg.norm(true[:, None] - true[None], axis=-1) + np.eye(60) * 1e9, axis=1) > 26]
    img = np.rint(_gauss_image(true, noise=0.5, seed=4, shape=(512, 640))).astype(np.uint8)
    pred = true + rng.uniform(-8, 8, true.shape)
    c = np.rint(pred)
    inside = (c >= 12).all(axis=1) & (c[:, 0] < 640 - 12) & (c[:, 1] < 512 - 12)
    assert inside.sum() >= 10
    xy, ok = window_peaks(img, pred, threshold_dn=8.0, background_dn=3.0, search_half_px=12)
    np.testing.assert_array_equal(ok, inside)  # every box inside the image finds its spot
    assert np.abs(xy[ok] - true[ok]).max() < 0.15
    assert np.isnan(xy[~ok]).all()


def test_window_peaks_without_a_spot_are_invalid():
    img = np.full((64, 64), 3, dtype=np.uint16)
    img[40, 40] = 5  # below the threshold
    xy, ok = window_peaks(img, np.array([[40.0, 40.0], [np.nan, 5.0], [1.0, 1.0], [1e30, 3.0]]), threshold_dn=8.0,
                          background_dn=3.0, search_half_px=3)
    assert not ok.any() and np.isnan(xy).all()


def test_window_without_a_spot_is_invalid():
    img = np.full((64, 64), 3.0)
    w = window_centroids(img, np.array([[32.0, 32.0], [np.nan, 5.0], [1.0, 1.0]]), threshold_dn=8.0,
                         background_dn=3.0, search_half_px=3)
    assert not w.valid.any()


def test_spots_in_boxes_equal_detect_spots_inside_the_boxes():
    """Box labelling gives the full-frame regions and centroids of every spot wholly inside a
    box; spots cut by a box edge are dropped, not measured truncated."""
    true = np.array([[40.2, 40.6], [44.9, 47.3], [100.5, 80.1], [70.0, 20.0]])
    img = np.rint(_gauss_image(true, amp=150.0, sigma=1.3, noise=1.0, seed=4)).astype(np.uint16)
    full = detect_spots(img, threshold_dn=9.0, background_dn=3.0, max_regions=100)
    boxes = spots_in_boxes(img, np.array([[42.0, 44.0], [100.0, 80.0], [70.0, 28.0]]), np.array([12, 6, 8]),
                           threshold_dn=9.0, background_dn=3.0)
    got = {tuple(np.round(x, 6)) for x in boxes.xy_px}
    inside = [k for k, xy in enumerate(full.xy_px) if (abs(xy[0] - 42) < 9 and abs(xy[1] - 44) < 9)
              or (abs(xy[0] - 100) < 3 and abs(xy[1] - 80) < 3)]
    assert {tuple(np.round(full.xy_px[k], 6)) for k in inside} == got
    # the spot at (70, 20) reaches the edge of the box centred 8 px below it: dropped
    assert not any(abs(x - 70) < 2 and abs(y - 20) < 2 for x, y in boxes.xy_px)


def test_robust_level_of_integer_frames_matches_numpy():
    """The histogram route for integer frames gives numpy's median and MAD: the median exactly
    (the median of integer counts is an integer or a half-integer, exact in any implementation),
    the threshold within 1e-9 relative (two summation orders)."""
    rng = np.random.default_rng(5)
    for dtype, top in ((np.uint8, 255), (np.uint16, 4095), (np.uint16, 65535)):
        for _ in range(10):
            img = rng.poisson(rng.uniform(0.2, 60.0), (256, 256)).astype(dtype)
            img[rng.integers(0, 256, 200), rng.integers(0, 256, 200)] = top
            med, thr = robust_level(img, 5.0)
            sub = img[::8, ::8].astype(np.float64)
            m = float(np.median(sub))
            mad = float(np.median(np.abs(sub - m))) * 1.4826
            sd = max(mad, float(np.std(sub[sub <= m + 5 * max(mad, 0.5)])), 0.5)
            assert med == m
            assert np.isclose(thr, m + 5 * sd, rtol=1e-9)


def test_windows_all_off_the_image_or_empty_give_no_spot():
    """Every window outside the image, at the image edge, or none at all: no crash, no spot."""
    img = np.full((64, 64), 3.0)
    for xy in (np.zeros((0, 2)), np.array([[-50.0, 10.0], [200.0, 30.0]]), np.array([[0.0, 0.0], [63.0, 63.0]])):
        for s in (0, 1, 4):
            w = window_centroids(img + 50.0, xy, threshold_dn=8.0, background_dn=3.0, search_half_px=s)
            assert w.xy_px.shape == (len(xy), 2) and not w.valid.any()
