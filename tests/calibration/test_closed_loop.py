"""The closed loop on the virtual bench (calibration/bench_files.py, measuring with
calibration/closed_loop.py): a montecarlo dataset exported with the calibrated facility,
captured by the virtual camera and measured like its software frames.

Fast tests use ``screen_small`` (256 px camera, 281 arcsec per camera px, 640 px screen) on a few
frames and check the noise-free loop (the bench's systematic error) in camera pixels, against an
uncalibrated bench that must fail the same checks. The issue's acceptance numbers (``bench``
preset, 71 arcsec per px, with camera noise) are in the ``slow`` test at the end:
``pytest -m slow tests/calibration/test_closed_loop.py``.
"""

import numpy as np
import pytest

from skynav.calibration.bench_files import run_closed_loop

SMALL_PX_ARCSEC = 281.0


@pytest.fixture(scope="module")
def small_calibrated(small_facility, small_patterns, small_captures):
    from skynav.calibration.radiometric import calibrate_radiometric
    from skynav.calibration.bench_files import calibrate_geometric

    geo = calibrate_geometric(small_facility, small_patterns, small_captures)
    return calibrate_radiometric(geo.facility, small_captures / "power_meter.csv").facility


@pytest.fixture(scope="module")
def small_loop(tmp_path_factory, small_facility, small_calibrated):
    return run_closed_loop(small_facility, small_calibrated, tmp_path_factory.mktemp("loop"), frames=6, dataset_seed=5)


def test_noise_free_loop_puts_stars_and_planets_on_their_directions(small_loop):
    s = small_loop.summary()
    assert s["frames"] == 6
    star, planet = s["noise_free"]["star"], s["noise_free"]["planet"]
    assert star["n"] >= 10 and star["measured"] == star["n"]
    # the calibrated model's own error on this small bench is ~0.01 camera px (4 averaged captures);
    # 0.03 px = 8 arcsec here is the 2 arcsec of the 1024 px bench scaled by 4
    assert star["rms_arcsec"] < 0.03 * SMALL_PX_ARCSEC and star["max_arcsec"] < 0.08 * SMALL_PX_ARCSEC
    # the software frame measured by the same code: the measurement's own floor
    assert star["software_rms_arcsec"] < 0.005 * SMALL_PX_ARCSEC
    if planet["n"]:
        assert planet["vs_photocentre_rms_arcsec"] < 0.05 * SMALL_PX_ARCSEC
    # photometry: capture electrons against the software frame's, 0.01 mag = 0.9 %
    assert star["n_photometry"] >= 5 and abs(star["dmag_bias"]) < 0.01 and star["dmag_rms"] < 0.02


def test_noisy_loop_is_measured_and_sources_are_accounted_for(small_loop):
    s = small_loop.summary()
    r = small_loop.rows
    assert len(r.frame) == s["noisy"]["star"]["n"] + s["noisy"]["planet"]["n"]
    assert set(r.kind) <= {"star", "planet"} and np.all(r.v_mag[r.kind == "star"] < 6.0)
    star = s["noisy"]["star"]
    # one noisy 256 px exposure: photon noise of a V = 6 star is ~0.01 px; 0.05 px leaves room
    assert star["measured"] == star["n"] and star["rms_arcsec"] < 0.05 * SMALL_PX_ARCSEC
    assert abs(star["dmag_bias"]) < 0.02


def test_an_uncalibrated_bench_fails_the_same_checks(tmp_path, small_facility):
    """Exporting with the nominal facility file (no calibration) misses by the bench's
    misalignment (about 950 arcsec): the loop must see it."""
    s = run_closed_loop(small_facility, small_facility, tmp_path, frames=2, dataset_seed=5).summary()
    star = s["noise_free"]["star"]
    assert star["rms_arcsec"] > 300.0


@pytest.mark.slow
def test_issue_12_closed_loop_acceptance(tmp_path):
    """On the realistic bench (25 % vignetting at the corner, the OLED-like screen
    spectrum, calibrated from its own captures), with camera noise: >= 99.5 % of the V < 6 stars
    within 5 arcsec of their true apparent direction, RMS <= 2 arcsec; unresolved planets within
    5 arcsec of their rendered photocentre (the truth direction of a disc's centre differs from
    its light centre by its phase offset, which the software frame shows too), RMS <= 2 arcsec;
    capture electrons vs software-frame electrons within 0.03 mag RMS, bias <= 0.01 mag."""
    from skynav.calibration.radiometric import calibrate_radiometric
    from skynav.calibration.bench_files import calibrate_geometric, simulate, write_patterns
    from skynav.scenes.facility import screen_preset

    fac = screen_preset()
    write_patterns(fac, tmp_path / "pat", phases=4)
    simulate(fac, tmp_path / "pat", tmp_path / "cap", scenario_name="realistic")
    geo = calibrate_geometric(fac, tmp_path / "pat", tmp_path / "cap")
    cal = calibrate_radiometric(geo.facility, tmp_path / "cap" / "power_meter.csv").facility
    s = run_closed_loop(fac, cal, tmp_path / "loop", frames=30, dataset_seed=20260101).summary()
    star, planet = s["noisy"]["star"], s["noisy"]["planet"]
    assert star["n"] >= 500
    assert star["within_5_arcsec"] >= 0.995 and star["rms_arcsec"] <= 2.0
    assert planet["n"] >= 10
    assert planet["vs_photocentre_within_5_arcsec"] == 1.0 and planet["vs_photocentre_rms_arcsec"] <= 2.0
    assert star["dmag_rms"] <= 0.03 and abs(star["dmag_bias"]) <= 0.01


def test_power_meter_readings_are_dense_at_low_counts(small_captures):
    """The radiometric model must be measured densely at low counts, where faint stars'
    screen pixels sit: at least 10 distinct digital counts below 10 % of full scale, including the
    first few steps above black (DN 1-3), which set the curve's foot."""
    from skynav.calibration.radiometric import read_measurements

    d, _, _ = read_measurements(small_captures / "power_meter.csv")
    low = np.unique(d[d < 0.1 * 1023])
    assert len(low) >= 10 and {1, 2, 3} <= set(low.astype(int).tolist())
