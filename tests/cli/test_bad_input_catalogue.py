"""The bad-input catalogue: every command, every kind of mistake, one line and exit 2.

Each case is a command line (with the files it needs: scene or recipe YAML, output paths, damaged
datasets) that a user could type. Each must end with exit code 2 (``dataset verify``: its
documented 1, the problems on stdout), exactly one line on stderr starting ``skynav: error:`` and
naming the key or path at fault, and no traceback. Commands run in this process through
``skynav.__main__.main`` (argparse's exit is caught), so the whole table takes seconds.
"""

from __future__ import annotations

import copy
import json
import os
import shutil
from pathlib import Path

import pytest
import yaml

from skynav.__main__ import main

GOOD_SCENE = {
    "epoch": "2027-02-01T00:00:00",
    "observer": {"position_km": [-128731399.4, 113269566.7, 51647643.2], "velocity_km_s": [-19.9093, -18.773, -8.1391]},
    "attitude": {"point_at": "mars"},
    "camera": {"preset": "paper", "width": 128, "height": 128},
}


def _set(d: dict, dotted: str, value):
    d = copy.deepcopy(d)
    node = d
    parts = dotted.split(".")
    for p in parts[:-1]:
        node = node.setdefault(p, {})
    if value is _DELETE:
        node.pop(parts[-1], None)
    else:
        node[parts[-1]] = value
    return d


_DELETE = object()

# (dotted key, bad value, text the error line must contain)
SCENE_MUTATIONS = [
    ("epoch", "2100-01-01T00:00:00", "de421.bsp covers"),
    ("epoch", "1800-01-01T00:00:00", "de421.bsp covers"),
    ("epoch", "yesterday", "epoch"),
    ("epoch", "2027-13-45", "epoch"),
    ("epoch", [2027, 1, 1], "epoch"),
    ("epoch", _DELETE, "epoch"),
    ("observer", "earth", "observer"),
    ("observer", _DELETE, "observer"),
    ("observer.position_km", [1, 2], "observer.position_km"),
    ("observer.position_km", "far", "observer.position_km"),
    ("observer.position_km", [1e30, 0, 0], "observer.position_km"),
    ("observer.position_km", [".nan", 0, 0], "observer.position_km[0]"),
    ("observer.position_km", [0, "x", 0], "observer.position_km[1]"),
    ("observer.position_km", [0, 0, True], "observer.position_km[2]"),
    ("observer.position_km", _DELETE, "observer"),
    ("observer.velocity_km_s", [400000, 0, 0], "observer.velocity_km_s"),
    ("observer.velocity_km_s", [1e10, 1e10, 0], "observer.velocity_km_s"),
    ("observer.velocity_km_s", [1, 2, 3, 4], "observer.velocity_km_s"),
    ("observer.velocity_km_s", None, "observer.velocity_km_s"),
    ("observer.relative_to", "pluto", "pluto"),
    ("observer.relative_to", 3, "3"),
    ("observer.speed", 3, "observer.speed"),
    ("attitude", "mars", "attitude"),
    ("attitude.point_at", "sun", "attitude.point_at"),
    ("attitude.point_at", "pluto", "pluto"),
    ("attitude.point_at", ["mars"], "attitude.point_at"),
    ("attitude.point_at", {"body": "mars"}, "attitude.point_at"),
    ("attitude.point_at", 4, "attitude.point_at"),
    ("attitude.point_at", None, "attitude.point_at"),  # found by the fuzz test (a traceback before)
    ("attitude.ra_deg", 10.0, "attitude"),
    ("attitude.q_cam_icrs", [1, 0, 0, 0], "attitude"),
    ("attitude.roll_deg", 1, "attitude.roll_deg"),
    ("attitude.angular_velocity_deg_s", [1, 2], "attitude.angular_velocity_deg_s"),
    ("attitude.angular_velocity_deg_s", [1e30, 0, 0], "attitude.angular_velocity_deg_s"),
    ("attitude.angular_velocity_deg_s", "fast", "attitude.angular_velocity_deg_s"),
    ("attitude.twist_deg", "a lot", "attitude.twist_deg"),
    ("attitude.twist_deg", ".inf", "attitude.twist_deg"),
    ("camera", "paper", "camera"),
    ("camera", ["paper"], "camera"),
    ("camera.preset", "hubble", "camera.preset"),
    ("camera.preset", {"name": "paper"}, "camera.preset"),
    ("camera.preset", ["paper"], "camera.preset"),
    ("camera.preset", 1, "camera.preset"),
    ("camera.width", 0, "camera.width"),
    ("camera.width", -5, "camera.width"),
    ("camera.width", 12.5, "camera.width"),
    ("camera.width", "wide", "camera.width"),
    ("camera.width", 100000000, "camera.width"),
    ("camera.height", 0, "camera.height"),
    ("camera.height", 1e9, "camera.height"),
    ("camera.width", 100000, "camera.width x camera.height"),  # with height 100000 below
    ("camera.fov_deg", 0, "camera.fov_deg"),
    ("camera.fov_deg", 180, "camera.fov_deg"),
    ("camera.fov_deg", -20, "camera.fov_deg"),
    ("camera.fov_deg", "wide", "camera.fov_deg"),
    ("camera.focal_length_mm", 1e30, "camera.focal_length_mm"),
    ("camera.focal_length_mm", 0, "camera.focal_length_mm"),
    ("camera.focal_length_mm", -50, "camera.focal_length_mm"),
    ("camera.pixel_pitch_um", 0, "camera.pixel_pitch_um"),
    ("camera.pixel_pitch_um", 1e9, "camera.pixel_pitch_um"),
    ("camera.pixel_pitch_y_um", -1, "camera.pixel_pitch_y_um"),
    ("camera.f_number", 0, "camera.f_number"),
    ("camera.f_number", -2, "camera.f_number"),
    ("camera.exposure_s", 1e300, "camera.exposure_s"),
    ("camera.exposure_s", 0, "camera.exposure_s"),
    ("camera.exposure_s", -0.1, "camera.exposure_s"),
    ("camera.exposure_s", "long", "camera.exposure_s"),
    ("camera.defocus_sigma_px", -1, "camera.defocus_sigma_px"),
    ("camera.K", [[1, 0, 0], [0, 1, 0], [0, 0, 1]], "camera.K"),
    ("camera.limiting_v_mag", 6, "visibility.limiting_v_mag"),
    ("camera.sun_exclusion_deg", 30, "visibility.sun_exclusion_deg"),
    ("camera.cosmic_rays_per_frame", 2, "render.cosmic_rays_per_frame"),
    ("camera.colour", "red", "camera.colour"),
    ("camera.distortion", 0.1, "camera.distortion"),
    ("camera.distortion.k9", 0.1, "camera.distortion.k9"),
    ("camera.distortion.k1", "big", "camera.distortion.k1"),
    ("camera.sensor", 12, "camera.sensor"),
    ("camera.sensor.bit_depth", 24, "bit_depth"),
    ("camera.sensor.bit_depth", 0, "bit_depth"),
    ("camera.sensor.bit_depth", 8.5, "camera.sensor.bit_depth"),
    ("camera.sensor.full_well_e", 1e-30, "camera.sensor.full_well_e"),
    ("camera.sensor.full_well_e", 0, "full_well_e"),
    ("camera.sensor.full_well_e", -100, "full_well_e"),
    ("camera.sensor.read_noise_e", -1, "read_noise_e"),
    ("camera.sensor.blooming", "yes", "camera.sensor.blooming"),
    ("camera.sensor.gain", 1, "camera.sensor.gain"),
    ("camera.response", {"wavelengths_nm": [500], "qe_t": [0.5]}, "camera.response"),
    ("camera.response", {"wavelengths_nm": [600, 500], "qe_t": [0.5, 0.5]}, "camera.response.wavelengths_nm"),
    ("camera.response", {"wavelengths_nm": [500, 600], "qe_t": [0.5, 1.5]}, "camera.response.qe_t"),
    ("visibility", 7, "visibility"),
    ("visibility.limiting_v_mag", "dim", "visibility.limiting_v_mag"),
    ("visibility.sun_exclusion_deg", 200, "visibility.sun_exclusion_deg"),
    ("visibility.sun_exclusion_deg", -1, "visibility.sun_exclusion_deg"),
    ("visibility.moon", 1, "visibility.moon"),
    ("render", [], "render"),
    ("render.catalog_limiting_v_mag", 30, "render.catalog_limiting_v_mag"),
    ("render.catalog_limiting_v_mag", "all", "render.catalog_limiting_v_mag"),
    ("render.star_mag_limit", 8, "render.catalog_limiting_v_mag"),
    ("render.cosmic_rays_per_frame", 1e7, "render.cosmic_rays_per_frame"),
    ("render.cosmic_rays_per_frame", -1, "render.cosmic_rays_per_frame"),
    ("render.resolved_threshold_px", 0, "render.resolved_threshold_px"),
    ("render.seed", -3, "render.seed"),
    ("render.seed", 1.5, "render.seed"),
    ("render.noise", False, "render.noise"),
    ("observer", {"relative_to": "earth", "position_km": [0, 0, 0], "velocity_km_s": [0, 0, 0]}, "inside earth"),
    ("observer", {"relative_to": "sun", "position_km": [1000, 0, 0], "velocity_km_s": [0, 0, 0]}, "inside sun"),
    ("observer", {"relative_to": "mars", "position_km": [100, 0, 0], "velocity_km_s": [0, 0, 0]}, "inside mars"),
    ("observer", {"relative_to": "moon", "position_km": [0, 0, 1000], "velocity_km_s": [0, 0, 0]}, "inside moon"),
    ("observer", {"relative_to": "jupiter", "position_km": [1e12, 0, 0], "velocity_km_s": [0, 0, 0]},
     "observer.position_km"),
    ("epcoh", "2027-01-01", "epcoh"),
]

SCENE_TEXT = yaml.safe_dump(GOOD_SCENE, sort_keys=False)
RAW_SCENES = [  # (id, file text, expected)
    ("malformed-yaml", SCENE_TEXT.replace("point_at: mars", "point_at: [mars"), "malformed YAML"),
    ("tab-indent", SCENE_TEXT.replace("  point_at", "\tpoint_at"), "malformed YAML"),
    ("duplicate-key", SCENE_TEXT + "attitude:\n  point_at: jupiter\n", "duplicate key 'attitude'"),
    ("duplicate-nested-key", SCENE_TEXT.replace("  point_at: mars\n", "  point_at: mars\n  point_at: venus\n"),
     "duplicate key 'point_at'"),
    ("empty-file", "", "a scene file must be a mapping"),
    ("a-list", "- 1\n- 2\n", "a scene file must be a mapping"),
    ("a-string", "hello\n", "a scene file must be a mapping"),
    ("binary", "\x00\x01\x02", "malformed YAML"),
    ("sci-exposure-huge", SCENE_TEXT.replace("height: 128", "height: 128\n  exposure_s: 1e300"), "camera.exposure_s"),
    ("sci-focal-huge", SCENE_TEXT.replace("height: 128", "height: 128\n  focal_length_mm: 1e30"), "camera.focal_length_mm"),
    ("sci-full-well-tiny", SCENE_TEXT.replace("height: 128", "height: 128\n  sensor: {full_well_e: 1e-30}"),
     "camera.sensor.full_well_e"),
]


def _scene_cases(tmp):
    cases = []
    for i, (key, value, expect) in enumerate(SCENE_MUTATIONS):
        d = _set(GOOD_SCENE, key, value)
        if key == "camera.width" and value == 100000:
            d["camera"]["height"] = 100000
        f = tmp / f"scene_{i}.yaml"
        f.write_text(yaml.safe_dump(d))
        cmd = "render" if i % 3 == 0 else "scene"  # both commands read scene files the same way
        argv = [cmd, str(f)] + (["-o", str(tmp / "out_render")] if cmd == "render" else [])
        cases.append((f"scene:{key}={value!r}"[:80], argv, expect, 2))
    for name, text, expect in RAW_SCENES:
        f = tmp / f"raw_{name}.yaml"
        f.write_bytes(text.encode("utf-8"))
        cases.append((f"scene-file:{name}", ["scene", str(f)], expect, 2))
    cases.append(("scene:missing-file", ["scene", str(tmp / "nope.yaml")], "nope.yaml", 2))
    cases.append(("scene:a-folder", ["scene", str(tmp)], str(tmp), 2))
    return cases


SMALL_RECIPE = {"kind": "montecarlo", "frames": 2, "seed": 5, "camera": {"preset": "paper", "width": 64, "height": 64},
                "catalog_limiting_v_mag": 6.0,
                "montecarlo": {"keep": []}}

RECIPE_MUTATIONS = [
    ("kind", "random", "kind"),
    ("kind", _DELETE, "kind"),
    ("frames", 0, "frames"),
    ("frames", -2, "frames"),
    ("frames", 2.5, "frames"),
    ("frames", "many", "frames"),
    ("frames", 1e12, "frames"),
    ("frames", _DELETE, "frames"),
    ("seed", -1, "seed"),
    ("seed", "abc", "seed"),
    ("seed", _DELETE, "seed"),
    ("seed", 1e30, "seed"),
    ("camera", "paper", "camera"),
    ("camera.preset", {"x": 1}, "camera.preset"),
    ("camera.preset", ["paper"], "camera.preset"),
    ("camera.width", 0, "camera.width"),
    ("camera.exposure_s", -1, "camera.exposure_s"),
    ("camera.K", [[1, 0, 0], [0, 1, 0], [0, 0, 1]], "camera.K"),
    ("camera.focal_length_mm", 1e30, "camera.focal_length_mm"),
    ("camera.sensor.full_well_e", 1e-30, "camera.sensor.full_well_e"),
    ("visibility.sun_exclusion_deg", 400, "visibility.sun_exclusion_deg"),
    ("visibility.limiting_v_mag", "x", "visibility.limiting_v_mag"),
    ("catalog_limiting_v_mag", 40, "catalog_limiting_v_mag"),
    ("catalog_limiting_v_mag", "x", "catalog_limiting_v_mag"),
    ("star_mag_limit", 8, "catalog_limiting_v_mag"),
    ("formats", ["png"], "formats"),
    ("formats", ["gif", "json"], "formats"),
    ("formats", [], "formats"),
    ("formats", ["json", "json"], "formats"),
    ("formats", 3, "formats"),
    ("colour", 1, "colour"),
    ("montecarlo", 3, "montecarlo"),
    ("montecarlo.position_sigma_au", [1, 2], "montecarlo.position_sigma_au"),
    ("montecarlo.position_sigma_au", [-1, 1, 1], "montecarlo.position_sigma_au"),
    ("montecarlo.epoch_start_tdb", "soon", "montecarlo.epoch_start_tdb"),
    ("montecarlo.epoch_end_tdb", "2100-01-01T00:00:00", "montecarlo.epoch_end_tdb"),
    ("montecarlo.keep", ["pretty"], "montecarlo.keep"),
    ("montecarlo.max_draws_per_frame", 0, "montecarlo.max_draws_per_frame"),
    ("montecarlo.velocity", "warp", "montecarlo.velocity"),
    ("montecarlo.attitude_frame", "galactic", "montecarlo.attitude_frame"),
    ("montecarlo.min_sun_distance_au", -1, "montecarlo.min_sun_distance_au"),
    ("montecarlo.bogus", 1, "montecarlo.bogus"),
]

RAW_RECIPES = [
    ("not-a-mapping", "- montecarlo\n", "recipe"),
    ("malformed", "kind: montecarlo\nframes: [1\n", "recipe"),
    ("duplicate-key", "kind: montecarlo\nseed: 1\nseed: 2\nframes: 2\n", "duplicate key 'seed'"),
    ("empty", "", "recipe"),
    ("scenes-empty", "kind: scenes\nseed: 1\nscenes: []\n", "scenes"),
    ("scenes-not-list", "kind: scenes\nseed: 1\nscenes: 3\n", "scenes"),
    ("scenes-bad-item", "kind: scenes\nseed: 1\nscenes:\n- {epoch: '2027-01-01', attitude: {point_at: sun},"
                        " observer: {position_km: [1.5e8, 0, 0], velocity_km_s: [0, 30, 0]}}\n", "scenes[0]"),
    ("scenes-per-scene-seed", "kind: scenes\nseed: 1\nscenes:\n- {epoch: '2027-01-01', render: {seed: 3},"
                              " observer: {position_km: [1.5e8, 0, 0], velocity_km_s: [0, 30, 0]}}\n", "scenes[0]"),
    ("scenes-cosmic-flood", "kind: scenes\nseed: 1\nscenes:\n- {epoch: '2027-01-01', render: {cosmic_rays_per_frame: 1e7},"
                            " observer: {position_km: [1.5e8, 0, 0], velocity_km_s: [0, 30, 0]}}\n", "cosmic_rays_per_frame"),
    ("sequence-bad-legs", "kind: sequence\nseed: 1\nsequence: {legs: 0}\n", "sequence.legs"),
    ("sequence-bad-window", "kind: sequence\nseed: 1\nsequence: {departure_window_tdb: [x, y]}\n", "sequence.departure_window_tdb"),
    ("sequence-bad-key", "kind: sequence\nseed: 1\nsequence: {warp: 9}\n", "sequence.warp"),
]


def _recipe_cases(tmp):
    cases = []
    for i, (key, value, expect) in enumerate(RECIPE_MUTATIONS):
        f = tmp / f"recipe_{i}.yaml"
        f.write_text(yaml.safe_dump(_set(SMALL_RECIPE, key, value)))
        out = tmp / f"ds_recipe_{i}"
        cases.append((f"recipe:{key}={value!r}"[:80], ["dataset", "generate", str(f), "-o", str(out), "-q"], expect, 2))
    for name, text, expect in RAW_RECIPES:
        f = tmp / f"raw_recipe_{name}.yaml"
        f.write_text(text)
        cases.append((f"recipe-file:{name}", ["dataset", "generate", str(f), "-o", str(tmp / f"ds_{name}"), "-q"],
                      expect, 2))
    cases.append(("recipe:missing-file", ["dataset", "generate", str(tmp / "none.yaml"), "-o", str(tmp / "x")],
                  "none.yaml", 2))
    return cases


def _flag_cases(tmp, good_scene, ds):
    out = str(tmp / "flag_out")
    return [(f"flags:{' '.join(a)}"[:80], a, e, 2) for a, e in [
        (["render", good_scene, "--seed", "-1", "-o", out], "--seed"),
        (["render", good_scene, "--seed", "abc", "-o", out], "--seed"),
        (["render", good_scene, "--backend", "opencl", "-o", out], "--backend"),
        (["render", good_scene, "--bogus"], "--bogus"),
        (["render", good_scene, "--name", "../../../x", "-o", out], "--name"),
        (["render", good_scene, "--name", "", "-o", out], "--name"),
        (["render", good_scene, "--name", ".hidden", "-o", out], "--name"),
        (["render", good_scene, "--name", "a/b", "-o", out], "--name"),
        (["render", "hubble-deep-field"], "hubble-deep-field"),
        (["scene", good_scene, "extra"], "extra"),
        (["teleport"], "teleport"),
        (["dataset", "generate", "montecarlo", "-o", out, "--count", "0"], "--count"),
        (["dataset", "generate", "montecarlo", "-o", out, "--count", "-2"], "--count"),
        (["dataset", "generate", "montecarlo", "-o", out, "--count", "ten"], "--count"),
        (["dataset", "generate", "montecarlo", "-o", out, "--workers", "0"], "--workers"),
        (["dataset", "generate", "montecarlo", "-o", out, "--seed", "-4"], "--seed"),
        (["dataset", "generate", "montecarlo"], "--output"),
        (["dataset", "generate", "nope-preset", "-o", out], "nope-preset"),
        (["dataset", "generate", "montecarlo", "-o", str(tmp / "dask"), "--count", "1", "-q",
          "--dask-scheduler", "tcp://127.0.0.1:9"], "--dask-scheduler tcp://127.0.0.1:9"),
        (["dataset", "generate", "montecarlo", "-o", str(tmp / "dask2"), "--count", "1", "-q",
          "--dask-scheduler", "not an address"], "--dask-scheduler"),
        (["dataset", "preview", ds, "--count", "0"], "--count"),
        (["dataset", "preview", ds, "--count", "-2"], "--count"),
        (["dataset", "preview", ds, "--columns", "0"], "--columns"),
        (["dataset", "verify"], "DATASET"),
        (["dataset", "info"], "DATASET"),
        (["dataset", "explode", ds], "explode"),
    ]]


def _path_cases(tmp, good_scene, ds):
    a_file = tmp / "a_file.txt"
    a_file.write_text("x")
    ro = tmp / "read_only"
    ro.mkdir(exist_ok=True)
    cases = []
    for label, out in [("existing-file", a_file), ("under-a-file", a_file / "sub"), ("in-proc", Path("/proc/skynav")),
                       ("in-sys", Path("/sys/skynav")), ("in-dev", Path("/dev/skynav/x"))]:
        cases.append((f"path:render:{label}", ["render", good_scene, "-o", str(out)], str(out), 2))
        png = out if label == "existing-file" else out / "p.png"
        if label == "existing-file":
            png = tmp  # a folder given as the PNG
        cases.append((f"path:preview:{label}", ["dataset", "preview", ds, "-o", str(png)],
                      str(png if label == "existing-file" else out), 2))
        cases.append((f"path:generate:{label}", ["dataset", "generate", "montecarlo", "-o", str(out), "-q"], str(out), 2))
    cases.append(("path:preview:hidden-name", ["dataset", "preview", ds, "-o", str(tmp / ".p.png")], ".p.png", 2))
    return cases


def _damaged_cases(tmp, ds):
    """Damaged dataset folders: info and preview exit 2 with one line; verify exits 1."""
    cases = []

    def variant(name, damage):
        d = tmp / f"dmg_{name}"
        if not d.exists():
            shutil.copytree(ds, d)
            damage(d)
        return str(d)

    damages = {
        "no-manifest": (lambda d: (d / "manifest.json").unlink(), "manifest.json"),
        "manifest-not-json": (lambda d: (d / "manifest.json").write_text("{not json"), "manifest.json"),
        "manifest-empty": (lambda d: (d / "manifest.json").write_bytes(b""), "manifest.json"),
        "manifest-wrong-schema": (lambda d: (d / "manifest.json").write_text('{"schema": "other/9"}'), "manifest.json"),
        "manifest-a-list": (lambda d: (d / "manifest.json").write_text("[1, 2]"), "manifest.json"),
        "manifest-no-recipe": (lambda d: (d / "manifest.json").write_text(json.dumps(
            {k: v for k, v in json.loads((d / "manifest.json").read_text()).items() if k != "recipe"})), "manifest.json"),
        "incomplete": (lambda d: (d / "manifest.json").write_text(
            (d / "manifest.json").read_text().replace('"complete": true', '"complete": false')), "incomplete"),
    }
    for name, (damage, expect) in damages.items():
        p = variant(name, damage)
        if name != "incomplete":  # info summarises an incomplete dataset (it says so): not an error
            cases.append((f"damaged:info:{name}", ["dataset", "info", p], expect, 2))
        cases.append((f"damaged:preview:{name}", ["dataset", "preview", p, "-o", str(tmp / f"pv_{name}.png")], expect, 2))
        cases.append((f"damaged:verify:{name}", ["dataset", "verify", p, "-q"], None, 1))
    frame_damages = {
        "png-0-bytes": (lambda d: (d / "frames" / "000000.png").write_bytes(b""), "000000.png"),
        "png-garbage": (lambda d: (d / "frames" / "000000.png").write_bytes(b"\x89PNG\r\n\x1a\nxxxx"), "000000.png"),
        "json-truncated": (lambda d: (d / "frames" / "000000.json").write_bytes(b'{"schema": "skynav.fr'), "000000.json"),
        "json-0-bytes": (lambda d: (d / "frames" / "000000.json").write_bytes(b""), "000000.json"),
        "frame-missing": (lambda d: (d / "frames" / "000000.png").unlink(), "000000.png"),
    }
    for name, (damage, expect) in frame_damages.items():
        p = variant(name, damage)
        cases.append((f"damaged:preview:{name}", ["dataset", "preview", p, "-o", str(tmp / f"pv_{name}.png")], expect, 2))
        cases.append((f"damaged:verify:{name}", ["dataset", "verify", p, "-q"], None, 1))
    index_bad = variant("index-garbage", lambda d: (d / "index.csv").write_bytes(b"\xff\xfe\x00\x01"))
    cases.append(("damaged:info:index-garbage", ["dataset", "info", index_bad], "index.csv", 2))
    cases.append(("damaged:verify:index-garbage", ["dataset", "verify", index_bad, "-q"], None, 1))
    for cmd in (["dataset", "info"], ["dataset", "preview"]):
        cases.append((f"damaged:{cmd[1]}:no-folder", cmd + [str(tmp / "no_such_ds")], "no_such_ds", 2))
        cases.append((f"damaged:{cmd[1]}:a-file", cmd + [str(tmp / "a_file.txt")], "a_file.txt", 2))
    cases.append(("damaged:generate:other-dataset", ["dataset", "generate", "montecarlo", "-o", ds, "-q", "--count", "2"],
                  "holds a different dataset", 2))
    return cases


@pytest.fixture(scope="module")
def catalogue(tmp_path_factory):
    from skynav.datasets import generate

    tmp = tmp_path_factory.mktemp("catalogue")
    good = tmp / "good.yaml"
    good.write_text(SCENE_TEXT)
    ds = tmp / "good_ds"
    generate(SMALL_RECIPE, ds, workers=1, progress=False)
    (tmp / "a_file.txt").write_text("x")
    cases = (_scene_cases(tmp) + _recipe_cases(tmp) + _flag_cases(tmp, str(good), str(ds))
             + _path_cases(tmp, str(good), str(ds)) + _damaged_cases(tmp, str(ds)))
    return cases


def _run(argv, capsys):
    try:
        code = main(argv)
    except SystemExit as exc:  # argparse
        code = exc.code
    out, err = capsys.readouterr()
    return code, out, err


def test_catalogue_is_large_enough(catalogue):
    assert len(catalogue) >= 150, len(catalogue)


def test_every_bad_input_gives_one_line_and_the_documented_exit_code(catalogue, capsys):
    """All cases in one test (one fixture build); every failure is listed, not only the first."""
    failures = []
    for ident, argv, expect, want_code in catalogue:
        code, out, err = _run(argv, capsys)
        lines = [ln for ln in err.splitlines() if ln.strip()]
        if "Traceback" in err or "Traceback" in out:
            failures.append(f"{ident}: traceback")
        elif code != want_code:
            failures.append(f"{ident}: exit {code}, want {want_code}; {err.strip()[:200]}")
        elif want_code == 2 and (len(lines) != 1 or not lines[0].startswith("skynav: error:")):
            failures.append(f"{ident}: {len(lines)} stderr lines: {err.strip()[:300]}")
        elif want_code == 2 and expect not in lines[0]:
            failures.append(f"{ident}: {expect!r} not named in: {lines[0]}")
        elif want_code == 1 and (lines or "FAILED" not in out.splitlines()[0]):
            failures.append(f"{ident}: verify said {out.strip()[:200]!r}, stderr {err.strip()[:200]!r}")
    assert not failures, f"{len(failures)} of {len(catalogue)} cases:\n" + "\n".join(failures)


@pytest.mark.parametrize("key, value, expect", [
    ("observer", {"relative_to": "earth", "position_km": [0, 0, 0], "velocity_km_s": [0, 0, 0]}, "inside earth"),
    ("attitude.point_at", "sun", "attitude.point_at"),
    ("camera.width", 100000, "camera.width x camera.height"),
])
def test_in_a_real_process_stderr_is_one_line_too(tmp_path, key, value, expect):
    """A few catalogue cases in a fresh interpreter: warnings printed by numpy or at interpreter
    exit (which the in-process table cannot see) must not add lines."""
    import subprocess
    import sys

    d = _set(GOOD_SCENE, key, value)
    if key == "camera.width":
        d["camera"]["height"] = 100000
    f = tmp_path / "s.yaml"
    f.write_text(yaml.safe_dump(d))
    p = subprocess.run([sys.executable, "-m", "skynav", "scene", str(f)], capture_output=True, text=True, timeout=120)
    lines = p.stderr.strip().splitlines()
    assert p.returncode == 2 and len(lines) == 1 and expect in lines[0], p.stderr
