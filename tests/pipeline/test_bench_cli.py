"""``skynav bench ip``: a tiny run writes the four report files with the fixed summary keys, and a
folder that is not a dataset, or frames without the needed keys, give one line and exit 2."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from skynav.cli import main

from .conftest import attitude_towards, render_observation


@pytest.fixture(scope="module")
def frame_folder(tmp_path_factory, paper_cam):
    """Two frames as a plain folder of PNG + JSON pairs (not a skynav dataset)."""
    from skynav.datasets.frame_files import write_png

    root = tmp_path_factory.mktemp("frames")
    for k, (ra, dec) in enumerate(((83.0, -5.0), (250.0, -20.0))):
        obs, truth = render_observation(R_cam_icrs=attitude_towards(ra, dec, 10.0), camera=paper_cam, seed=k)
        write_png(root / f"{k:06d}.png", np.asarray(obs.dn))
        (root / f"{k:06d}.json").write_text(json.dumps(truth))
    return root


def test_bench_ip_on_a_folder_of_frames(frame_folder, tmp_path, capsys):
    out = tmp_path / "rep"
    code = main(["bench", "ip", str(frame_folder), "--position-sigma-km", "1e4", "1e7", "-q", "-o", str(out)])
    assert code == 0
    for name in ("results.csv", "summary.json", "report.md", "report.html"):
        assert (out / name).stat().st_size > 0
    s = json.loads((out / "summary.json").read_text())
    assert s["frames"] == 2
    assert set(s["attitude"]) >= {"correct_rate", "wrong_rate", "none_rate", "error_arcsec_median", "error_arcsec_p90",
                                  "error_arcsec_1sigma"}
    assert s["attitude"]["correct_rate"] == 1.0
    assert set(s["beacon"]) == {"10000", "1e+07"}
    assert set(s["beacon"]["10000"]) >= {"correct_rate", "wrong_rate", "none_rate", "error_px_mean"}
    assert set(s["time_ms"]) == {"median", "p90"}
    html = (out / "report.html").read_text()
    assert html.count("data:image/png;base64,") >= 3 and "http" not in html.split("<body>")[1]
    # reproducible from the seed
    out2 = tmp_path / "rep2"
    main(["bench", "ip", str(frame_folder), "--position-sigma-km", "1e4", "1e7", "-q", "-o", str(out2)])
    a = [line.split(",")[:9] for line in (out / "results.csv").read_text().splitlines()]
    b = [line.split(",")[:9] for line in (out2 / "results.csv").read_text().splitlines()]
    assert a == b


def test_scores_are_frozen_dataclasses_and_the_csv_has_a_row_per_beacon(frame_folder, tmp_path):
    """Results are frozen dataclasses; ``results.csv`` writes one row per beacon of a run
    (one row for a run without beacons) with the beacon's name, outcome and error."""
    import csv
    import dataclasses

    from skynav.pipeline.scoring import BeaconScore, FrameScore, run_benchmark, summarise
    from skynav.pipeline.scoring_report import CSV_FIELDS, write_report

    rows, info = run_benchmark(frame_folder, sigmas_km=(1e4,), progress=False)
    assert all(isinstance(r, FrameScore) for r in rows) and len(rows) == 2
    assert all(isinstance(b, BeaconScore) for r in rows for b in r.beacons)
    with pytest.raises(dataclasses.FrozenInstanceError):
        rows[0].attitude = "wrong"
    summary = summarise(rows, frames=info["frames"], sigmas_km=(1e4,))
    out = write_report(tmp_path / "rep", rows, summary, sigmas_km=(1e4,), mode="improved", seed=0, source=frame_folder,
                       info={k: v for k, v in info.items() if k not in ("peer_rows", "peer_notes")})
    with open(tmp_path / "rep" / "results.csv", newline="", encoding="utf-8") as f:
        table = list(csv.DictReader(f))
    assert list(table[0]) == list(CSV_FIELDS) and out is not None
    assert len(table) == sum(max(1, len(r.beacons)) for r in rows)
    found = [(t["frame"], t["beacon_name"], t["beacon_outcome"]) for t in table if t["beacon_name"]]
    assert found == [(str(r.frame), b.name, b.outcome) for r in rows for b in r.beacons]


def test_not_a_dataset_and_missing_keys(frame_folder, tmp_path, capsys):
    empty = tmp_path / "empty"
    empty.mkdir()
    assert main(["bench", "ip", str(empty), "-o", str(tmp_path / "r")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "is not a dataset" in err
    assert main(["bench", "ip", str(tmp_path / "nope"), "-o", str(tmp_path / "r")]) == 2
    assert "no such folder" in capsys.readouterr().err
    bad = tmp_path / "bad"
    shutil.copytree(frame_folder, bad)
    d = json.loads((bad / "000000.json").read_text())
    del d["attitude"]
    (bad / "000000.json").write_text(json.dumps(d))
    assert main(["bench", "ip", str(bad), "-q", "-o", str(tmp_path / "r")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "attitude.R_cam_icrs" in err


@pytest.mark.slow
def test_report_html_in_headless_chromium(frame_folder, tmp_path):
    """report.html loads in a real browser with no console errors and shows the plots."""
    import importlib.util
    from pathlib import Path

    spec = importlib.util.spec_from_file_location(
        "check_report_html", Path(__file__).resolve().parents[2] / "benchmarks" / "check_report_html.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    if mod.chromium() is None:
        pytest.skip("no chromium on PATH (Debian: apt-get install chromium)")
    out = tmp_path / "rep"
    assert main(["bench", "ip", str(frame_folder), "--position-sigma-km", "1e4", "-q", "-o", str(out)]) == 0
    ok, msg = mod.check(out / "report.html", tmp_path / "shot.png")
    assert ok, msg


def test_peers_side_by_side(frame_folder, tmp_path):
    pytest.importorskip("tetra3rs")
    out = tmp_path / "rep"
    assert main(["bench", "ip", str(frame_folder), "--position-sigma-km", "1e4", "--peers", "-q", "-o", str(out)]) == 0
    s = json.loads((out / "summary.json").read_text())
    assert set(s["peers"]["tetra3rs"]) >= {"solved_rate", "error_arcsec_median", "time_ms_median"}
    assert "cedar-solve" in (out / "report.md").read_text()


def test_folder_frames_are_read_by_the_datasets_reader_with_the_jsons_camera(frame_folder, tmp_path):
    """A frame JSON holding only the schema's required camera keys (no sensor, no distortion):
    the observation's camera takes its pixel pitch, focal length and bit depth from the JSON
    (not an assumed pitch), and its K equals the JSON's K to rounding."""
    from skynav.pipeline.scoring import open_frames

    lean = tmp_path / "lean"
    shutil.copytree(frame_folder, lean)
    for js in sorted(lean.glob("*.json")):
        d = json.loads(js.read_text())
        d["camera"] = {k: d["camera"][k] for k in ("K", "width", "height", "focal_length_mm", "pixel_pitch_um",
                                                   "f_number", "exposure_s", "bit_depth")}
        d["epoch"] = {k: d["epoch"][k] for k in ("tdb_iso", "jd_tdb")}
        js.write_text(json.dumps(d))
    d = json.loads((lean / "000000.json").read_text())
    cam = open_frames(lean).observation(0).camera
    assert cam.pixel_pitch_um == d["camera"]["pixel_pitch_um"] != 10.0
    assert cam.sensor.bit_depth == d["camera"]["bit_depth"]
    np.testing.assert_allclose(cam.K, np.asarray(d["camera"]["K"]), rtol=1e-12)
    assert main(["bench", "ip", str(lean), "--position-sigma-km", "1e4", "-q", "-o", str(tmp_path / "r")]) == 0
    assert json.loads((tmp_path / "r" / "summary.json").read_text())["attitude"]["correct_rate"] == 1.0
