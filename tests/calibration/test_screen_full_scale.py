"""A source brighter than the screen's full scale (renderer/display.py ``spread_over_full_scale``):
its excess charge moves to the neighbouring screen pixels, keeping its electrons and its centroid.
Plain clipping loses the core unevenly and shifts it by a fraction of a screen pixel (measured on
the closed loop: 2 to 5 arcsec for Jupiter and Venus on the bench preset)."""

import numpy as np

from skynav.renderer.display import spread_over_full_scale
from skynav.scenes.facility import bench_small_preset


def _source(shape, xy, total_e, sigma_px=0.6):
    yy, xx = np.mgrid[0:shape[0], 0:shape[1]]
    g = np.exp(-((xx - xy[0]) ** 2 + (yy - xy[1]) ** 2) / (2 * sigma_px ** 2))
    return total_e * g / g.sum()


def test_excess_charge_keeps_total_and_centroid():
    fac = bench_small_preset()
    rm, cam = fac.radiometric, fac.camera
    e_full = (rm.peak_w_m2 - rm.black_w_m2) * fac.electrons_per_s_per_w_m2() * cam.exposure_s
    shape = (fac.screen.height_px, fac.screen.width_px)
    xy = np.array([301.37, 288.81])
    img = _source(shape, xy, 200 * e_full)  # a core 200 x full scale in total
    out, n_over = spread_over_full_scale(img, fac)
    assert n_over >= 4
    assert out.max() <= e_full * (1 + 1e-6)
    assert abs(out.sum() / img.sum() - 1) < 1e-9
    yy, xx = np.mgrid[0:shape[0], 0:shape[1]]
    centroid = lambda a: np.array([(a * xx).sum(), (a * yy).sum()]) / a.sum()  # noqa: E731
    c0 = centroid(img)  # the sampled source's own centroid
    assert np.hypot(*(centroid(out) - c0)) < 1e-6
    # what clipping would do here: 0.065 screen px (2.1 arcsec on the bench preset's camera)
    assert np.hypot(*(centroid(np.minimum(img, e_full)) - c0)) > 0.03


def test_nothing_changes_below_full_scale():
    fac = bench_small_preset()
    img = _source((fac.screen.height_px, fac.screen.width_px), (100.2, 200.7), 1e4)
    out, n_over = spread_over_full_scale(img, fac)
    assert n_over == 0 and out is img
