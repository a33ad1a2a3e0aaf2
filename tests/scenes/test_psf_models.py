"""PSF models as camera values: equality, hash, pickle, repr, dict round trips, errors for people."""

import pickle

import numpy as np
import pytest

from skynav.infra.errors import ConfigValueError
from skynav.scenes.camera import Camera, paper_camera
from skynav.scenes.config import camera_from_mapping
from skynav.scenes.psf import AiryPSFModel, GaussianPSFModel, OpticalPSFModel  # noqa: F401 (eval)
from skynav.scenes.psf_measured import FieldPSF, TabulatedPSFModel, psf_from_dict  # noqa: F401 (eval)


def _models(tmp_path):
    a = np.zeros((9, 9))
    a[4, 4], a[4, 5] = 3.0, 1.0
    np.save(tmp_path / "p.npy", a)
    for x in (0.0, 50.0):
        for y in (0.0, 40.0):
            np.save(tmp_path / f"g{x}_{y}.npy", a * (1 + x + y))
    field = [{"x_px": x, "y_px": y, "file": str(tmp_path / f"g{x}_{y}.npy")} for x in (0.0, 50.0) for y in (0.0, 40.0)]
    return [
        GaussianPSFModel(0.5),
        AiryPSFModel(obscuration=0.25),
        AiryPSFModel(obscuration=0.0, wavelength_nm=600.0),
        OpticalPSFModel(obscuration=0.1, wavelength_nm=550.0, zernike_waves={4: 0.5, 7: 0.1}),
        TabulatedPSFModel(file=str(tmp_path / "p.npy"), oversampling=2),
        psf_from_dict({"model": "tabulated", "field": field, "oversampling": 2}),
    ]


def test_models_are_values_and_round_trip_through_dicts(tmp_path):
    models = _models(tmp_path)
    for m in models:
        assert pickle.loads(pickle.dumps(m)) == m
        assert eval(repr(m)) == m and hash(eval(repr(m))) == hash(m)
        assert psf_from_dict(m.to_dict()) == m
        cam = paper_camera(psf=m)
        assert Camera.from_dict(cam.to_dict()) == cam and pickle.loads(pickle.dumps(cam)) == cam
        assert camera_from_mapping({"preset": "paper", "psf": m.to_dict()}) == cam
    assert len(set(models)) == len(models)
    t = models[4]
    assert abs(t.tables[0].sum() - 1.0) < 1e-15  # normalised on load


def test_defocus_sigma_px_stays_the_shorthand_of_the_gaussian():
    cam = paper_camera()
    assert cam.psf == GaussianPSFModel(0.5) and cam.to_dict()["psf"] == {"model": "gaussian", "sigma_px": 0.5}
    c2 = cam.replace(defocus_sigma_px=0.8)
    assert c2.psf == GaussianPSFModel(0.8)
    assert paper_camera(psf={"model": "gaussian", "sigma_px": 0.3}).defocus_sigma_px == 0.3
    airy = cam.replace(psf=AiryPSFModel())
    assert airy.replace(defocus_sigma_px=0.7).psf == GaussianPSFModel(0.7)  # the shorthand wins when given alone
    # a frame/1 camera record (no psf key) reads as the Gaussian of its defocus_sigma_px
    d = cam.to_dict()
    del d["psf"]
    assert Camera.from_dict(d) == cam


def test_changed_psf_file_is_refused_by_its_sha256(tmp_path):
    m = _models(tmp_path)[4]
    d = m.to_dict()
    np.save(tmp_path / "p.npy", np.ones((5, 5)))
    with pytest.raises(ConfigValueError, match=r"camera\.psf\.sha256 = .*\(a PSF file has changed\)"):
        psf_from_dict(d)


@pytest.mark.parametrize("bad, key", [
    ({"model": "moffat"}, r"camera\.psf\.model = 'moffat'.*gaussian, airy, optical, tabulated"),
    ({"model": "airy", "obscuration": 1.2}, r"camera\.psf\.obscuration = 1\.2"),
    ({"model": "airy", "sigma_px": 1.0}, r"camera\.psf\.sigma_px = 1\.0 .*no such key for model airy"),
    ({"model": "optical", "zernike_waves": {4: 0.5}}, r"camera\.psf\.wavelength_nm = None.*monochromatic.*model airy without wavelength_nm"),
    ({"model": "optical", "wavelength_nm": 550, "zernike_waves": {40: 0.5}}, r"camera\.psf\.zernike_waves = 40"),
    ({"model": "optical", "wavelength_nm": 550, "zernike_waves": {4: "big"}}, r"camera\.psf\.zernike_waves\.4"),
    ({"model": "tabulated", "file": "/nonexistent/psf.npy", "oversampling": 4}, r"camera\.psf\.file = '/nonexistent/psf\.npy'"),
    ({"model": "tabulated", "file": "psf.png", "oversampling": 4}, r"a \.npy or \.fits file"),
    ({"model": "tabulated", "file": "x.npy", "oversampling": 0}, r"camera\.psf\.oversampling = 0"),
    ({"model": "gaussian", "sigma_px": -1}, r"camera\.psf\.sigma_px = -1"),
    ("airy", r"camera\.psf = 'airy'"),
])
def test_bad_psf_keys_are_one_line_naming_the_key(bad, key):
    with pytest.raises(ConfigValueError, match=key):
        camera_from_mapping({"preset": "paper", "psf": bad})


def test_field_grid_must_be_rectangular(tmp_path):
    np.save(tmp_path / "a.npy", np.ones((5, 5)))
    f = str(tmp_path / "a.npy")
    pts = [{"x_px": 0, "y_px": 0, "file": f}, {"x_px": 10, "y_px": 0, "file": f}, {"x_px": 0, "y_px": 10, "file": f}]
    with pytest.raises(ConfigValueError, match=r"camera\.psf\.field = '3 points'.*rectangular grid"):
        psf_from_dict({"model": "tabulated", "field": pts, "oversampling": 1})
    with pytest.raises(ConfigValueError, match=r"camera\.defocus_sigma_px = 0\.7.*psf\.sigma_px"):
        camera_from_mapping({"preset": "paper", "defocus_sigma_px": 0.7, "psf": {"model": "gaussian", "sigma_px": 0.5}})


def test_airy_extent_follows_the_encircled_energy_tail():
    """Half size for a flux fraction from the tail 2 lambda F / (pi^2 r), capped at 16: the flux
    outside the circle of radius h - 1/2 (inside the stamp whatever the phase), by Rayleigh's
    closed form 1 - EE = J0(v)^2 + J1(v)^2 (Born & Wolf 8.5.2), is below the fraction asked."""
    from scipy.special import j0, j1

    cam = Camera(width=64, height=64, focal_length_mm=100.0, pixel_pitch_um=5.0, f_number=20.0)
    m = AiryPSFModel(wavelength_nm=550.0)
    lf = 2.2
    for f in (0.05, 0.02, 0.01):
        h = m.half_size_px(f, cam)
        v = np.pi * (h - 0.5) / lf
        if h < 16:
            assert j0(v) ** 2 + j1(v) ** 2 < f
    assert m.half_size_px(0.05, cam) == 10
    assert m.half_size_px(1e-6, cam) == 16
    assert AiryPSFModel(wavelength_nm=550.0, max_half_px=30).half_size_px(1e-6, cam) == 30
    assert GaussianPSFModel(0.5).half_size_px(1e-6) == 3
