"""FITS with lens distortion: the TAN-SIP WCS puts the truth's stars on their pixels through
astropy alone, on the file `skynav render --fits` writes.

The truth is the renderer's own projection (apparent direction, then Brown-Conrady, then ``K``);
astropy.wcs (WCSLIB's SIP) knows nothing of skynav, so agreement within 0.01 px checks the
header, its polynomials and the 1-based pixel convention (FITS pixel = skynav pixel + 1;
astropy's 0-based pixels are skynav's) together.
"""

import warnings

import numpy as np
import pytest

from skynav.cli import main
from skynav.scenes.camera import paper_camera
from skynav.scenes.distortion import BrownConrady


def _render(out, distortion):
    from skynav.datasets.fits_files import read_fits
    from skynav.datasets.truth_schema import read_truth_json

    args = ["render", "-o", str(out), "--backend", "numpy", "--fits"]
    if distortion:
        args += ["--set", f"camera.distortion={distortion}"]
    assert main(args) == 0
    return read_truth_json(out / "frame.json"), read_fits(out / "frame.fits")[1], out / "frame.fits"


def _astropy_pixels(path, truth):
    from astropy.coordinates import SkyCoord
    from astropy.io import fits
    from astropy.wcs import WCS

    with warnings.catch_warnings():
        warnings.simplefilter("error")  # astropy reads the SIP header without a warning
        with fits.open(path) as hdul:
            w = WCS(hdul[0].header)
    u = np.array([s["u_icrs"] for s in truth["stars"]])
    xy = np.array([s["xy"] for s in truth["stars"]])
    sky = SkyCoord(x=u[:, 0], y=u[:, 1], z=u[:, 2], representation_type="cartesian", frame="icrs")
    ra, dec = sky.spherical.lon.deg, sky.spherical.lat.deg
    # astropy's pixels are 0-based (origin 0): skynav's pixel centres, FITS pixel - 1
    px = w.all_world2pix(np.stack([ra, dec], axis=1), 0, tolerance=1e-8, maxiter=50)
    return w, px, xy


@pytest.mark.parametrize("distortion", ["{k1: -0.2}", "{k1: 0.05, k2: -0.02, p1: 1e-3, p2: -5e-4}"])
def test_astropy_puts_every_truth_star_within_0_01_px(tmp_path, distortion):
    truth, header, path = _render(tmp_path, distortion)
    assert header["CTYPE1"] == "RA---TAN-SIP" and header["CTYPE2"] == "DEC--TAN-SIP"
    w, px, xy = _astropy_pixels(path, truth)
    assert w.sip is not None and len(xy) > 10
    err = np.hypot(px[:, 0] - xy[:, 0], px[:, 1] - xy[:, 1])
    assert np.max(err) <= 0.01, f"max {np.max(err):.4g} px"
    # the fit's own residual is in the header and within the acceptance
    assert 0 <= header["SIPMXERR"] <= 0.01 and 0 <= header["SIPIMXER"] <= 0.01
    # and pixel to sky: the truth pixel maps back to the star's direction (0.01 px of the
    # plate scale, ~ 0.01 * |CD| deg)
    radec = w.all_pix2world(xy, 0)
    u = np.array([s["u_icrs"] for s in truth["stars"]])
    ra, dec = np.radians(radec[:, 0]), np.radians(radec[:, 1])
    back = np.stack([np.cos(dec) * np.cos(ra), np.cos(dec) * np.sin(ra), np.sin(dec)], axis=1)
    scale_rad = np.radians(np.sqrt(abs(np.linalg.det(w.wcs.cd))))
    assert np.max(np.arccos(np.clip(np.sum(back * u, axis=1), -1, 1))) <= 0.01 * scale_rad


def test_without_distortion_the_wcs_stays_plain_tan(tmp_path):
    truth, header, path = _render(tmp_path, None)
    assert header["CTYPE1"] == "RA---TAN" and "A_ORDER" not in header
    _, px, xy = _astropy_pixels(path, truth)
    assert np.max(np.hypot(px[:, 0] - xy[:, 0], px[:, 1] - xy[:, 1])) < 1e-6


@pytest.mark.parametrize("k1", [-0.2, -0.05, 0.1])
def test_sip_fit_residual_over_the_whole_sensor(k1):
    """The polynomials against the exact Brown-Conrady maps at every sensor corner and edge,
    on a grid other than the fit's and the check's (pixel centres, 1-px step along the edges)."""
    from skynav.datasets.fits_sip import sip_fit

    cam = paper_camera(distortion=BrownConrady(k1=k1))
    order, fwd, inv, err_f, err_i = sip_fit(cam)
    assert 2 <= order <= 9 and max(err_f, err_i) <= 0.01
    W, H = cam.width, cam.height
    edge = np.concatenate([np.stack([np.arange(W), np.zeros(W)], 1), np.stack([np.arange(W), np.full(W, H - 1)], 1),
                           np.stack([np.zeros(H), np.arange(H)], 1), np.stack([np.full(H, W - 1), np.arange(H)], 1)])
    v_cam = cam.back_project(edge)  # exact: Newton through the distortion
    ideal = cam.project(v_cam, distort=False)
    cx, cy = cam.K[0, 2], cam.K[1, 2]
    u, v = edge[:, 0] - cx, edge[:, 1] - cy
    a = sum(c[0] * u ** p * v ** q for (p, q), c in fwd.items())
    b = sum(c[1] * u ** p * v ** q for (p, q), c in fwd.items())
    assert np.max(np.hypot(u + a - (ideal[:, 0] - cx), v + b - (ideal[:, 1] - cy))) <= 0.01


def test_a_dataset_of_a_distorting_camera_writes_tan_sip(tmp_path):
    import skynav.datasets as D
    from skynav.datasets.truth_schema import read_truth_json

    rec = D.preset_recipe("sequence")
    rec["frames"] = 1
    rec["formats"] = ["png", "json", "fits"]
    rec["camera"] = {"preset": "paper", "width": 256, "height": 256, "fov_deg": 20.0, "distortion": {"k1": -0.2}}
    rec["catalog_limiting_v_mag"] = 7.0
    D.generate(rec, tmp_path / "ds", workers=1, progress=False)
    truth = read_truth_json(tmp_path / "ds" / "frames" / "000000.json")
    _, px, xy = _astropy_pixels(tmp_path / "ds" / "frames" / "000000.fits", truth)
    assert len(xy) > 10 and np.max(np.hypot(px[:, 0] - xy[:, 0], px[:, 1] - xy[:, 1])) <= 0.01
