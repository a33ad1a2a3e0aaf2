"""The quick look: ``render --preview`` and ``dataset preview`` show a stretched image, the frame's
own PNG keeps its physical DN.

A star field's PNG is a sky at the black level with a few bright points (a viewer shows it black);
the quick look puts the sky at a visible dark grey and the faint stars well above it.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from PIL import Image

from skynav import datasets
from skynav.__main__ import main
from skynav.datasets.frame_files import read_png
from skynav.datasets.quicklook import display_limits, quicklook_u8


def _u8(path) -> np.ndarray:
    with Image.open(path) as im:
        return np.asarray(im.convert("L"))


def test_render_preview_is_stretched_beside_the_physical_png(tmp_path, capsys):
    out = tmp_path / "r"
    assert main(["render", "-o", str(out), "--preview", "--set", "camera.width=256", "--set", "camera.height=256"]) == 0
    assert f"preview {out / 'frame_preview.png'}" in capsys.readouterr().out
    physical, preview = _u8(out / "frame.png"), _u8(out / "frame_preview.png")
    dn = read_png(out / "frame.png")
    assert np.array_equal(physical, dn)  # the 8-bit frame's PNG is its DN, untouched by --preview
    assert np.median(physical) < 5 and np.median(preview) > 25  # the sky: black there, dark grey here
    truth = json.loads((out / "frame.json").read_text())
    faint = [s for s in truth["stars"] if 6.0 < s["v_mag"] < 7.0]
    assert faint
    peaks = [int(preview[int(round(s["xy"][1])), int(round(s["xy"][0]))]) for s in faint]
    sky = np.median(preview)
    assert np.median(peaks) > sky + 40, (peaks, sky)  # faint stars stand out of the sky


def test_render_preview_of_a_screen_frame(tmp_path, capsys):
    from skynav.scenes.facility import PRESETS

    small = next(n for n in PRESETS if n.endswith("_small"))
    out = tmp_path / "s"
    assert main(["render", "--facility", small, "-o", str(out), "--preview", "-q"]) == 0
    capsys.readouterr()
    assert sorted(p.name for p in out.iterdir()) == ["frame.json", "frame.png", "frame_preview.png"]
    assert np.median(_u8(out / "frame_preview.png")) > np.median(read_png(out / "frame.png"))


def test_dataset_preview_tiles_are_stretched(tmp_path, capsys):
    recipe = datasets.preset_recipe("montecarlo")
    recipe.update(frames=2, formats=["png", "json"], camera={"preset": "paper", "width": 128, "height": 128})
    datasets.generate(recipe, tmp_path / "ds", workers=1, progress=False)
    sheet = tmp_path / "sheet.png"
    assert main(["dataset", "preview", str(tmp_path / "ds"), "-o", str(sheet), "--columns", "2"]) == 0
    said = capsys.readouterr().out
    assert "quick look" in said and "circles" in said and str(sheet) in said
    tile = _u8(sheet)[4 + 20:4 + 256 - 20, 4 + 20:4 + 256 - 20]  # inside the first tile, below its label
    assert np.median(tile) > 25  # the sky a dark grey, not black
    assert np.median(datasets.open(tmp_path / "ds")[0].dn) < 5


def test_noisy_sky_gets_the_zscale_limits():
    """A sky with noise of several DN: the limits are astropy's zscale ones, and the sky sits in
    the grey, not at either end."""
    from astropy.visualization import ZScaleInterval

    rng = np.random.default_rng(3)
    dn = rng.poisson(400.0, (200, 200)).astype(np.uint16)
    dn[100, 100] = 4000
    assert display_limits(dn.ravel()) == pytest.approx(ZScaleInterval().get_limits(dn.astype(float)))
    q = quicklook_u8(dn)
    assert 60 < np.median(q) < 220 and q[100, 100] == 255


def test_a_flat_image_is_black_and_a_quantised_sky_is_dark_grey():
    assert quicklook_u8(np.full((8, 8), 7, np.uint8)).max() == 0
    dn = np.full((100, 100), 2, np.uint8)
    dn[10, 10], dn[20, 20], dn[30, 30] = 3, 5, 200
    q = quicklook_u8(dn)
    assert 20 < np.median(q) < q[10, 10] < q[20, 20] < q[30, 30] == 255


def test_dataset_preview_never_writes_into_the_dataset(tmp_path, monkeypatch, capsys):
    import hashlib

    recipe = datasets.preset_recipe("montecarlo")
    recipe.update(frames=1, formats=["png", "json"], camera={"preset": "paper", "width": 64, "height": 64})
    datasets.generate(recipe, tmp_path / "mc", workers=1, progress=False)

    def tree():
        return {p.relative_to(tmp_path / "mc").as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
                for p in sorted((tmp_path / "mc").rglob("*")) if p.is_file()}

    before = tree()
    monkeypatch.chdir(tmp_path)
    assert main(["dataset", "preview", "mc"]) == 0
    assert "mc_preview.png" in capsys.readouterr().out
    assert (tmp_path / "mc_preview.png").is_file() and tree() == before
