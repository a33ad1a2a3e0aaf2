"""Wrong inputs to `skynav calibrate` / `skynav hil` get one clear line and exit code 2."""

import shutil

import numpy as np
import pytest

from skynav.cli import main


def _run(capsys, *argv):
    rc = main(list(argv))
    err = capsys.readouterr().err
    return rc, err


def _one_line_exit_2(rc, err, *words):
    assert rc == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("skynav: error:"), err
    for w in words:
        assert w in lines[0]


def test_full_chain_runs(tmp_path, capsys, small_patterns, small_captures):
    fac = tmp_path / "fac.yaml"
    assert main(["hil", "facility", "screen_small", "-o", str(fac)]) == 0
    assert main(["calibrate", "geometric", str(fac), "--patterns", str(small_patterns), "--captures", str(small_captures),
                 "-o", str(tmp_path / "geo.yaml")]) == 0
    assert (tmp_path / "geo_residuals.png").is_file()
    assert main(["calibrate", "radiometric", str(tmp_path / "geo.yaml"), "--measurements", str(small_captures / "power_meter.csv"),
                 "-o", str(tmp_path / "cal.yaml")]) == 0
    assert (tmp_path / "cal_radiometric.png").is_file()
    out = capsys.readouterr().out
    assert "held-out line-of-sight residual" in out and "usable" in out


def test_missing_capture(tmp_path, capsys, small_patterns, small_captures):
    cap = tmp_path / "cap"
    shutil.copytree(small_captures, cap)
    (cap / "dots_03.png").unlink()
    rc, err = _run(capsys, "calibrate", "geometric", "screen_small", "--patterns", str(small_patterns), "--captures", str(cap), "-o", str(tmp_path / "o.yaml"))
    _one_line_exit_2(rc, err, "missing", "dots_03.png")


@pytest.mark.parametrize("bad", ["size", "depth"])
def test_capture_of_wrong_size_or_bit_depth(tmp_path, capsys, small_patterns, small_captures, bad):
    from skynav.datasets.frame_files import write_png

    cap = tmp_path / "cap"
    shutil.copytree(small_captures, cap)
    img = np.zeros((200, 256), np.uint8) if bad == "size" else np.full((256, 256), 1000, np.uint16)
    write_png(cap / "dots_00.png", img)
    rc, err = _run(capsys, "calibrate", "geometric", "screen_small", "--patterns", str(small_patterns), "--captures", str(cap), "-o", str(tmp_path / "o.yaml"))
    _one_line_exit_2(rc, err, "dots_00.png")


def test_patterns_for_another_screen(tmp_path, capsys, small_patterns, small_captures):
    rc, err = _run(capsys, "calibrate", "geometric", "screen", "--patterns", str(small_patterns), "--captures", str(small_captures), "-o", str(tmp_path / "o.yaml"))
    _one_line_exit_2(rc, err, "screen")


@pytest.mark.parametrize("text,word", [
    ("digital_count,lit_pixels,irradiance_w_m2\n0,100,1e-9\n10,100,2e-9\n", "need"),
    ("digital_count,lit_pixels,irradiance_w_m2\n" + "".join(f"{d},100,{e}\n" for d, e in
     zip(range(0, 100, 10), [1, 2, 3, 4, 5, 3, 7, 8, 9, 10])), "monotone"),
    ("dn,n,e\n1,2,3\n", "header"),
])
def test_bad_measurement_file(tmp_path, capsys, text, word):
    csv = tmp_path / "m.csv"
    csv.write_text(text)
    rc, err = _run(capsys, "calibrate", "radiometric", "screen_small", "--measurements", str(csv), "-o", str(tmp_path / "o.yaml"))
    _one_line_exit_2(rc, err, word)


def test_facility_that_does_not_cover_the_field(tmp_path, capsys):
    import yaml

    fac = tmp_path / "fac.yaml"
    assert main(["hil", "facility", "screen_small", "-o", str(fac)]) == 0
    d = yaml.safe_load(fac.read_text())
    d["collimator"]["focal_length_mm"] = 80.0
    d["geometric"]["parameters"]["focal_length_mm"] = 80.0
    fac.write_text(yaml.safe_dump(d))
    capsys.readouterr()
    rc, err = _run(capsys, "hil", "facility", str(fac), "-o", str(tmp_path / "x.yaml"))
    _one_line_exit_2(rc, err, "cover")


def test_unknown_facility(tmp_path, capsys):
    rc, err = _run(capsys, "calibrate", "patterns", "nope", "-o", str(tmp_path / "p"))
    _one_line_exit_2(rc, err, "nope")
