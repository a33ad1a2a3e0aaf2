"""Calibration on the virtual bench (screen_small: 256 px camera, 281 arcsec per camera pixel).

The acceptance numbers (bench preset, 1024 px camera) are in test_acceptance_campaign.py (slow)
and benchmarks/hil_bench.py; here the same steps run at a quarter of the resolution.
"""

import json

import numpy as np
import pytest

from skynav.calibration.errors import IdentificationError
from skynav.calibration.radiometric import calibrate_radiometric
from skynav.calibration.virtual_bench import scenario, uncalibrated_error_arcsec
from skynav.calibration.bench_files import calibrate_geometric, simulate

from .conftest import true_error_arcsec


def test_patterns_json_has_the_issue_schema(small_facility, small_patterns):
    from skynav.datasets.frame_files import read_png

    doc = json.loads((small_patterns / "patterns.json").read_text())
    assert doc["schema"] == "skynav.patterns/2"
    assert doc["screen"] == {"width_px": 640, "height_px": 640, "bit_depth": 10}
    dots = [p for p in doc["patterns"] if p["dots"]]
    assert len(dots) == 9 and all(set(p) >= {"file", "dots"} for p in doc["patterns"])
    img = read_png(small_patterns / dots[0]["file"])
    assert img.shape == (640, 640) and img.dtype == np.uint16
    x, y = (int(v) for v in dots[0]["dots"][len(dots[0]["dots"]) // 2])
    assert img[y, x] == img.max()  # dot centres in CONVENTIONS pixel coordinates


def test_realistic_bench_calibrates(small_facility, small_patterns, small_captures):
    truth = scenario("realistic", small_facility)
    assert uncalibrated_error_arcsec(small_facility, truth) >= 500
    res = calibrate_geometric(small_facility, small_patterns, small_captures)
    s = res.summary()
    # 0.5 arcsec at 1024 px is 0.002 camera px; here one camera pixel is 281 arcsec
    assert s["p99"] < 0.02 * 281 and s["max"] < 0.05 * 281
    assert np.percentile(true_error_arcsec(small_facility, res.facility, truth), 99) < 0.015 * 281
    assert res.facility.flat_field is not None
    ff = res.facility.flat_field
    assert 0.7 < min(min(r) for r in ff.relative) < 0.95  # the virtual collimator vignettes
    assert res.seconds < 30


@pytest.mark.parametrize("name", ["shifted", "roll90"])
def test_displaced_or_rolled_bench_calibrates_correctly(tmp_path, small_facility, small_patterns, name):
    truth = scenario(name, small_facility)
    simulate(small_facility, small_patterns, tmp_path, scenario_name=name, frames=2)
    try:
        res = calibrate_geometric(small_facility, small_patterns, tmp_path)
    except IdentificationError:  # refusing is acceptable; slipping is not
        return
    assert np.percentile(true_error_arcsec(small_facility, res.facility, truth), 99) < 0.02 * 281


def test_radiometric_fit_recovers_the_virtual_screen(small_facility, small_captures):
    res = calibrate_radiometric(small_facility, small_captures / "power_meter.csv")
    truth = scenario("realistic", small_facility)
    assert abs(res.facility.radiometric.gamma - truth.gamma) < 0.02
    assert res.rms_relative < 0.01
    lo, hi = res.usable_v_mag
    assert hi < lo and lo > 6.0  # stars to beyond V = 6 are displayable


def test_hot_pixels_a_cosmic_ray_and_missing_dots_do_not_slip(tmp_path, small_facility, small_patterns, small_captures):
    import shutil

    from skynav.datasets.frame_files import read_png, write_png

    cap = tmp_path / "cap"
    shutil.copytree(small_captures, cap)
    img = read_png(cap / "dots_00.png")
    rng = np.random.default_rng(3)
    img[rng.integers(5, 250, 25), rng.integers(5, 250, 25)] = 255  # hot pixels
    img[100, 60:80] = 200  # a cosmic-ray track
    img[120:140, 120:140] = img[0:20, 0:20]  # a few dots hidden
    write_png(cap / "dots_00.png", img, bit_depth=8)
    res = calibrate_geometric(small_facility, small_patterns, cap)
    truth = scenario("realistic", small_facility)
    assert np.percentile(true_error_arcsec(small_facility, res.facility, truth), 99) < 0.015 * 281
    assert res.summary()["max"] < 0.05 * 281
