"""The bad-input catalogue of the bench and calibration commands: damaged input files.

The standard of ``test_bad_input_catalogue.py`` (render, scene, dataset) held over the files the
``hil``, ``render --hil``, ``calibrate`` and ``bench`` commands read: facility files (every key
mutated, calibrated ones, files that are not YAML), pattern manifests and their PNGs, captures,
power-meter tables and datasets. Each case is a command line a user could type, with the files it
needs; each must end with exit 2, exactly one stderr line ``skynav: error: ...`` naming the key or
file at fault, no traceback, and every input unchanged afterwards (every file under the inputs
folder, hidden ones included, is hashed before and after each case; a new file there counts as a
change). Bad flags and output paths are in ``test_bench_command_line_catalogue.py``.

Inputs are tiny (the ``screen_small`` facility, one dot grid, one-frame datasets), so the table
runs in seconds; commands run in this process through ``skynav.__main__.main``.
"""

from __future__ import annotations

import copy
import json
import shutil
from pathlib import Path

import pytest
import yaml

from .bench_catalogue import build_world, check_catalogue

_DELETE = object()  # a key to remove


def _set(d: dict, dotted: str, value):
    d = copy.deepcopy(d)
    node = d
    parts = dotted.split(".")
    for p in parts[:-1]:
        node = node.setdefault(p, {}) if isinstance(node, dict) else node[int(p)]
    if value is _DELETE:
        node.pop(parts[-1], None)
    else:
        node[parts[-1]] = value
    return d


# (dotted key, bad value, text the error line must contain)
FACILITY_MUTATIONS = [
    ("schema", "skynav.facility/9", "schema"),
    ("schema", _DELETE, "schema"),
    ("schema", 1, "schema"),
    ("name", ["a"], "name"),
    ("name", "x" * 500, "name"),
    ("screen", [640, 640], "screen"),
    ("screen", _DELETE, "screen"),
    ("screen.width_px", 0, "screen.width_px"),
    ("screen.width_px", -640, "screen.width_px"),
    ("screen.width_px", 640.5, "screen.width_px"),
    ("screen.width_px", "wide", "screen.width_px"),
    ("screen.width_px", 300000, "screen.width_px"),
    ("screen.width_px", True, "screen.width_px"),
    ("screen.width_px", _DELETE, "screen.width_px"),
    ("screen.height_px", 8, "screen.height_px"),
    ("screen.height_px", float("nan"), "screen.height_px"),
    ("screen.height_px", None, "screen.height_px"),
    ("screen.pixel_pitch_um", 0, "screen.pixel_pitch_um"),
    ("screen.pixel_pitch_um", -32, "screen.pixel_pitch_um"),
    ("screen.pixel_pitch_um", float("inf"), "screen.pixel_pitch_um"),
    ("screen.pixel_pitch_um", "32um", "screen.pixel_pitch_um"),
    ("screen.pixel_pitch_um", 1e300, "screen.pixel_pitch_um"),
    ("screen.bit_depth", 0, "screen.bit_depth"),
    ("screen.bit_depth", 17, "screen.bit_depth"),
    ("screen.bit_depth", 10.5, "screen.bit_depth"),
    ("screen.bitdepth", 10, "did you mean screen.bit_depth"),
    ("screen.widht_px", 640, "did you mean screen.width_px"),
    ("collimator", 50, "collimator"),
    ("collimator", _DELETE, "collimator"),
    ("collimator.focal_length_mm", 0, "collimator.focal_length_mm"),
    ("collimator.focal_length_mm", -50, "collimator.focal_length_mm"),
    ("collimator.focal_length_mm", float("nan"), "collimator.focal_length_mm"),
    ("collimator.focal_length_mm", "50 mm", "collimator.focal_length_mm"),
    ("collimator.focal_length_mm", 60.0, "geometric.parameters.focal_length_mm"),  # disagrees with the model's key
    ("collimator.focal_lenght_mm", 50, "did you mean collimator.focal_length_mm"),
    ("camera", "paper", "camera"),
    ("camera", _DELETE, "camera"),
    ("camera.width", 0, "camera.width"),
    ("camera.width", "wide", "camera.width"),
    ("camera.focal_length_mm", -1, "camera.focal_length_mm"),
    ("camera.exposure_s", float("inf"), "camera.exposure_s"),
    ("camera.zoom", 2, "camera.zoom"),
    ("spectra", [1, 2], "spectra"),
    ("spectra.screen_emision", {}, "did you mean spectra.screen_emission"),
    ("spectra.screen_emission", "oled", "spectra.screen_emission"),
    ("spectra.screen_emission.relative", [1.0, float("nan")] + [0.5] * 79, "spectra.screen_emission.relative[1]"),
    ("spectra.screen_emission.relative", [-1.0] + [0.5] * 80, "spectra.screen_emission.relative[0]"),
    ("spectra.screen_emission.relative", [0.0] * 81, "spectra.screen_emission.relative"),
    ("spectra.screen_emission.relative", [0.5] * 10, "spectra.screen_emission.relative"),
    ("spectra.screen_emission.relative", [0.5], "spectra.screen_emission.relative"),
    ("spectra.screen_emission.wavelengths_nm", list(range(780, 375, -5)), "spectra.screen_emission.wavelengths_nm[1]"),
    ("spectra.screen_emission.wavelengths_nm", [float(w) for w in range(2000, 2405, 5)], "spectra.screen_emission"),
    ("spectra.screen_emission.wavelengths_nm", "visible", "spectra.screen_emission.wavelengths_nm"),
    ("spectra.screen_emission.wavelengths_nm", _DELETE, "spectra.screen_emission.wavelengths_nm"),
    ("spectra.power_meter_responsivity", {"wavelengths_nm": [1300.0, 1400.0], "relative": [1.0, 1.0]},
     "spectra.power_meter_responsivity"),
    ("spectra.power_meter_responsivity.relative", [float("inf"), 1.0], "spectra.power_meter_responsivity.relative[0]"),
    ("spectra.power_meter_responsivity.wavelengths_nm", [300.0, 300.0], "spectra.power_meter_responsivity.wavelengths_nm[1]"),
    ("geometric", [1, 2], "geometric"),
    ("geometric", "nominal", "geometric"),
    ("geometric.model", "pinhole/2", "geometric.model"),
    ("geometric.parameters", [50.0], "geometric.parameters"),
    ("geometric.parameters.focal_length_mm", 0, "geometric.parameters.focal_length_mm"),
    ("geometric.parameters.focal_length_mm", -50, "geometric.parameters.focal_length_mm"),
    ("geometric.parameters.focal_length_mm", "long", "geometric.parameters.focal_length_mm"),
    ("geometric.parameters.k_1", 0.1, "did you mean geometric.parameters.k1"),
    ("geometric.parameters.k1", float("nan"), "geometric.parameters.k1"),
    ("geometric.parameters.k1", "0.1", "geometric.parameters.k1"),
    ("geometric.parameters.k2", 1e300, "geometric.parameters.k2"),
    ("geometric.parameters.p1", None, "geometric.parameters.p1"),
    ("geometric.parameters.roll_deg", 720, "geometric.parameters.roll_deg"),
    ("geometric.parameters.tilt_x_deg", float("inf"), "geometric.parameters.tilt_x_deg"),
    ("geometric.parameters.tilt_x_rad", 0.1, "did you mean geometric.parameters.tilt_x_deg"),
    ("geometric.parameters.decentre_x_mm", 1e9, "geometric.parameters.decentre_x_mm"),
    ("geometric.parameters.misalignment_deg", 0.1, "geometric.parameters.misalignment_deg"),
    ("geometric.parameters.misalignment_deg", [0.1, 0.2], "geometric.parameters.misalignment_deg"),
    ("geometric.parameters.misalignment_deg", [0.1, "x", 0.0], "geometric.parameters.misalignment_deg[1]"),
    ("geometric.residual_field", [1], "geometric.residual_field"),
    ("geometric.residual_field", {"x_px": [0, 1, 2, 3]}, "geometric.residual_field.y_px"),
    ("geometric.residual_field", {"x_px": [0, 10, 20, 30], "y_px": [30, 20, 10, 0], "dx_arcsec": [[0] * 4] * 4,
                                  "dy_arcsec": [[0] * 4] * 4}, "geometric.residual_field.y_px[1]"),
    ("geometric.residual_field", {"x_px": [0, 10, 20, 30], "y_px": [0, 10, 20, 30], "dx_arcsec": [[0] * 3] * 4,
                                  "dy_arcsec": [[0] * 4] * 4}, "geometric.residual_field.dx_arcsec"),
    ("geometric.residual_field", {"x_px": [0, 10, 20, 30], "y_px": [0, 10, 20, 30], "dx_arcsec": [[0] * 4] * 4,
                                  "dy_arcsec": [[float("inf")] * 4] * 4}, "geometric.residual_field.dy_arcsec[0][0]"),
    ("geometric.residual_field", {"x_px": [0, 10, 20], "y_px": [0, 10, 20], "dx_arcsec": [[0] * 3] * 3,
                                  "dy_arcsec": [[0] * 3] * 3}, "geometric.residual_field.x_px"),
    ("geometric.fit", "good", "geometric.fit"),
    ("radiometric", 7, "radiometric"),
    ("radiometric.model", "linear", "radiometric.model"),
    ("radiometric.parameters.gamma", 0, "radiometric.parameters.gamma"),
    ("radiometric.parameters.gamma", 100, "radiometric.parameters.gamma"),
    ("radiometric.parameters.gamma", float("nan"), "radiometric.parameters.gamma"),
    ("radiometric.parameters.peak_w_m2", -1.0, "radiometric.parameters.peak_w_m2"),
    ("radiometric.parameters.peak_w_m2", 1e-30, "radiometric.parameters.peak_w_m2"),
    ("radiometric.parameters.black_w_m2", -1e-12, "radiometric.parameters.black_w_m2"),
    ("radiometric.parameters.black_w_m2", 1.0, "radiometric.parameters"),
    ("radiometric.parameters.gama", 2.2, "did you mean radiometric.parameters.gamma"),
    ("radiometric.flat_field", {"x_px": [0, 100], "y_px": [0, 100], "relative": [[1, 1], [1, float("inf")]]},
     "radiometric.flat_field.relative[1][1]"),
    ("radiometric.flat_field", {"x_px": [100, 0], "y_px": [0, 100], "relative": [[1, 1], [1, 1]]},
     "radiometric.flat_field.x_px[1]"),
    ("radiometric.flat_field", {"x_px": [0, 100], "y_px": [0, 100], "relative": [[1, 1], [1, 0]]},
     "radiometric.flat_field.relative[1][1]"),
    ("radiometric.flat_field", {"x_px": [0, 100, 200], "y_px": [0, 100], "relative": [[1, 1], [1, 1]]},
     "radiometric.flat_field.relative[0]"),
    ("radiometric.flat_field", {"x_px": [0, 100], "y_px": [0, 100]}, "radiometric.flat_field.relative"),
    ("extra_section", {}, "extra_section"),
]

BAD_FACILITY_TEXTS = [
    ("empty", b"", "facility"),
    ("a-list", b"- 1\n- 2\n", "facility"),
    ("a-string", b"bench\n", "facility"),
    ("not-yaml", b"screen: [1, 2\n", "not valid YAML"),
    ("binary", b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR\xff\xfe", "fac_binary.yaml"),
    ("utf16", "schema: skynav.facility/1\n".encode("utf-16"), "fac_utf16.yaml"),
]


def _facility_cases(tmp, inp, out):
    base = yaml.safe_load((inp / "fac.yaml").read_text())
    cal = yaml.safe_load((inp / "cal.yaml").read_text())
    cases = []
    for i, (key, value, expect) in enumerate(FACILITY_MUTATIONS):
        f = inp / "facs" / f"m{i:03d}.yaml"
        f.parent.mkdir(exist_ok=True)
        f.write_text(yaml.safe_dump(_set(base, key, value)))
        cases.append((f"facility:{key}={str(value)[:20]}", ["hil", "facility", str(f), "-o", str(out / "f.yaml"), "-q"],
                      expect))
        if i % 7 == 0:  # the same files through the other readers
            cases.append((f"facility-patterns:{key}", ["calibrate", "patterns", str(f), "-o", str(out / "p"), "-q"], expect))
            cases.append((f"facility-render:{key}", ["render", "--hil", str(f), "-o", str(out / "r")], expect))
            cases.append((f"facility-export:{key}", ["hil", "export", str(inp / "ds"), "--facility", str(f), "-o",
                                                     str(out / "e"), "-q"], expect))
    for key, value, expect in [("collimator.focal_length_mm", 60.0, "edit geometric.parameters.focal_length_mm"),
                               ("geometric.fit", [], "geometric.fit"),
                               ("geometric.residual_field.y_px", _DELETE, "geometric.residual_field.y_px")]:
        f = inp / "facs" / f"cal_{key}.yaml"
        f.write_text(yaml.safe_dump(_set(cal, key, value)))
        cases.append((f"calibrated:{key}", ["hil", "facility", str(f), "-o", str(out / "f.yaml"), "-q"], expect))
        cases.append((f"calibrated-radiometric:{key}", ["calibrate", "radiometric", str(f), "--measurements",
                                                        str(inp / "caps" / "power_meter.csv"), "-o", str(out / "c.yaml"),
                                                        "-q"], expect))
    for name, data, expect in BAD_FACILITY_TEXTS:
        f = inp / "facs" / f"fac_{name}.yaml"
        f.write_bytes(data)
        cases.append((f"facility-text:{name}", ["hil", "facility", str(f), "-o", str(out / "f.yaml"), "-q"], expect))
        cases.append((f"facility-text-sim:{name}", ["calibrate", "simulate", str(f), "--patterns", str(inp / "pats"),
                                                    "-o", str(out / "s"), "-q"], expect))
    tiny = _set(_set(base, "screen.width_px", 16), "screen.height_px", 16)
    (inp / "facs" / "tiny_screen.yaml").write_text(yaml.safe_dump(tiny))
    cases.append(("facility:16x16-screen-patterns", ["calibrate", "patterns", str(inp / "facs" / "tiny_screen.yaml"), "-o",
                                                     str(out / "p16"), "-q"], "screen"))
    cases.append(("facility:missing", ["hil", "facility", str(inp / "nope.yaml"), "-o", str(out / "f.yaml")], "nope.yaml"))
    cases.append(("facility:a-folder", ["hil", "facility", str(inp / "pats"), "-o", str(out / "f.yaml")], "pats"))
    cases.append(("facility:preset-typo", ["hil", "facility", "screen_smal", "-o", str(out / "f.yaml")], "screen_small"))
    cases.append(("facility:former-preset-name", ["hil", "facility", "bench_small", "-o", str(out / "g.yaml")],
                  "now named screen_small"))
    cases.append(("facility:former-preset-name-render", ["render", "--hil", "bench", "-o", str(out / "h")], "give screen"))
    return cases


def _variant(inp, src, name, damage):
    d = inp / "damaged" / name
    if not d.exists():
        shutil.copytree(src, d)
        damage(d)
    return str(d)


def _edit_json(path: Path, edit):
    doc = json.loads(path.read_text())
    edit(doc)
    path.write_text(json.dumps(doc))


def _patterns_cases(tmp, inp, out):
    fac, caps = str(inp / "fac.yaml"), str(inp / "caps")
    pj = "patterns.json"
    damages = {
        "no-manifest": (lambda d: (d / pj).unlink(), pj),
        "not-json": (lambda d: (d / pj).write_text("{not json"), pj),
        "empty": (lambda d: (d / pj).write_bytes(b""), pj),
        "a-list": (lambda d: (d / pj).write_text("[1, 2]"), pj),
        "binary": (lambda d: (d / pj).write_bytes(b"\x89PNG\r\n\x1a\n\xff\xfe"), pj),
        "wrong-schema": (lambda d: _edit_json(d / pj, lambda j: j.update(schema="other/9")), pj),
        "no-patterns": (lambda d: _edit_json(d / pj, lambda j: j.pop("patterns")), pj),
        "patterns-a-dict": (lambda d: _edit_json(d / pj, lambda j: j.update(patterns={"a": 1})), pj),
        "patterns-empty": (lambda d: _edit_json(d / pj, lambda j: j.update(patterns=[])), pj),
        "no-screen": (lambda d: _edit_json(d / pj, lambda j: j.pop("screen")), pj),
        "screen-a-list": (lambda d: _edit_json(d / pj, lambda j: j.update(screen=[640, 640])), pj),
        "other-screen": (lambda d: _edit_json(d / pj, lambda j: j["screen"].update(width_px=1024)), "1024"),
        "file-escapes": (lambda d: _edit_json(d / pj, lambda j: j["patterns"][0].update(file="../x.png")), "../x.png"),
        "file-absolute": (lambda d: _edit_json(d / pj, lambda j: j["patterns"][0].update(file="/tmp/x.png")), "/tmp/x.png"),
        "file-subfolder": (lambda d: _edit_json(d / pj, lambda j: j["patterns"][0].update(file="a/b.png")), "a/b.png"),
        "file-hidden": (lambda d: _edit_json(d / pj, lambda j: j["patterns"][0].update(file=".x.png")), ".x.png"),
        "file-empty": (lambda d: _edit_json(d / pj, lambda j: j["patterns"][0].update(file="")), pj),
        "file-a-number": (lambda d: _edit_json(d / pj, lambda j: j["patterns"][0].update(file=7)), pj),
        "file-duplicate": (lambda d: _edit_json(d / pj, lambda j: j["patterns"][1].update(file=j["patterns"][0]["file"])),
                           "dots_00.png"),
        "file-csv": (lambda d: _edit_json(d / pj, lambda j: j["patterns"][-1].update(file="power_meter.csv")),
                     "power_meter.csv"),
        "dots-nan": (lambda d: _edit_json(d / pj, lambda j: j["patterns"][0]["dots"][0].__setitem__(0, float("nan"))), pj),
        "dots-odd": (lambda d: _edit_json(d / pj, lambda j: j["patterns"][0].update(dots=[1, 2, 3])), pj),
        "dots-strings": (lambda d: _edit_json(d / pj, lambda j: j["patterns"][0].update(dots=[["a", "b"]])), pj),
        "dots-off-screen": (lambda d: _edit_json(d / pj, lambda j: j["patterns"][0]["dots"][0].__setitem__(0, 1e9)), pj),
        "kind-unknown": (lambda d: _edit_json(d / pj, lambda j: j["patterns"][0].update(kind="stars")), pj),
        "fiducial-out-of-range": (lambda d: _edit_json(d / pj, lambda j: j["patterns"][0].update(fiducials=[99999])), pj),
        "radius-negative": (lambda d: _edit_json(d / pj, lambda j: j["patterns"][0].update(dot_radius_px=-3)), pj),
        "level-too-high": (lambda d: _edit_json(d / pj, lambda j: j["patterns"][0].update(level_dn=10 ** 9)), pj),
        "png-missing": (lambda d: (d / "dots_00.png").unlink(), "dots_00.png"),
        "png-truncated": (lambda d: (d / "dots_00.png").write_bytes((d / "dots_00.png").read_bytes()[:100]), "dots_00.png"),
        "png-text": (lambda d: (d / "dots_00.png").write_text("not an image"), "dots_00.png"),
        "png-wrong-size": (lambda d: shutil.copy(inp / "caps" / "dots_00.png", d / "dots_00.png"), "dots_00.png"),
    }
    cases = []
    for name, (damage, expect) in damages.items():
        p = _variant(inp, inp / "pats", f"pats_{name}", damage)
        cases.append((f"patterns:simulate:{name}", ["calibrate", "simulate", fac, "--patterns", p, "-o",
                                                    str(out / f"s_{name}"), "-q"], expect))
        if not name.startswith("png-"):
            cases.append((f"patterns:geometric:{name}", ["calibrate", "geometric", fac, "--patterns", p, "--captures",
                                                         caps, "-o", str(out / "g.yaml"), "-q"], expect))
    cap_damages = {
        "capture-missing": (lambda d: (d / "dots_00.png").unlink(), "dots_00.png"),
        "capture-truncated": (lambda d: (d / "dots_00.png").write_bytes((d / "dots_00.png").read_bytes()[:200]), "dots_00.png"),
        "capture-empty": (lambda d: (d / "dots_00.png").write_bytes(b""), "dots_00.png"),
        "capture-is-pattern": (lambda d: shutil.copy(inp / "pats" / "dots_00.png", d / "dots_00.png"), "dots_00.png"),
        "capture-a-folder": (lambda d: ((d / "dots_00.png").unlink(), (d / "dots_00.png").mkdir()), "dots_00.png"),
        "captures-all-dark": (lambda d: [shutil.copy(d / "dark.png", d / f) for f in ("dots_00.png",)], "dots_00.png"),
    }
    for name, (damage, expect) in cap_damages.items():
        p = _variant(inp, inp / "caps", name, damage)
        cases.append((f"captures:geometric:{name}", ["calibrate", "geometric", fac, "--patterns", str(inp / "pats"),
                                                     "--captures", p, "-o", str(out / "g.yaml"), "-q"], expect))
    return cases


def _csv_cases(tmp, inp, out):
    good = (inp / "caps" / "power_meter.csv").read_text()
    lines = good.splitlines()
    texts = {
        "empty": (b"", "header"),
        "header-only": (lines[0].encode() + b"\n", "measurements"),
        "wrong-header": (("dn,pixels,watts\n" + "\n".join(lines[1:])).encode(), "header"),
        "a-png": ((inp / "caps" / "dark.png").read_bytes(), "pm_"),
        "utf16": (good.encode("utf-16"), "pm_"),
        "latin1-garbage": (b"digital_count,lit_pixels,irradiance_w_m2\n\xff\xfe,1,2\n", "pm_"),
        "nan": ((good + "5,100,nan\n").encode(), "irradiance_w_m2"),
        "inf": ((good + "5,100,inf\n").encode(), "irradiance_w_m2"),
        "negative": ((good + "5,100,-1e-9\n").encode(), "irradiance_w_m2"),
        "pixels-zero": ((good + "5,0,1e-9\n").encode(), "lit_pixels"),
        "pixels-nan": ((good + "5,nan,1e-9\n").encode(), "lit_pixels"),
        "dn-negative": ((good + "-5,100,1e-9\n").encode(), "digital_count"),
        "dn-fraction": ((good + "5.5,100,1e-9\n").encode(), "digital_count"),
        "dn-too-high": ((good + "99999,100,1e-3\n").encode(), "digital_count"),
        "dn-nan": ((good + "nan,100,1e-9\n").encode(), "digital_count"),
        "four-columns": ((good + "5,100,1e-9,7\n").encode(), "pm_"),
        "two-columns": ((good + "5,100\n").encode(), "pm_"),
        "a-word": ((good + "five,100,1e-9\n").encode(), "pm_"),
        "few-rows": ("\n".join(lines[:4]).encode(), "pm_"),
        "non-monotone": ((lines[0] + "\n" + "\n".join(f"{d},1,{1e-9 * (100 - d):e}" for d in range(1, 20)) + "\n").encode(),
                         "monotone"),
        "all-same-dn": ((lines[0] + "\n" + "5,1,1e-9\n" * 20).encode(), "distinct"),
        "huge-value": ((good + "5,100,1e300\n").encode(), "pm_"),
    }
    cases = []
    for name, (data, expect) in texts.items():
        f = inp / "csvs" / f"pm_{name}.csv"
        f.parent.mkdir(exist_ok=True)
        f.write_bytes(data)
        cases.append((f"csv:{name}", ["calibrate", "radiometric", str(inp / "fac.yaml"), "--measurements", str(f), "-o",
                                      str(out / "r.yaml"), "-q"], expect))
    cases.append(("csv:missing", ["calibrate", "radiometric", str(inp / "fac.yaml"), "--measurements",
                                  str(inp / "csvs" / "nope.csv"), "-o", str(out / "r.yaml"), "-q"], "nope.csv"))
    return cases


def _dataset_cases(tmp, inp, out):
    fac = str(inp / "fac.yaml")
    ds = inp / "ds"
    truth = "frames/000000.json"

    def edit_truth(edit):
        return lambda d: _edit_json(d / truth, edit)

    damages = {
        "truth-no-observer": (edit_truth(lambda j: j.pop("observer")), "observer"),
        "truth-no-camera": (edit_truth(lambda j: j.pop("camera")), "camera"),
        "truth-no-epoch": (edit_truth(lambda j: j.pop("epoch")), "epoch"),
        "truth-no-attitude": (edit_truth(lambda j: j.pop("attitude")), "attitude"),
        "truth-observer-a-list": (edit_truth(lambda j: j.update(observer=[1, 2, 3])), "observer"),
        "truth-position-short": (edit_truth(lambda j: j["observer"].update(position_km=[1, 2])), "position_km"),
        "truth-camera-a-string": (edit_truth(lambda j: j.update(camera="paper")), "camera"),
        "truth-epoch-garbage": (edit_truth(lambda j: j.update(epoch="yesterday")), "epoch"),
        "truth-not-json": (lambda d: (d / truth).write_text("{oops"), "000000.json"),
        "truth-empty": (lambda d: (d / truth).write_bytes(b""), "000000.json"),
        "truth-missing": (lambda d: (d / truth).unlink(), "000000.json"),
        "no-manifest": (lambda d: (d / "manifest.json").unlink(), "manifest.json"),
        "manifest-garbage": (lambda d: (d / "manifest.json").write_text("[]"), "manifest.json"),
        "png-truncated": (lambda d: (d / "frames/000000.png").write_bytes((d / "frames/000000.png").read_bytes()[:300]),
                          "000000.png"),
        "png-missing": (lambda d: (d / "frames/000000.png").unlink(), "000000.png"),
    }
    cases = []
    for name, (damage, expect) in damages.items():
        p = _variant(inp, ds, f"ds_{name}", damage)
        if not name.startswith("png-"):  # export reads the truth only
            cases.append((f"dataset:export:{name}", ["hil", "export", p, "--facility", fac, "-o", str(out / f"e_{name}"),
                                                     "-q"], expect))
        if name != "no-manifest":  # bench ip reads any folder of PNG + JSON frames
            cases.append((f"dataset:bench-ip:{name}", ["bench", "ip", p, "-o", str(out / f"ip_{name}"), "-q"], expect))
    # a folder of frames (no manifest): one JSON missing, one frame of another size
    lone = inp / "damaged" / "frames_lone"
    if not lone.exists():
        shutil.copytree(ds / "frames", lone / "frames")
        shutil.copy(ds / "frames" / "000000.png", lone / "frames" / "000001.png")
    cases.append(("frames:bench-ip:png-without-json", ["bench", "ip", str(lone), "-o", str(out / "ip_lone"), "-q"],
                  "000001.png"))
    mixed = inp / "damaged" / "frames_mixed"
    if not mixed.exists():
        shutil.copytree(ds / "frames", mixed / "frames")
        shutil.copy(inp / "ds512" / "frames" / "000000.png", mixed / "frames" / "000000.png")
    cases.append(("frames:bench-ip:another-size", ["bench", "ip", str(mixed), "-o", str(out / "ip_mixed"), "-q"],
                  "000000.png"))
    return cases


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    return build_world(tmp_path_factory)


@pytest.fixture(scope="module")
def catalogue(world):
    tmp, inp, out = world
    return _facility_cases(tmp, inp, out) + _patterns_cases(tmp, inp, out) + _csv_cases(tmp, inp, out) + _dataset_cases(tmp, inp, out)


def test_every_bad_input_file_gives_one_line_exit_2_and_leaves_the_inputs_alone(world, catalogue, capsys):
    """All cases in one test (one fixture build); every failure is listed, not only the first."""
    assert len(catalogue) >= 250, len(catalogue)  # the catalogue is large enough
    check_catalogue(world, catalogue, capsys)
