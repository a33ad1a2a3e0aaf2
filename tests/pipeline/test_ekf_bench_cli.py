"""``skynav bench nav`` end to end on a small rendered ``sequence`` dataset, and its one-line errors."""

import json
import shutil

import pytest

from skynav.cli import main

SUMMARY_KEYS = {"runs", "frames", "final", "nees", "measurement_error_px", "cases", "time_s"}


@pytest.fixture(scope="module")
def seq(tmp_path_factory):
    d = tmp_path_factory.mktemp("nav") / "seq"
    assert main(["dataset", "generate", "sequence", "-o", str(d), "--count", "6", "--workers", "1", "-q"]) == 0
    return d


def test_bench_nav_writes_the_report(seq, tmp_path, capsys):
    out = tmp_path / "rep"
    rc = main(["bench", "nav", str(seq), "--runs", "4", "--case", "1", "3", "--seed", "3", "-q",
               "--calibration-stride", "2", "-o", str(out)])
    assert rc == 0
    s = json.loads((out / "summary.json").read_text())
    assert SUMMARY_KEYS <= set(s)
    assert set(s["final"]) >= {"position_3sigma_km", "velocity_3sigma_m_s", "position_error_rms_km", "velocity_error_rms_m_s"}
    assert set(s["nees"]) >= {"mean", "band_low", "band_high", "fraction_inside"}
    assert set(s["measurement_error_px"]) >= {"mean", "std"}
    assert set(s["cases"]) == {"1", "3"} and set(s["cases"]["1"]) == {"position_rmse_km", "velocity_rmse_m_s"}
    assert s["runs"] == 4 and s["frames"] == 6
    assert s["measurements"]["frames_with_centroid"] >= 4  # the image processing found the target
    html = (out / "report.html").read_text()
    assert html.count("data:image/png;base64,") == 4 and "<script" not in html and "http" not in html
    assert (out / "runs.csv").read_text().count("\n") == 1 + 2 * 4
    assert "report:" in capsys.readouterr().out


def _err(argv, capsys):
    rc = main(argv)
    err = capsys.readouterr().err.strip().splitlines()
    return rc, err


def test_wrong_inputs_one_line_exit_2(seq, tmp_path, capsys):
    mc = tmp_path / "mc"
    assert main(["dataset", "generate", "montecarlo", "-o", str(mc), "--count", "1", "--workers", "1", "-q"]) == 0
    rc, err = _err(["bench", "nav", str(mc), "-o", str(tmp_path / "r1")], capsys)
    assert rc == 2 and len(err) == 1 and "sequence" in err[0]

    missing = tmp_path / "missing"
    shutil.copytree(seq, missing)
    (missing / "frames" / "000003.png").unlink()
    rc, err = _err(["bench", "nav", str(missing), "-o", str(tmp_path / "r2")], capsys)
    assert rc == 2 and len(err) == 1 and "frame 3 is missing" in err[0]

    blind = tmp_path / "blind"
    shutil.copytree(seq, blind)
    for js in (blind / "frames").glob("*.json"):
        t = json.loads(js.read_text())
        for b in t["bodies"]:
            b["visible"] = False
        js.write_text(json.dumps(t))
    rc, err = _err(["bench", "nav", str(blind), "-o", str(tmp_path / "r3")], capsys)
    assert rc == 2 and len(err) == 1 and "no visible planet" in err[0]

    rc, err = _err(["bench", "nav", str(seq), "--case", "7", "-o", str(tmp_path / "r4")], capsys)
    assert rc == 2 and len(err) == 1
    rc, err = _err(["bench", "nav", str(tmp_path / "nothing"), "-o", str(tmp_path / "r5")], capsys)
    assert rc == 2 and len(err) == 1
