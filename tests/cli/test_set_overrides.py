"""``--set KEY.SUB=VALUE`` on render, dataset generate, hil export and bench ip; ``dataset recipe``.

Real renders at 128 x 128 px and real files; bad overrides give one line and exit 2.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from skynav.cli import main
from skynav.datasets.frame_files import read_exr

SMALL = ["--set", "camera.width=128", "--set", "camera.height=128"]
NO_RAYS = ["--set", "render.cosmic_rays_per_frame=0"]


def _render(tmp_path, name, *extra):
    out = tmp_path / name
    assert main(["render", "-o", str(out), "--no-noise", *SMALL, *NO_RAYS, *extra]) == 0
    return json.loads((out / "frame.json").read_text()), read_exr(out / "frame.exr")["electrons"].astype(np.float64)


def test_render_set_exposure_changes_the_exposure_and_the_truth(tmp_path, capsys):
    base_truth, base_e = _render(tmp_path, "base")  # the default scene: 0.4 s
    truth, e = _render(tmp_path, "short", "--set", "camera.exposure_s=0.2")
    assert base_truth["camera"]["exposure_s"] == 0.4
    assert truth["camera"]["exposure_s"] == 0.2
    assert truth["cosmic_rays"] == []
    stars = {s["hip"]: s["electrons"] for s in truth["stars"]}
    base = {s["hip"]: s["electrons"] for s in base_truth["stars"]}
    assert stars and stars.keys() == base.keys()
    for hip, el in stars.items():  # signal = rate x exposure, the same rate (float64 products)
        assert el == pytest.approx(0.5 * base[hip], rel=1e-9)
    # the image: the PSF stamps cut 1e-6 of each source's flux whatever its brightness
    assert e.sum() == pytest.approx(0.5 * base_e.sum(), rel=1e-5)


def test_set_value_is_yaml_and_later_wins(tmp_path):
    truth, _ = _render(tmp_path, "a", "--set", "camera.exposure_s=2e-1", "--set", "camera={preset: paper, width: 96, "
                       "height: 64, exposure_s: 0.1}")
    assert (truth["camera"]["width"], truth["camera"]["height"], truth["camera"]["exposure_s"]) == (96, 64, 0.1)


def test_scene_file_override_leaves_the_file_alone(tmp_path):
    import shutil
    from pathlib import Path

    src = Path(__file__).resolve().parents[2] / "docs" / "examples" / "default_scene.yaml"
    scene = tmp_path / "scene.yaml"
    shutil.copy(src, scene)
    before = scene.read_bytes()
    out = tmp_path / "out"
    assert main(["render", str(scene), "-o", str(out), *SMALL, *NO_RAYS, "--set", "camera.exposure_s=0.2"]) == 0
    assert json.loads((out / "frame.json").read_text())["camera"]["exposure_s"] == 0.2
    assert scene.read_bytes() == before


BAD = [
    (["--set", "camera.exposre_s=0.2"], "camera.exposre_s = 0.2 is not allowed; expected no such key; allowed keys:"),
    (["--set", "camera.exposure_s=-1"], "camera.exposure_s = -1.0 is not allowed"),
    (["--set", "camera.exposure_s=fast"], "camera.exposure_s = 'fast' is not allowed; expected a finite number"),
    (["--set", "camera.exposure_s"], "argument --set: 'camera.exposure_s': expected KEY.SUB=VALUE"),
    (["--set", "=1"], "expected KEY.SUB=VALUE"),
    (["--set", "camera..x=1"], "KEY: names and list indices joined by dots"),
    (["--set", "camera.exposure_s=[0.2"], "the VALUE is not valid YAML"),
    (["--set", "epoch.year=2027"], "--set epoch.year=2027: epoch is a string ('2027-02-01T00:00:00'), not a mapping"),
    (["--set", "render.seed=-3"], "render.seed = -3 is not allowed"),
]


def _run(argv) -> int:
    """main()'s exit code; argparse usage errors leave through SystemExit."""
    try:
        return main(argv)
    except SystemExit as exc:
        return exc.code


@pytest.mark.parametrize("args, says", BAD, ids=[a[1] for a, _ in BAD])
def test_bad_override_on_render_is_one_line_exit_2(tmp_path, capsys, args, says):
    rc = _run(["render", "-o", str(tmp_path / "out"), *args])
    err = capsys.readouterr().err
    assert rc == 2
    assert err.count("\n") == 1 and err.startswith("skynav: error: ") and says in err, err
    assert "Traceback" not in err
    assert not (tmp_path / "out").exists()  # refused before anything is written


def _one_line(capsys, rc, says):
    err = capsys.readouterr().err
    assert rc == 2 and err.count("\n") == 1 and err.startswith("skynav: error: ") and says in err, err


@pytest.fixture(scope="module")
def tiny_dataset(tmp_path_factory):
    root = tmp_path_factory.mktemp("ds") / "ds"
    assert main(["dataset", "generate", "montecarlo", "-o", str(root), "--count", "1", "--workers", "1", "-q",
                 *SMALL, *NO_RAYS, "--set", "seed=3"]) == 0
    return root


def test_dataset_generate_set(tiny_dataset):
    m = json.loads((tiny_dataset / "manifest.json").read_text())
    assert m["recipe"]["render"] == {"cosmic_rays_per_frame": 0.0}
    from skynav.scenes.camera import paper_camera

    # the size override keeps the paper camera's 20 deg field: the pitch follows, 1024 / 128 = 8 times
    pitch = paper_camera().pixel_pitch_um * 8.0
    assert m["recipe"]["camera"] == {"preset": "paper", "width": 128, "height": 128, "pixel_pitch_um": pitch}
    assert m["master_seed"] == 3
    assert json.loads((tiny_dataset / "frames" / "000000.json").read_text())["cosmic_rays"] == []


@pytest.mark.parametrize("args, says", [
    (["--set", "montecarlo.legs=3"], "montecarlo.legs = 3 is not allowed; expected no such key; allowed keys: attitude_frame"),
    (["--set", "render.cosmic_rays_per_frame=lots"], "render.cosmic_rays_per_frame = 'lots' is not allowed"),
    (["--set", "formats.5=png"], "--set formats.5=png: formats is a list of 3; give an index 0..2"),
])
def test_bad_override_on_dataset_generate(tmp_path, capsys, args, says):
    _one_line(capsys, main(["dataset", "generate", "montecarlo", "-o", str(tmp_path / "d"), *args]), says)
    assert not (tmp_path / "d").exists()


def test_hil_export_set_addresses_the_facility(tiny_dataset, tmp_path, capsys):
    out = tmp_path / "hx"
    from skynav.scenes.camera import paper_camera

    # the dataset's camera (128 px, the paper camera's 20 deg field) set on the facility: export refuses another
    cam = ["--set", "camera.width=128", "--set", "camera.height=128", "--set",
           f"camera.pixel_pitch_um={paper_camera().pixel_pitch_um * 8.0!r}"]
    assert main(["hil", "export", str(tiny_dataset), "--facility", "screen_small", "-o", str(out), "-q",
                 "--set", "screen.bit_depth=8", *cam]) == 0
    assert json.loads((out / "frames" / "000000.json").read_text())["facility"]["screen"]["bit_depth"] == 8
    assert "never calibrated" in capsys.readouterr().err  # the nominal facility's one warning line
    _one_line(capsys, main(["hil", "export", str(tiny_dataset), "--facility", "screen_small", "-o", str(tmp_path / "x"),
                            "--set", "screen.gama=2"]),
              "--set screen.gama=2: the facility has no key screen.gama; allowed keys in screen: bit_depth, height_px")
    _one_line(capsys, main(["hil", "export", str(tiny_dataset), "--facility", "screen_small", "-o", str(tmp_path / "x"),
                            "--set", "radiometric.parameters.gamma=steep"]),
              "radiometric.parameters.gamma = 'steep' is not allowed; expected a finite number")


def test_bench_ip_set_addresses_the_process_options(tiny_dataset, tmp_path, capsys):
    assert main(["bench", "ip", str(tiny_dataset), "-o", str(tmp_path / "rep"), "-q", "--position-sigma-km", "1e4",
                 "--set", "inlier_px=2.5", "--set", "n_max=10"]) == 0
    capsys.readouterr()
    _one_line(capsys, main(["bench", "ip", str(tiny_dataset), "-o", str(tmp_path / "r2"), "--set", "inliers=2"]),
              "--set inliers=2: ProcessOptions has no key inliers; allowed keys: T, T_max_iterations")
    _one_line(capsys, main(["bench", "ip", str(tiny_dataset), "-o", str(tmp_path / "r2"), "--set", "n_max=2.5"]),
              "--set n_max=2.5: ProcessOptions.n_max = 2.5 is not allowed; expected an integer")


def test_bench_ip_options_reach_the_pipeline(tiny_dataset):
    """max_spots=0 makes every frame 'too_many_spots': the options are the ones process_frame used."""
    from skynav.pipeline.process import ProcessOptions
    from skynav.pipeline.scoring import run_benchmark

    rows, _ = run_benchmark(tiny_dataset, sigmas_km=(1e4,), progress=False, options=ProcessOptions(max_spots=0))
    default, _ = run_benchmark(tiny_dataset, sigmas_km=(1e4,), progress=False)
    assert [r.status for r in rows] == ["too_many_spots"]
    assert default[0].status != "too_many_spots"


def test_dataset_recipe_writes_a_file_generate_reads(tmp_path, capsys):
    path = tmp_path / "r.yaml"
    assert main(["dataset", "recipe", "montecarlo", "-o", str(path)]) == 0
    text = path.read_text()
    assert "# mean cosmic-ray hits per frame" in text and "cosmic_rays_per_frame: 1.0" in text
    path.write_text(text.replace("cosmic_rays_per_frame: 1.0", "cosmic_rays_per_frame: 0"))
    out = tmp_path / "ds"
    assert main(["dataset", "generate", str(path), "-o", str(out), "--count", "1", "--workers", "1", "-q", *SMALL]) == 0
    assert json.loads((out / "frames" / "000000.json").read_text())["cosmic_rays"] == []
    capsys.readouterr()
    _one_line(capsys, main(["dataset", "recipe", "montecarlo", "-o", str(path)]), "exists; give another path, or --force")
    assert main(["dataset", "recipe", "sequence", "-o", str(path), "--force"]) == 0
    assert "kind: sequence" in path.read_text()


def test_scene_set_changes_what_is_printed(capsys):
    assert main(["scene", "--set", "camera.fov_deg=10", "--set", "camera.exposure_s=0.25"]) == 0
    first = capsys.readouterr().out.splitlines()[0]
    assert "FOV 10.00 deg, 250 ms" in first, first


# ----------------------------------------------------------------------------- size overrides keep the field
def _fov_deg(camera: dict, size_key: str = "width") -> float:
    """Edge-to-edge field from a truth record's size, pitch and focal length (pinhole geometry)."""
    half = 0.5 * camera[size_key] * camera["pixel_pitch_um"] * 1e-3 / camera["focal_length_mm"]
    return 2.0 * math.degrees(math.atan(half))


def test_a_size_override_keeps_the_20_deg_field_and_says_so(tmp_path, capsys):
    """The example of ``skynav render --help``: the paper camera at 256 x 256 px still sees 20 deg
    (it saw 5 deg when the pitch stayed), and one line on stderr says what changed."""
    out = tmp_path / "r"
    assert main(["render", "-o", str(out), "--no-noise", *NO_RAYS, "--set", "camera.width=256",
                 "--set", "camera.height=256"]) == 0
    note = [line for line in capsys.readouterr().err.splitlines() if "pixel pitch" in line]
    assert len(note) == 1 and note[0].startswith("skynav: --set camera.width=256 camera.height=256: the pixel pitch"), note
    assert "so the field is 20 x 20 deg" in note[0]
    cam = json.loads((out / "frame.json").read_text())["camera"]
    assert (cam["width"], cam["height"]) == (256, 256)
    assert _fov_deg(cam) == pytest.approx(20.0, abs=1e-9) and _fov_deg(cam, "height") == pytest.approx(20.0, abs=1e-9)


def test_a_size_override_with_the_pitch_keeps_the_pitch_and_quiet_says_nothing(tmp_path, capsys):
    from skynav.scenes.camera import paper_camera

    pitch = paper_camera().pixel_pitch_um
    assert main(["scene", "--set", "camera.width=256", "--set", "camera.height=256",
                 "--set", f"camera.pixel_pitch_um={pitch!r}"]) == 0
    got = capsys.readouterr()
    assert "FOV 5.05 deg" in got.out and "pixel pitch" not in got.err  # what was asked: the centre of the field
    assert main(["render", "-q", "-o", str(tmp_path / "q"), "--no-noise", *NO_RAYS, "--set", "camera.width=64",
                 "--set", "camera.height=64"]) == 0
    got = capsys.readouterr()
    assert got.err == "" and got.out == ""
    assert _fov_deg(json.loads((tmp_path / "q" / "frame.json").read_text())["camera"]) == pytest.approx(20.0, abs=1e-9)


def test_a_height_alone_keeps_the_pitch_and_says_the_new_field(capsys):
    assert main(["scene", "--set", "camera.height=512"]) == 0
    got = capsys.readouterr()
    assert "camera 1024x512, FOV 20.00 deg" in got.out
    assert "skynav: --set camera.height=512: the field is 20 x 10.08 deg (was 20 x 20 deg; the pixel pitch is kept)" in got.err
