"""`skynav render --fits`: the FITS file verifies with astropy.io.fits and carries the standard
keywords a FITS user expects, with the values of the ground truth and the camera.

References: FITS standard 4.0 (section 4.4.2, 9: DATE-OBS, MJD-OBS, TIMESYS, EXPTIME, BUNIT,
INSTRUME, TELESCOP); Rots et al. (2015), A&A 574, A36 (DATE-AVG, DATE-END)."""

import math
import warnings

import numpy as np
import pytest

from skynav.cli import main


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    from skynav.datasets.fits_files import read_fits
    from skynav.datasets.truth_schema import read_truth_json

    out = tmp_path_factory.mktemp("fits")
    assert main(["render", "-o", str(out), "--backend", "numpy", "--fits"]) == 0
    truth = read_truth_json(out / "frame.json")
    data, header = read_fits(out / "frame.fits")
    return out / "frame.fits", truth, data, header


def test_fits_file_verifies(rendered):
    from astropy.io import fits

    path, *_ = rendered
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with fits.open(path) as hdul:
            hdul.verify("exception")


def test_time_keywords_are_the_truth_epoch_in_utc(rendered):
    from astropy.time import Time

    _, truth, _, h = rendered
    exptime = truth["camera"]["exposure_s"]
    assert h["TIMESYS"] == "UTC" and h["EXPTIME"] == exptime
    # the truth's mid-exposure epoch, from its ISO TDB string (not the seconds the writer used)
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*dubious year.*")  # a future epoch: no leap second assumed
        mid = Time(truth["epoch"]["tdb_iso"], scale="tdb").utc
        avg = Time(h["DATE-AVG"], scale="utc")
        obs = Time(h["DATE-OBS"], scale="utc")
        end = Time(h["DATE-END"], scale="utc")
        # 1 us: the ISO strings carry microseconds
        assert abs((avg - mid).to_value("s")) < 1e-6
        assert abs((mid - obs).to_value("s") - exptime / 2) < 1e-6
        assert abs((end - mid).to_value("s") - exptime / 2) < 1e-6
        # MJD-OBS is DATE-OBS: float64 MJD resolves ~1 us
        assert abs((Time(h["MJD-OBS"], format="mjd", scale="utc") - obs).to_value("s")) < 5e-6
        assert abs((Time(h["MJD-AVG"], format="mjd", scale="utc") - avg).to_value("s")) < 5e-6
        assert abs((Time(h["MJD-END"], format="mjd", scale="utc") - end).to_value("s")) < 5e-6
    # without astropy's UTC: TDB - UTC = (TDB - TT) + 32.184 s + (TAI - UTC = 37 s since 2017-01-01),
    # |TDB - TT| < 1.7 ms (Fairhead & Bretagnon 1990)
    jd_tdb = truth["epoch"]["jd_tdb"]
    assert jd_tdb > 2457754.5  # 2017-01-01: the last leap second so far
    utc_jd_mid = jd_tdb - (32.184 + 37.0) / 86400.0
    mjd_avg = utc_jd_mid - 2400000.5
    assert abs(h["MJD-AVG"] - mjd_avg) * 86400.0 < 2e-3


def test_camera_keywords_are_the_camera(rendered):
    from astropy import units as u

    from skynav.scenes.camera import Camera

    _, truth, data, h = rendered
    cam = Camera.from_dict(truth["camera"])
    sp = cam.sensor
    assert u.Unit(h["BUNIT"], format="fits") == u.adu
    assert h["INSTRUME"] and h["TELESCOP"]
    assert math.isclose(h["GAIN"] * sp.gain_dn_per_e, 1.0, rel_tol=1e-15)  # e-/DN, 16 digits in the card
    assert h["RDNOISE"] == sp.read_noise_e
    # saturation: the full well read out, within the DN range
    assert h["SATURATE"] == min(sp.max_dn, math.floor(sp.full_well_e * sp.gain_dn_per_e + sp.offset_dn + 0.5))
    assert int(data.max()) <= h["SATURATE"]
    assert h["BITDEPTH"] == sp.bit_depth


def test_observer_state_is_the_truths(rendered):
    _, truth, _, h = rendered
    assert h["OBSFRAME"] == "ICRS"
    pos = [h[f"OBSPOS-{a}"] for a in "XYZ"]
    vel = [h[f"OBSVEL-{a}"] for a in "XYZ"]
    # a FITS card holds 16-17 significant digits: exact for these values, 1 mm / 1 um/s bounds
    np.testing.assert_allclose(pos, truth["observer"]["position_km"], rtol=0, atol=1e-6)
    np.testing.assert_allclose(vel, truth["observer"]["velocity_km_s"], rtol=0, atol=1e-9)


def test_wcs_still_verifies_and_places_the_stars(rendered):
    from astropy.coordinates import SkyCoord
    from astropy.wcs import WCS

    _, truth, _, h = rendered
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no FITSFixedWarning from the time keywords
        w = WCS(h)
    u = np.array([s["u_icrs"] for s in truth["stars"]][:20])
    xy = np.array([s["xy"] for s in truth["stars"]][:20])
    sky = SkyCoord(x=u[:, 0], y=u[:, 1], z=u[:, 2], representation_type="cartesian", frame="icrs")
    px, py = w.world_to_pixel(sky)
    # the default camera has no distortion: TAN is exact, float round-off only
    assert np.max(np.hypot(px - xy[:, 0], py - xy[:, 1])) < 1e-6
