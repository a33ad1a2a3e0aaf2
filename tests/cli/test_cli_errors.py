"""The command line: one clear line and exit code 2 for a user's mistake, never a traceback."""

import subprocess
import sys

import pytest

from skynav.cli import main

GOOD = """
epoch: "2027-02-01T00:00:00"
observer:
  position_km: [-128731399.4, 113269566.7, 51647643.2]
  velocity_km_s: [-19.9093, -18.773, -8.1391]
attitude: {point_at: mars}
camera: {preset: paper}
"""


def run(argv, capsys):
    code = main(argv)
    out, err = capsys.readouterr()
    return code, out, err


@pytest.mark.parametrize(
    "text, expected",
    [
        (GOOD.replace("2027-02-01", "2100-01-01"), "de421.bsp covers"),
        (GOOD.replace("point_at: mars", "point_at: pluto"), "unknown body 'pluto'"),
        (GOOD.replace("{preset: paper}", "{preset: paper, exposure_s: -0.1}"), "camera.exposure_s"),
        (GOOD.replace("attitude: {point_at: mars}", "attitude: {point_at: mars"), "malformed YAML"),
        (GOOD.replace("epoch:", "epcoh:"), "epcoh"),
        (GOOD.replace("{preset: paper}", "{preset: paper, sensor: {bit_depth: 24}}"), "sensor.bit_depth"),
        (GOOD.replace("{preset: paper}", "{preset: paper, limiting_v_mag: 6}"), "write it as visibility.limiting_v_mag"),
        (GOOD.replace("{preset: paper}", "{preset: paper, sun_exclusion_deg: 30}"), "write it as visibility.sun_exclusion_deg"),
        (GOOD.replace("{preset: paper}", "{preset: paper, cosmic_rays_per_frame: 2}"), "write it as render.cosmic_rays_per_frame"),
        (GOOD + "render: {star_mag_limit: 8}\n", "write it as render.catalog_limiting_v_mag"),
        (GOOD.replace("position_km: [-128731399.4, 113269566.7, 51647643.2]",
                      "relative_to: earth\n  position_km: [1000.0, 0.0, 0.0]"), "inside earth"),
    ],
    ids=["epoch-outside-de421", "unknown-body", "negative-exposure", "malformed-yaml", "unknown-key", "bit-depth",
         "moved-limiting-v-mag", "moved-sun-exclusion", "moved-cosmic-rays", "moved-star-mag-limit", "inside-earth"],
)
def test_bad_input_gives_one_line_and_exit_2(tmp_path, capsys, text, expected):
    f = tmp_path / "scene.yaml"
    f.write_text(text)
    code, out, err = run(["scene", str(f)], capsys)
    assert code == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("skynav: error:"), err
    assert expected in lines[0]
    assert "Traceback" not in err


def test_missing_file(capsys):
    code, _, err = run(["scene", "no/such/file.yaml"], capsys)
    assert code == 2 and "no such scene file" in err


def test_entry_point_exit_code_and_version(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text(GOOD.replace("point_at: mars", "point_at: vulcan"))
    p = subprocess.run([sys.executable, "-m", "skynav", "scene", str(bad)], capture_output=True, text=True)
    assert p.returncode == 2 and p.stderr.count("\n") == 1 and "vulcan" in p.stderr
    v = subprocess.run([sys.executable, "-m", "skynav", "--version"], capture_output=True, text=True)
    assert v.returncode == 0 and v.stdout.startswith("skynav ")


def test_help_on_every_command(capsys):
    for argv in (["--help"], ["scene", "--help"], ["render", "--help"]):
        with pytest.raises(SystemExit) as exc:
            main(argv)
        assert exc.value.code == 0
    assert "render" in capsys.readouterr().out


def test_render_default_writes_viewable_png_with_a_visible_planet(tmp_path, capsys):
    from skynav.datasets.frame_files import read_png
    from skynav.datasets.truth_schema import read_truth_json, validate_truth

    code = main(["render", "-o", str(tmp_path), "--backend", "numpy"])
    out = capsys.readouterr().out
    assert code == 0 and "mars" in out
    dn = read_png(tmp_path / "frame.png")
    truth = read_truth_json(tmp_path / "frame.json")
    assert validate_truth(truth) == []
    mars = next(b for b in truth["bodies"] if b["name"] == "mars")
    assert mars["visible"] and mars["in_fov"]
    x, y = (int(round(c)) for c in mars["xy"])
    assert dn[y, x] > 100  # the planet stands out of the dark sky (8-bit DN)
    assert (tmp_path / "frame.exr").is_file()


def test_scene_prints_elongation_and_the_visibility_rule(tmp_path, capsys):
    """`skynav scene` names the two Sun angles apart and follows the file's visibility section."""
    code, out, _ = run(["scene"], capsys)
    assert code == 0
    assert "deg from the boresight (exclusion 20 deg; visible: V <= 7)" in out
    assert "elong deg" in out
    mars = next(line for line in out.splitlines() if line.startswith("mars "))
    assert "visible" in mars
    f = tmp_path / "scene.yaml"
    f.write_text(GOOD + "visibility: {limiting_v_mag: -3.0, sun_exclusion_deg: 25}\n")
    code, out, _ = run(["scene", str(f)], capsys)
    assert code == 0 and "exclusion 25 deg; visible: V <= -3" in out
    mars = next(line for line in out.splitlines() if line.startswith("mars "))
    assert "visible" not in mars and "in_fov" in mars


def test_render_reads_cosmic_rays_per_frame_from_the_render_section(tmp_path, capsys):
    import json

    f = tmp_path / "scene.yaml"
    f.write_text(GOOD.replace("{preset: paper}", "{preset: paper, width: 64, height: 64}")
                 + "render: {cosmic_rays_per_frame: 0.0, seed: 3}\n")
    code, out, _ = run(["render", str(f), "-o", str(tmp_path), "--backend", "numpy"], capsys)
    assert code == 0 and "0 cosmic rays" in out
    truth = json.loads((tmp_path / "frame.json").read_text())
    assert truth["render"]["cosmic_rays_per_frame"] == 0.0 and truth["cosmic_rays"] == []
    assert "cosmic_rays_per_frame" not in truth["camera"]
    assert truth["visibility"] == {"limiting_v_mag": 7.0, "sun_exclusion_deg": 20.0}
