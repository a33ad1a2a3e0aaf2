"""`skynav hil export` runs like `dataset generate`: checksum records, a resume that redoes
damaged or interrupted frames and keeps the rest byte for byte, one export per folder, and the
same bytes from every executor (in-process, spawned processes, a Dask cluster)."""

from __future__ import annotations

import json

import pytest

from skynav.cli import main


@pytest.fixture(scope="module")
def source(tmp_path_factory):
    from skynav import datasets

    recipe = datasets.preset_recipe("montecarlo")
    recipe["frames"] = 3
    recipe["formats"] = ["png", "json"]
    from skynav.scenes.facility import screen_small_preset

    recipe["camera"] = screen_small_preset().camera.to_dict()  # the bench's camera (export refuses another)
    root = tmp_path_factory.mktemp("hilsrc") / "ds"
    datasets.generate(recipe, root, workers=1, progress=False)
    return root


@pytest.fixture(scope="module")
def reference(source, tmp_path_factory):
    from skynav.calibration.facility_io import load_facility
    from skynav.datasets.hil_export import export_dataset

    out = tmp_path_factory.mktemp("hilref") / "screen"
    s = export_dataset(load_facility("screen_small"), source, out)
    assert s == {"frames": 3, "exported": 3, "skipped": 0, "workers": 1, "executor": "in-process"}
    return out


def _bytes(folder):
    return {p.name: p.read_bytes() for p in sorted((folder / "frames").iterdir()) if not p.name.startswith(".")}


def test_export_writes_records_and_a_complete_manifest(reference):
    from skynav.datasets.journal import frame_problem

    for k in range(3):
        assert frame_problem(reference, k, ("png", "json"))[0] is None
    m = json.loads((reference / "export.json").read_text())
    assert m["complete"] is True and m["schema"] == "skynav.hil_export/2"
    assert m["facility"]["name"] == "screen_small" and len(m["facility"]["sha256"]) == 64
    assert sorted(m["checksums"]) == sorted(f"frames/{k:06d}.{e}" for k in range(3) for e in ("png", "json", "sha256"))


def test_resume_redoes_damaged_and_interrupted_frames_only(source, reference, tmp_path):
    import shutil

    from skynav.calibration.facility_io import load_facility
    from skynav.datasets.hil_export import export_dataset

    out = tmp_path / "screen"
    shutil.copytree(reference, out)
    png1 = out / "frames" / "000001.png"
    png1.write_bytes(png1.read_bytes()[:100])          # a truncated file (a crash, a full disk)
    (out / "frames" / "000002.sha256").unlink()        # a frame whose commit point never came
    kept = (out / "frames" / "000000.png").stat().st_mtime_ns
    s = export_dataset(load_facility("screen_small"), source, out)
    assert (s["exported"], s["skipped"]) == (2, 1)
    assert (out / "frames" / "000000.png").stat().st_mtime_ns == kept
    assert _bytes(out) == _bytes(reference)


def test_spawned_processes_and_dask_give_the_same_bytes(source, reference, tmp_path):
    distributed = pytest.importorskip("distributed")
    from skynav.calibration.facility_io import load_facility
    from skynav.datasets.hil_export import export_dataset

    fac = load_facility("screen_small")
    s = export_dataset(fac, source, tmp_path / "pool", workers=2)
    assert s["executor"] == "processes (spawn)" and s["exported"] == 3
    assert _bytes(tmp_path / "pool") == _bytes(reference)
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
        with distributed.Client(cluster) as client:
            s = export_dataset(fac, source, tmp_path / "dask", client=client)
    assert s["executor"] == "dask" and s["exported"] == 3
    assert _bytes(tmp_path / "dask") == _bytes(reference)


def test_a_folder_holding_another_facilitys_export_is_refused(source, reference, tmp_path, capsys):
    import shutil

    out = tmp_path / "screen"
    shutil.copytree(reference, out)
    capsys.readouterr()
    assert main(["hil", "export", str(source), "--facility", "screen_small", "--set", "screen.bit_depth=8", "-o", str(out),
                 "-q"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "another facility" in err[0] and "Traceback" not in err[0]


def test_an_export_of_format_1_is_not_resumed(source, reference, tmp_path, capsys):
    """Version 1 stored the screen DN unscaled: resuming into it would mix two PNG layouts."""
    import shutil

    out = tmp_path / "screen"
    shutil.copytree(reference, out)
    m = json.loads((out / "export.json").read_text())
    m["schema"] = "skynav.hil_export/1"
    for key in ("png_scaling", "significant_bits"):
        m.pop(key)
    (out / "export.json").write_text(json.dumps(m))
    capsys.readouterr()
    assert main(["hil", "export", str(source), "--facility", "screen_small", "-o", str(out), "-q"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "another file format" in err[0]


def test_screen_frames_give_the_same_dn_in_both_layouts(reference, tmp_path):
    """The closed loop and every other reader see the same screen DN in a 0.3.0-style export
    (unscaled PNGs with sBIT, no marker) as in this one."""
    import numpy as np
    from PIL import Image, PngImagePlugin

    from skynav.datasets.frame_files import read_png

    for k in range(3):
        png = reference / "frames" / f"{k:06d}.png"
        m = json.loads((reference / "frames" / f"{k:06d}.json").read_text())
        assert m["png_scaling"] == "sbit"
        dn = read_png(png)
        assert int(dn.max()) <= (1 << m["significant_bits"]) - 1
        info = PngImagePlugin.PngInfo()
        info.add(b"sBIT", bytes([m["significant_bits"]]))
        Image.fromarray(dn).save(tmp_path / "old.png", pnginfo=info)
        np.testing.assert_array_equal(read_png(tmp_path / "old.png"), dn)
        with Image.open(png) as im:  # what a viewer sees: the full 16-bit range, not <= 1023
            assert np.array(im).max() > 1023 or dn.max() == 0
