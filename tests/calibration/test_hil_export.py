"""`skynav hil export`: a dataset as screen frames (PNG + JSON), resumable."""

import copy
import json

import numpy as np

from skynav.cli import main


def test_export_a_dataset_and_resume(tmp_path, capsys):
    from skynav import datasets
    from skynav.datasets.frame_files import read_png

    recipe = copy.deepcopy(datasets.preset_recipe("scenes"))
    recipe["scenes"] = recipe["scenes"][1:]
    recipe["formats"] = ["png", "json"]
    from skynav.scenes.facility import screen_small_preset

    recipe["camera"] = screen_small_preset().camera.to_dict()  # the bench's camera (export refuses another)
    datasets.generate(recipe, tmp_path / "ds", workers=1, progress=False)
    out = tmp_path / "hil"
    assert main(["hil", "export", str(tmp_path / "ds"), "--facility", "screen_small", "-o", str(out), "-q"]) == 0
    png = read_png(out / "frames" / "000000.png")
    assert png.shape == (640, 640) and png.dtype == np.uint16 and png.max() > 0
    rec = json.loads((out / "frames" / "000000.json").read_text())
    assert rec["schema"] == "skynav.hil_frame/2" and rec["source"]["frame"] == 0
    star = max(rec["stars"], key=lambda s: s["electrons"])
    assert set(star) >= {"screen_xy", "electrons", "peak_dn"} and star["peak_dn"] > 0
    assert set(rec["clipped"]) == {"too_bright_px", "too_faint_sources"}
    capsys.readouterr()
    assert main(["hil", "export", str(tmp_path / "ds"), "--facility", "screen_small", "-o", str(out)]) == 0
    assert "1 already there" in capsys.readouterr().out
