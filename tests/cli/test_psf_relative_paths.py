"""PSF files named with relative paths in a scene file, a recipe or a facility file are found
beside that file, whatever the working directory; the truth and the manifest record the resolved
absolute path and the tables' sha256.

Each test runs from another folder that holds a *different* ``psf.npy`` (a decoy), so a path read
from the working directory would draw the wrong PSF and be caught by its sha256.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from skynav.cli import main
from skynav.scenes.psf_measured import TabulatedPSFModel

SMALL = ["--set", "camera.width=128", "--set", "camera.height=128", "--set", "render.cosmic_rays_per_frame=0"]


def _psf(path, sigma):
    u = (np.arange(33) - 16) / 4.0
    np.save(path, np.exp(-0.5 * (u[None, :] ** 2 + u[:, None] ** 2) / sigma**2))
    return str(path)


@pytest.fixture
def lab(tmp_path, monkeypatch):
    """``lab/`` with psf.npy (and a 2 x 2 grid of them), ``elsewhere/`` (the working directory)
    with a decoy psf.npy."""
    (tmp_path / "lab" / "psfs").mkdir(parents=True)
    (tmp_path / "elsewhere").mkdir()
    real = _psf(tmp_path / "lab" / "psf.npy", 0.7)
    for i in range(4):
        _psf(tmp_path / "lab" / "psfs" / f"p{i}.npy", 0.6 + 0.1 * i)
    _psf(tmp_path / "elsewhere" / "psf.npy", 1.5)
    monkeypatch.chdir(tmp_path / "elsewhere")
    return tmp_path / "lab", TabulatedPSFModel(file=real, oversampling=4)


def test_scene_file_psf_is_read_beside_the_scene_file(lab, capsys):
    folder, real = lab
    (folder / "scene.yaml").write_text(
        'epoch: "2027-02-01T00:00:00"\n'
        "observer: {position_km: [-128731399.4, 113269566.7, 51647643.2], velocity_km_s: [-19.9093, -18.773, -8.1391]}\n"
        "attitude: {point_at: mars}\n"
        "camera: {preset: paper, psf: {model: tabulated, file: psf.npy, oversampling: 4}}\n")
    assert main(["render", "../lab/scene.yaml", "-o", "out", "--no-noise", "-q", *SMALL]) == 0
    psf = json.loads((folder.parent / "elsewhere" / "out" / "frame.json").read_text())["camera"]["psf"]
    assert psf["file"] == str(folder / "psf.npy") and psf["sha256"] == real.sha256


def test_recipe_field_grid_is_read_beside_the_recipe_and_recorded_in_the_manifest(lab, capsys):
    folder, _ = lab
    grid = ", ".join(f"{{x_px: {x}, y_px: {y}, file: psfs/p{2 * i + j}.npy}}"
                     for i, x in enumerate((0, 127)) for j, y in enumerate((0, 127)))
    (folder / "recipe.yaml").write_text(
        "kind: montecarlo\nframes: 1\nseed: 3\nformats: [json]\n"
        f"camera: {{preset: paper, width: 128, height: 128, psf: {{model: tabulated, oversampling: 4, field: [{grid}]}}}}\n")
    assert main(["dataset", "generate", "../lab/recipe.yaml", "-o", "ds", "-q"]) == 0
    ds = folder.parent / "elsewhere" / "ds"
    manifest = json.loads((ds / "manifest.json").read_text())
    files = sorted(p["file"] for p in manifest["recipe"]["camera"]["psf"]["field"])
    assert files == [str(folder / "psfs" / f"p{i}.npy") for i in range(4)]
    truth = json.loads(next((ds / "frames").glob("*.json")).read_text())
    assert sorted(p["file"] for p in truth["camera"]["psf"]["field"]) == files and truth["camera"]["psf"]["sha256"]


def test_facility_file_psf_is_read_beside_the_facility_file(lab):
    import dataclasses

    from skynav.calibration.facility_io import load_facility, write_facility
    from skynav.scenes.facility import screen_small_preset

    folder, real = lab
    f = screen_small_preset()
    f = dataclasses.replace(f, camera=f.camera.replace(psf=real))
    path = write_facility(f, folder / "facility.yaml")
    text = path.read_text()
    assert str(folder / "psf.npy") in text
    path.write_text(text.replace(str(folder / "psf.npy"), "psf.npy"))  # as a lab writes it by hand
    got = load_facility("../lab/facility.yaml").camera.psf
    assert got.file == str(folder / "psf.npy") and got.sha256 == real.sha256
