"""Cosmic-ray hits: count statistics (chi-square vs the Poisson pmf), charge law (KS vs scipy's
Moyal), charge conservation, every hit recorded."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from skynav.infra.errors import ConfigValueError
from skynav.renderer.cosmic_rays import ChargeModel, CosmicRayHits, deposit, draw_cosmic_rays
from skynav.renderer.detector import Sensor
from skynav.scenes.camera import SensorParams


def test_poisson_counts_chi_square():
    rate, frames = 1.7, 3000
    rng = np.random.default_rng(2024)
    counts = np.array([len(draw_cosmic_rays((32, 32), rate, rng)) for _ in range(frames)])
    kmax = 6  # pool k >= 6 (expected ~ 26 frames)
    obs = np.array([np.sum(counts == k) for k in range(kmax)] + [np.sum(counts >= kmax)], float)
    exp = frames * np.append(stats.poisson.pmf(np.arange(kmax), rate), stats.poisson.sf(kmax - 1, rate))
    chi2 = float(np.sum((obs - exp) ** 2 / exp))
    assert stats.chi2.sf(chi2, len(obs) - 1) > 1e-3, (obs, exp)


def test_fixed_mode_paper_single_pixel():
    rng = np.random.default_rng(1)
    for _ in range(50):
        hits = draw_cosmic_rays((64, 48), 1, rng, mode="fixed")
        assert len(hits) == 1 and hits.pixel_rows.size == 1
        r, c = hits.pixel_rows[0], hits.pixel_cols[0]
        assert 0 <= r < 64 and 0 <= c < 48
        assert np.array_equal(hits.xy[0], [c, r])  # pixel centre, x = column
    with pytest.raises(ConfigValueError):
        draw_cosmic_rays((8, 8), 1.5, rng, mode="fixed")


def test_charge_follows_moyal_ks():
    rng = np.random.default_rng(5)
    model = ChargeModel(mpv_e=1600.0, width_e=250.0)
    q = np.concatenate([draw_cosmic_rays((256, 256), 40, rng, mode="fixed", charge_model=model).electrons for _ in range(100)])
    # floor at 0 is ~6.4 widths below the mode: probability ~1e-10, irrelevant here
    p = stats.kstest(q, stats.moyal(loc=1600.0, scale=250.0).cdf).pvalue
    assert p > 1e-3
    assert np.all(q > 0)
    ql = draw_cosmic_rays((64, 64), 2000, rng, mode="fixed", charge_model=ChargeModel(kind="lognormal", mpv_e=1000.0, width_e=300.0)).electrons
    assert stats.kstest(np.log(ql), stats.norm(np.log(1000.0), 0.3).cdf).pvalue > 1e-3


@pytest.mark.parametrize("track_prob", [0.0, 0.5, 1.0])
def test_charge_conserved_and_every_hit_recorded(track_prob):
    rng = np.random.default_rng(int(track_prob * 10) + 3)
    shape = (40, 50)
    hits = draw_cosmic_rays(shape, 30, rng, mode="fixed", track_prob=track_prob, max_track_length_px=12.0)
    assert len(hits) == 30
    base = rng.uniform(0, 10, shape)
    out = deposit(base.copy(), hits)
    assert out.sum() - base.sum() == pytest.approx(hits.electrons.sum(), rel=1e-12)
    # every hit has charged pixels, and its recorded charge is the sum of them
    for i in range(len(hits)):
        sel = hits.pixel_hit == i
        assert sel.any()
        assert hits.pixel_electrons[sel].sum() == pytest.approx(hits.electrons[i], rel=1e-12)
        if hits.is_track[i]:
            # tracks: pixels within half a pixel (+ diagonal) of the segment, charge ~ length
            a, b = hits.track_start_xy[i], hits.track_end_xy[i]
            length = np.hypot(*(b - a))
            assert 1.0 <= length <= 12.0
            pts = np.column_stack([hits.pixel_cols[sel], hits.pixel_rows[sel]]).astype(float)
            t = np.clip(((pts - a) @ (b - a)) / (length * length), 0, 1)
            dist = np.hypot(*(pts - (a + t[:, None] * (b - a))).T)
            assert np.all(dist <= np.sqrt(0.5) + 1e-9)
            assert np.allclose(hits.xy[i], 0.5 * (a + b))
        else:
            assert np.array_equal(hits.track_start_xy[i], hits.xy[i])
    assert hits.is_track.mean() == pytest.approx(track_prob, abs=0.3)
    assert len(hits.to_ground_truth()) == 30


def test_deterministic_and_value_semantics():
    a = draw_cosmic_rays((32, 32), 5.0, np.random.default_rng(9), track_prob=0.5)
    b = draw_cosmic_rays((32, 32), 5.0, np.random.default_rng(9), track_prob=0.5)
    c = draw_cosmic_rays((32, 32), 5.0, np.random.default_rng(10), track_prob=0.5)
    assert a == b and hash(a) == hash(b) and a != c
    assert isinstance(a, CosmicRayHits)
    empty = draw_cosmic_rays((8, 8), 0.0, np.random.default_rng(0))
    assert len(empty) == 0 and np.array_equal(deposit(np.ones((8, 8)), empty), np.ones((8, 8)))
    img = np.zeros((32, 32))
    assert deposit(img, a) is img and img.sum() == pytest.approx(a.electrons.sum())  # in place


def test_deposit_through_sensor_is_not_poisson_scaled():
    # the extra charge reaches the ADC unscaled by PRNU and without shot noise on it
    p = SensorParams(bit_depth=16, gain_dn_per_e=1.0, offset_dn=0.0, full_well_e=60000.0, read_noise_e=0.0, reset_noise_e=0.0, dark_current_e_per_s=0.0, dsnu_e_per_s=0.0, prnu_fraction=0.3)
    s = Sensor(p, (16, 16))
    hits = draw_cosmic_rays(s.shape, 3, np.random.default_rng(1), mode="fixed")
    extra = deposit(np.zeros(s.shape), hits)
    dn = s.expose(np.zeros(s.shape), 0.1, np.random.default_rng(2), backend="numpy", extra_charge_e=extra)
    assert np.array_equal(dn, np.floor(extra + 0.5).astype(np.uint16))


def test_bad_config():
    rng = np.random.default_rng(0)
    with pytest.raises(ConfigValueError, match="mode"):
        draw_cosmic_rays((8, 8), 1, rng, mode="sometimes")
    with pytest.raises(ConfigValueError, match="track_prob"):
        draw_cosmic_rays((8, 8), 1, rng, track_prob=2.0)
    with pytest.raises(ConfigValueError, match="kind"):
        ChargeModel(kind="gauss")
    with pytest.raises(ConfigValueError, match="shape"):
        deposit(np.zeros((4, 4)), draw_cosmic_rays((8, 8), 1, rng))
    with pytest.raises(ConfigValueError, match="in place"):
        deposit(np.zeros((8, 8), dtype=np.uint16), draw_cosmic_rays((8, 8), 1, rng))
