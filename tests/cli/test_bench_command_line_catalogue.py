"""The bad-input catalogue of the bench and calibration commands: flags and output paths.

The standard of ``test_bad_input_catalogue.py`` held over what is typed on the command line of
``hil facility|export``, ``render --hil``, ``calibrate patterns|simulate|geometric|radiometric``
and ``bench ip|nav``: out-of-range, non-finite and malformed flag values, and output paths that
would write into an input, onto a file or a device, or under ``/dev``, ``/sys``, ``/proc``. Each
case must end with exit 2, exactly one stderr line ``skynav: error: ...`` naming the flag or path
at fault, no traceback, and every input unchanged afterwards. The documented good paths follow,
on the same inputs. Damaged input files are in ``test_bench_bad_input_catalogue.py``.

Commands run in this process through ``skynav.__main__.main``.
"""

from __future__ import annotations

import json

import pytest
import yaml

from .bench_catalogue import build_world, check_catalogue, run_cli, sha_tree


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    return build_world(tmp_path_factory)


def _flag_cases(tmp, inp, out):
    fac, pats, caps, ds = str(inp / "fac.yaml"), str(inp / "pats"), str(inp / "caps"), str(inp / "ds")
    csv = str(inp / "caps" / "power_meter.csv")
    sim = ["calibrate", "simulate", fac, "--patterns", pats, "-o", str(out / "s"), "-q"]
    geo = ["calibrate", "geometric", fac, "--patterns", pats, "--captures", caps, "-o", str(out / "g.yaml"), "-q"]
    pat = ["calibrate", "patterns", fac, "-o", str(out / "p"), "-q"]
    ip = ["bench", "ip", ds, "-o", str(out / "ip"), "-q"]
    nav = ["bench", "nav", ds, "-o", str(out / "nav"), "-q"]
    exp = ["hil", "export", ds, "--facility", fac, "-o", str(out / "e"), "-q"]
    return [(f"flags:{' '.join(a[:2])} {' '.join(a[-2:])}"[:80], a, e) for a, e in [
        (sim + ["--seed", "-1"], "--seed"),
        (sim + ["--seed", "x"], "--seed"),
        (sim + ["--seed", str(2 ** 70)], "--seed"),
        (geo + ["--seed", "-1"], "--seed"),
        (ip + ["--seed", "-1"], "--seed"),
        (nav + ["--seed", "-1"], "--seed"),
        (sim + ["--frames", "0"], "--frames"),
        (sim + ["--frames", "-3"], "--frames"),
        (sim + ["--frames", "100000"], "--frames"),
        (sim + ["--frames", "1.5"], "--frames"),
        (sim + ["--scenario", "perfect"], "--scenario"),
        (pat + ["--phases", "0"], "--phases"),
        (pat + ["--phases", "-1"], "--phases"),
        (pat + ["--phases", "400"], "--phases"),
        (pat + ["--phases", "three"], "--phases"),
        (geo + ["--holdout", "0"], "--holdout"),
        (geo + ["--holdout", "1"], "--holdout"),
        (geo + ["--holdout", "-0.2"], "--holdout"),
        (geo + ["--holdout", "nan"], "--holdout"),
        (geo + ["--holdout", "inf"], "--holdout"),
        (geo + ["--holdout", "lots"], "--holdout"),
        (ip + ["--limit", "-1"], "--limit"),
        (ip + ["--limit", "0"], "--limit"),
        (ip + ["--position-sigma-km", "1e300"], "--position-sigma-km"),
        (ip + ["--position-sigma-km", "nan"], "--position-sigma-km"),
        (ip + ["--position-sigma-km", "inf"], "--position-sigma-km"),
        (ip + ["--position-sigma-km", "-5"], "--position-sigma-km"),
        (ip + ["--position-sigma-km", "0"], "--position-sigma-km"),
        (ip + ["--mode", "best"], "--mode"),
        (ip + ["--position-sigma-km"] + ["1e4"] * 17, "--position-sigma-km"),
        (ip + ["--set", "inlier_px=inf"], "inlier_px"),
        (ip + ["--set", "no_such=1"], "no_such"),
        (nav + ["--calibration-stride", "0"], "--calibration-stride"),
        (nav + ["--calibration-stride", "-2"], "--calibration-stride"),
        (nav + ["--sigma-px", "inf"], "--sigma-px"),
        (nav + ["--sigma-px", "nan"], "--sigma-px"),
        (nav + ["--sigma-px", "0"], "--sigma-px"),
        (nav + ["--sigma-px", "-1"], "--sigma-px"),
        (nav + ["--runs", "100000000"], "--runs"),
        (nav + ["--runs", "1"], "--runs"),
        (nav + ["--runs", "1e8"], "--runs"),
        (nav + ["--workers", "0"], "--workers"),
        (nav + ["--workers", "100000"], "--workers"),
        (nav + ["--case", "9"], "--case"),
        (nav + ["--limit", "-1"], "--limit"),
        (nav + ["--gm-sigma", "nan"], "--gm-sigma"),
        (nav, "sequence"),  # a montecarlo dataset
        (exp + ["--workers", "0"], "--workers"),
        (exp + ["--workers", "-1"], "--workers"),
        (exp + ["--workers", "100000"], "--workers"),
        (exp + ["--set", "screen.bit_depth=0"], "screen.bit_depth"),
        (exp + ["--set", "screen.bitdepth=8"], "screen.bitdepth"),
        (exp + ["--set", "geometric.parameters.k1=.nan"], "geometric.parameters.k1"),
        (exp + ["--set", "collimator.focal_length_mm=-5"], "collimator.focal_length_mm"),
        (exp + ["--dask-scheduler", "not an address"], "--dask-scheduler"),
        (["hil", "export", str(inp / "ds512"), "--facility", fac, "-o", str(out / "e2"), "-q"], "camera"),
        (["hil", "export", str(inp / "ds512"), "--facility", "screen_small", "-o", str(out / "e3"), "-q"], "camera"),
        (["render", "--hil", "screen_small", "--seed", "-1", "-o", str(out / "r")], "--seed"),
        (["render", "--hil", "no_such_bench", "-o", str(out / "r")], "no_such_bench"),
        (["calibrate", "patterns", fac], "--output"),
        (["calibrate", "frobnicate", fac], "frobnicate"),
        (["hil", "export", ds, "-o", str(out / "e")], "--facility"),
    ]]


def _path_cases(tmp, inp, out):
    fac, pats, caps, ds = str(inp / "fac.yaml"), str(inp / "pats"), str(inp / "caps"), str(inp / "ds")
    csv = str(inp / "caps" / "power_meter.csv")
    a_file = str(inp / "a_file.txt")
    cases = [
        ("path:export-into-dataset", ["hil", "export", ds, "--facility", fac, "-o", ds, "-q"], ds),
        ("path:export-inside-dataset", ["hil", "export", ds, "--facility", fac, "-o", ds + "/frames/screen", "-q"], ds),
        ("path:export-onto-a-file", ["hil", "export", ds, "--facility", fac, "-o", a_file, "-q"], a_file),
        ("path:export-no-dataset", ["hil", "export", str(inp / "nods"), "--facility", fac, "-o", str(out / "e"), "-q"],
         "nods"),
        ("path:export-dataset-a-file", ["hil", "export", a_file, "--facility", fac, "-o", str(out / "e"), "-q"], a_file),
        ("path:simulate-onto-patterns", ["calibrate", "simulate", fac, "--patterns", pats, "-o", pats, "-q"], pats),
        ("path:simulate-inside-patterns", ["calibrate", "simulate", fac, "--patterns", pats, "-o", pats + "/c", "-q"], pats),
        ("path:simulate-onto-a-file", ["calibrate", "simulate", fac, "--patterns", pats, "-o", a_file, "-q"], a_file),
        ("path:simulate-no-patterns", ["calibrate", "simulate", fac, "--patterns", str(inp / "nop"), "-o",
                                       str(out / "s"), "-q"], "nop"),
        ("path:patterns-onto-a-file", ["calibrate", "patterns", fac, "-o", a_file, "-q"], a_file),
        ("path:patterns-onto-facility", ["calibrate", "patterns", fac, "-o", fac, "-q"], fac),
        ("path:geometric-onto-facility", ["calibrate", "geometric", fac, "--patterns", pats, "--captures", caps, "-o", fac,
                                          "-q"], fac),
        ("path:geometric-into-captures", ["calibrate", "geometric", fac, "--patterns", pats, "--captures", caps, "-o",
                                          caps + "/cal.yaml", "-q"], caps),
        ("path:geometric-into-patterns", ["calibrate", "geometric", fac, "--patterns", pats, "--captures", caps, "-o",
                                          pats + "/cal.yaml", "-q"], pats),
        ("path:geometric-onto-a-folder", ["calibrate", "geometric", fac, "--patterns", pats, "--captures", caps, "-o",
                                          str(out), "-q"], str(out)),
        ("path:geometric-no-captures", ["calibrate", "geometric", fac, "--patterns", pats, "--captures", str(inp / "noc"),
                                        "-o", str(out / "g.yaml"), "-q"], "noc"),
        ("path:geometric-captures-are-patterns", ["calibrate", "geometric", fac, "--patterns", pats, "--captures", pats,
                                                  "-o", str(out / "g.yaml"), "-q"], pats),
        ("path:radiometric-onto-csv", ["calibrate", "radiometric", fac, "--measurements", csv, "-o", csv, "-q"], csv),
        ("path:radiometric-onto-facility", ["calibrate", "radiometric", fac, "--measurements", csv, "-o", fac, "-q"], fac),
        ("path:radiometric-onto-a-folder", ["calibrate", "radiometric", fac, "--measurements", csv, "-o", str(out), "-q"],
         str(out)),
        ("path:radiometric-csv-a-folder", ["calibrate", "radiometric", fac, "--measurements", caps, "-o",
                                           str(out / "r.yaml"), "-q"], caps),
        ("path:hil-facility-onto-a-folder", ["hil", "facility", "screen_small", "-o", str(out), "-q"], str(out)),
        ("path:hil-facility-onto-itself", ["hil", "facility", fac, "-o", fac, "-q"], fac),
        ("path:hil-facility-under-a-file", ["hil", "facility", "screen_small", "-o", a_file + "/f.yaml", "-q"], a_file),
        ("path:hil-facility-onto-a-device", ["hil", "facility", "screen_small", "-o", "/dev/full", "-q"], "/dev/full"),
        ("path:hil-facility-into-dev", ["hil", "facility", "screen_small", "-o", "/dev/skynav.yaml", "-q"], "/dev"),
        ("path:geometric-into-sys", ["calibrate", "geometric", fac, "--patterns", pats, "--captures", caps, "-o",
                                     "/sys/cal.yaml", "-q"], "/sys"),
        ("path:simulate-into-proc", ["calibrate", "simulate", fac, "--patterns", pats, "-o", "/proc/caps", "-q"], "/proc"),
        ("path:patterns-under-a-file", ["calibrate", "patterns", fac, "-o", a_file + "/p", "-q"], a_file),
        ("path:hil-facility-in-proc", ["hil", "facility", "screen_small", "-o", "/proc/skynav.yaml", "-q"], "/proc/skynav.yaml"),
        ("path:bench-ip-into-dataset", ["bench", "ip", ds, "-o", ds + "/report", "-q"], ds),
        ("path:bench-ip-onto-dataset", ["bench", "ip", ds, "-o", ds, "-q"], ds),
        ("path:bench-ip-no-dir", ["bench", "ip", str(inp / "nodir"), "-o", str(out / "ip"), "-q"], "nodir"),
        ("path:bench-ip-empty-dir", ["bench", "ip", str(out), "-o", str(out / "ip2"), "-q"], str(out)),
        ("path:bench-nav-no-dir", ["bench", "nav", str(inp / "nodir"), "-o", str(out / "nav"), "-q"], "nodir"),
    ]
    return cases


@pytest.fixture(scope="module")
def catalogue(world):
    tmp, inp, out = world
    return _flag_cases(tmp, inp, out) + _path_cases(tmp, inp, out)


def test_every_bad_flag_or_path_gives_one_line_exit_2_and_leaves_the_inputs_alone(world, catalogue, capsys):
    """All cases in one test (one fixture build); every failure is listed, not only the first."""
    assert len(catalogue) >= 90, len(catalogue)  # the catalogue is large enough
    check_catalogue(world, catalogue, capsys)


# ----------------------------------------------------------------------------- the good paths, on the command line
SMALL_CAMERA = ["--set", "camera.width=256", "--set", "camera.height=256", "--set",
                "camera.pixel_pitch_um=55.102181471395305"]  # the screen_small facility's camera


@pytest.mark.parametrize("facility", ["preset", "nominal", "calibrated"])
def test_render_hil_documented_paths_run_on_the_command_line(world, facility, capsys):
    """``skynav render --hil`` with a preset, a nominal facility file and a calibrated one."""
    tmp, inp, out = world
    fac = {"preset": "screen_small", "nominal": str(inp / "fac.yaml"), "calibrated": str(inp / "cal.yaml")}[facility]
    before = sha_tree(inp)
    dest = out / f"render_{facility}"
    code, stdout, err = run_cli(["render", "--hil", fac, "-o", str(dest), *SMALL_CAMERA], capsys)
    assert code == 0, err
    assert "screen frame 640x640 10-bit" in stdout and "Traceback" not in err
    rec = json.loads((dest / "frame.json").read_text())  # render writes OUT/NAME.*, with or without --hil
    assert rec["facility"]["screen"] == {"width_px": 640, "height_px": 640, "bit_depth": 10}
    assert (rec["facility"]["geometric_fit"] is not None) == (facility == "calibrated")
    assert sha_tree(inp) == before


def test_editing_the_nominal_focal_length_of_a_calibrated_facility_is_refused_naming_the_key(world, capsys):
    tmp, inp, out = world
    doc = yaml.safe_load((inp / "cal.yaml").read_text())
    doc["collimator"]["focal_length_mm"] = 55.0
    f = out / "edited.yaml"
    f.write_text(yaml.safe_dump(doc))
    code, _, err = run_cli(["hil", "export", str(inp / "ds"), "--facility", str(f), "-o", str(out / "ed"), "-q"], capsys)
    assert code == 2 and "collimator.focal_length_mm = 55.0" in err and "edit geometric.parameters.focal_length_mm" in err
    # the key the model uses does change the model
    doc = yaml.safe_load((inp / "cal.yaml").read_text())
    for section in (doc["collimator"], doc["geometric"]["parameters"]):
        section["focal_length_mm"] = 55.0
    f.write_text(yaml.safe_dump(doc))
    from skynav.calibration.facility_io import load_facility

    assert load_facility(f).geometric.focal_length_mm == 55.0


def test_a_power_meter_table_with_a_byte_order_mark_is_read(world, capsys):
    tmp, inp, out = world
    f = out / "bom.csv"
    f.write_bytes(b"\xef\xbb\xbf" + (inp / "caps" / "power_meter.csv").read_bytes())
    code, _, err = run_cli(["calibrate", "radiometric", str(inp / "fac.yaml"), "--measurements", str(f), "-o",
                         str(out / "bom.yaml"), "-q"], capsys)
    assert code == 0, err


def test_set_collimator_focal_length_on_a_nominal_preset_changes_the_model(world, capsys):
    tmp, inp, out = world
    code, _, err = run_cli(["hil", "export", str(inp / "ds"), "--facility", "screen_small", "-o", str(out / "f55"), "-q",
                         "--set", "collimator.focal_length_mm=55"], capsys)
    assert code == 0, err
    code, _, err = run_cli(["hil", "export", str(inp / "ds"), "--facility", "screen_small", "-o", str(out / "f50"), "-q"], capsys)
    assert code == 0, err
    a = json.loads((out / "f55" / "frames" / "000000.json").read_text())["stars"]
    b = json.loads((out / "f50" / "frames" / "000000.json").read_text())["stars"]
    assert a and [s["screen_xy"] for s in a] != [s["screen_xy"] for s in b]  # 10 % longer focal: stars move
