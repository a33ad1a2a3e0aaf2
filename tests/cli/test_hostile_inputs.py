"""Hostile inputs found from outside the project's own tests: each one line and a clean exit.

The classes: a manifest with a wrong type (a count that is not an integer, a number where a list
belongs); a frame truth with a wrong type; an EXR with no parts (or no ``electrons``, a deep image,
another size); a manifest that says 0 frames; Ctrl-C during ``hil export`` (one worker and two);
``render --hil ''``; ``render --hil FACILITY --fits``. The command line says one line
``skynav: error: ...`` and exits 2 (130 for Ctrl-C); the Python API raises skynav's own error
class with the same line. Data files may hold keys this skynav does not know: they are kept, and
said once per dataset.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import struct
import subprocess
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import pytest

from skynav import datasets
from skynav.__main__ import main
from skynav.infra.errors import SkynavError, SkynavWarning
from skynav.scenes import facility as facility_presets

SMALL = next(name for name in facility_presets.PRESETS if name.endswith("_small"))  # the small facility preset


@pytest.fixture(scope="module")
def small_ds(tmp_path_factory):
    """A 4-frame dataset with the small facility's camera (PNG, EXR, JSON)."""
    from skynav.calibration.facility_io import load_facility

    root = tmp_path_factory.mktemp("hostile") / "ds"
    recipe = datasets.preset_recipe("montecarlo")
    recipe.update(frames=4, formats=["png", "exr", "json"], camera=load_facility(SMALL).camera.to_dict())
    datasets.generate(recipe, root, workers=1, progress=False)
    return root


@pytest.fixture(scope="module")
def long_ds(tmp_path_factory):
    """A 40-frame dataset like ``small_ds``: an export long enough that a Ctrl-C after its first
    frame lands while it runs, however warm the machine."""
    from skynav.calibration.facility_io import load_facility

    root = tmp_path_factory.mktemp("hostile-long") / "ds"
    recipe = datasets.preset_recipe("montecarlo")
    recipe.update(frames=LONG_FRAMES, formats=["png", "json"], camera=load_facility(SMALL).camera.to_dict())
    datasets.generate(recipe, root, workers=1, progress=False)
    return root


LONG_FRAMES = 40


def _copy(src: Path, dst: Path, *, manifest=None, truth=None) -> Path:
    shutil.copytree(src, dst)
    for name, edit in (("manifest.json", manifest), ("frames/000000.json", truth)):
        if edit is not None:
            doc = json.loads((dst / name).read_text())
            edit(doc)
            (dst / name).write_text(json.dumps(doc))
    return dst


def _cli(argv, capsys):
    try:
        code = main(argv)
    except SystemExit as exc:
        code = exc.code
    out, err = capsys.readouterr()
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert "Traceback" not in err + out, err
    return code, lines


def _one_error_line(code, lines):
    assert code == 2 and len(lines) == 1 and lines[0].startswith("skynav: error: "), (code, lines)
    return lines[0][len("skynav: error: "):]


# ----------------------------------------------------------------------------- a manifest with a wrong type
MANIFEST_TYPES = {
    "frames-a-string": (lambda m: m["counts"].update(frames="4"), "$.counts.frames"),
    "frames-a-fraction": (lambda m: m["counts"].update(frames=3.5), "$.counts.frames"),
    "frames-a-list": (lambda m: m["counts"].update(frames=[4]), "$.counts.frames"),
    "frames-negative": (lambda m: m["counts"].update(frames=-1), "$.counts.frames"),
    "formats-a-number": (lambda m: m.update(formats=3), "$.formats"),
    "formats-a-string": (lambda m: m.update(formats="png"), "$.formats"),
    "counts-a-list": (lambda m: m.update(counts=[4]), "$.counts"),
    "recipe-a-list": (lambda m: m.update(recipe=[1]), "$.recipe"),
    "camera-a-number": (lambda m: m.update(camera=3), "$.camera"),
    "files-a-list": (lambda m: m.update(files=[]), "$.files"),
    "no-json-format": (lambda m: m.update(formats=["png", "exr"]), "json"),
    "frames-disagree-with-files": (lambda m: m["counts"].update(frames=2, frames_done=2), "file table lists 4"),
}


@pytest.mark.parametrize("case", sorted(MANIFEST_TYPES))
def test_a_manifest_with_a_wrong_type_is_one_line_from_the_api_and_the_cli(small_ds, tmp_path, case, capsys):
    edit, expect = MANIFEST_TYPES[case]
    d = _copy(small_ds, tmp_path / "ds", manifest=edit)
    with pytest.raises(datasets.DatasetError) as info:
        datasets.open(d)
    assert isinstance(info.value, SkynavError) and expect in str(info.value) and "\n" not in str(info.value)
    line = _one_error_line(*_cli(["hil", "export", str(d), "--facility", SMALL, "-o", str(tmp_path / "e"), "-q"], capsys))
    assert line == str(info.value)
    assert not (tmp_path / "e").exists() or not any((tmp_path / "e").rglob("*.png"))


# ----------------------------------------------------------------------------- a frame truth with a wrong type
TRUTH_TYPES = {
    "stars-a-number": (lambda t: t.update(stars=3), "$.stars"),
    "xy-a-number": (lambda t: t["stars"][0].update(xy=3), "$.stars[0].xy"),
    "bodies-a-number": (lambda t: t.update(bodies=3), "$.bodies"),
    "width-a-string": (lambda t: t["camera"].update(width="256"), "camera.width"),
    "width-a-fraction": (lambda t: t["camera"].update(width=255.5), "camera.width"),
    "position-a-number": (lambda t: t["observer"].update(position_km=3), "position_km"),
    "epoch-a-number": (lambda t: t.update(epoch=3), "epoch"),
    "visibility-a-number": (lambda t: t.update(visibility=3), "visibility"),
    "catalogue-limit-a-string": (lambda t: t.update(catalog_limiting_v_mag="7"), "catalog_limiting_v_mag"),
}


@pytest.mark.parametrize("case", sorted(TRUTH_TYPES))
def test_a_frame_truth_with_a_wrong_type_is_one_line_from_the_api_and_hil_export(small_ds, tmp_path, case, capsys):
    edit, expect = TRUTH_TYPES[case]
    d = _copy(small_ds, tmp_path / "ds", truth=edit)
    ds = datasets.open(d)
    with pytest.raises(SkynavError) as info:
        ds.truth(0)
    assert "000000.json" in str(info.value) and "\n" not in str(info.value)
    assert repr(ds[0]).startswith("FrameRecord(index=0")  # the plain dict and its repr stay readable
    line = _one_error_line(*_cli(["hil", "export", str(d), "--facility", SMALL, "-o", str(tmp_path / "e"), "-q",
                                  "--workers", "1"], capsys))
    assert "000000.json" in line and expect in line


# ----------------------------------------------------------------------------- an EXR with no parts and kin
def _deep_exr(path: Path, size: int) -> None:
    """A deep scanline OpenEXR file (one sample per pixel), written by hand after the OpenEXR file
    layout: the Python binding reads it as a channel of per-pixel arrays (objects), not numbers."""
    def attr(name, kind, value):
        return name.encode() + b"\0" + kind.encode() + b"\0" + struct.pack("<i", len(value)) + value

    box = struct.pack("<iiii", 0, 0, size - 1, size - 1)
    header = b"".join([
        attr("channels", "chlist", b"electrons\0" + struct.pack("<iB3xii", 2, 0, 1, 1) + b"\0"),
        attr("compression", "compression", b"\0"), attr("dataWindow", "box2i", box), attr("displayWindow", "box2i", box),
        attr("lineOrder", "lineOrder", b"\0"), attr("pixelAspectRatio", "float", struct.pack("<f", 1)),
        attr("screenWindowCenter", "v2f", struct.pack("<ff", 0, 0)), attr("screenWindowWidth", "float", struct.pack("<f", 1)),
        attr("type", "string", b"deepscanline"), attr("version", "int", struct.pack("<i", 1)),
        attr("chunkCount", "int", struct.pack("<i", size)), attr("maxSamplesPerPixel", "int", struct.pack("<i", 1))]) + b"\0"
    head = struct.pack("<ii", 20000630, 2 | 0x800) + header
    chunks, offsets = b"", []
    for y in range(size):
        offsets.append(len(head) + 8 * size + len(chunks))
        counts, samples = struct.pack(f"<{size}i", *range(1, size + 1)), struct.pack(f"<{size}f", *([0.0] * size))
        chunks += struct.pack("<iQQQ", y, len(counts), len(samples), len(samples)) + counts + samples
    path.write_bytes(head + struct.pack(f"<{size}Q", *offsets) + chunks)


def _exr(path: Path, channels: dict) -> None:
    import OpenEXR

    OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}, channels).write(str(path))


EXR_DAMAGE = {
    "garbage": (lambda p: p.write_bytes(b"v/1\x01 not an image"), "not readable"),
    "empty": (lambda p: p.write_bytes(b""), "not readable"),
    "missing": (lambda p: p.unlink(), "missing"),
    "no-electrons": (lambda p: _exr(p, {"R": np.zeros((256, 256), np.float32)}), "no electrons channel"),
    "another-size": (lambda p: _exr(p, {"electrons": np.zeros((8, 8), np.float32)}), "8x8 px"),
    "deep": (lambda p: _deep_exr(p, 8), "deep"),
}


@pytest.mark.parametrize("case", sorted(EXR_DAMAGE))
def test_a_damaged_exr_is_one_dataset_error_naming_the_file(small_ds, tmp_path, case):
    damage, expect = EXR_DAMAGE[case]
    d = _copy(small_ds, tmp_path / "ds")
    damage(d / "frames" / "000000.exr")
    rec = datasets.open(d)[0]
    with pytest.raises(datasets.DatasetError) as info:
        rec.electrons
    assert "000000.exr" in str(info.value) and expect in str(info.value) and "\n" not in str(info.value)
    assert datasets.open(d)[1].electrons.shape == rec.dn.shape  # the other frames read


def test_an_exr_with_no_parts_is_one_dataset_error(small_ds, tmp_path, monkeypatch):
    """The OpenEXR binding's File with no parts (what it gives for a file whose parts it cannot
    read) answers ``channels()`` with its own ValueError: the reader names the file instead."""
    import OpenEXR

    real = OpenEXR.File

    def no_parts(*args, **kwargs):
        f = real(*args, **kwargs)
        f.parts = []
        return f

    monkeypatch.setattr(OpenEXR, "File", no_parts)
    with pytest.raises(datasets.DatasetError, match=r"000000\.exr: frame 0's EXR is not readable \(ValueError"):
        datasets.open(small_ds)[0].electrons


# ----------------------------------------------------------------------------- 0 frames
def test_a_dataset_of_0_frames_is_not_exported_without_a_word(small_ds, tmp_path, capsys):
    def none(m):
        m["counts"].update(frames=0, frames_done=0)
        m["files"] = {k: v for k, v in m["files"].items() if not k.startswith("frames/")}

    d = _copy(small_ds, tmp_path / "ds", manifest=none)
    assert len(datasets.open(d)) == 0
    line = _one_error_line(*_cli(["hil", "export", str(d), "--facility", SMALL, "-o", str(tmp_path / "e"), "-q"], capsys))
    assert "holds no frames" in line
    # a manifest that says 0 frames over a file table of 4 is refused when opened
    d0 = _copy(small_ds, tmp_path / "ds0", manifest=lambda m: m["counts"].update(frames=0, frames_done=0))
    line = _one_error_line(*_cli(["hil", "export", str(d0), "--facility", SMALL, "-o", str(tmp_path / "e0"), "-q"], capsys))
    assert "counts.frames is 0" in line


# ----------------------------------------------------------------------------- unknown keys
def test_unknown_keys_of_data_files_are_kept_and_said_once_per_dataset(small_ds, tmp_path):
    def more_truth(t):
        t["other_tool"] = {"snr": 3}
        t["camera"]["lens_serial"] = "A12"

    d = _copy(small_ds, tmp_path / "ds", manifest=lambda m: m.update(made_by="another program"), truth=more_truth)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("default")
        ds = datasets.open(d)
        for _ in range(2):
            assert ds[0].truth["other_tool"] == {"snr": 3}  # kept
            assert ds.observation(0).camera == datasets.open(small_ds).observation(0).camera  # ignored
            assert ds.truth(0).raw["camera"]["lens_serial"] == "A12"
    said = [str(w.message) for w in caught if issubclass(w.category, SkynavWarning)]
    assert len(said) == 3 and all("kept and ignored" in s for s in said), said
    assert any("made_by" in s for s in said) and any("other_tool" in s for s in said)
    assert any("camera.lens_serial" in s for s in said)


# ----------------------------------------------------------------------------- render --hil
@pytest.mark.parametrize("option", ["--hil", "--facility"])
def test_render_hil_with_an_empty_facility_is_refused(tmp_path, option, capsys):
    line = _one_error_line(*_cli(["render", option, "", "-o", str(tmp_path / "r")], capsys))
    assert line.startswith(f"{option} '': ") and SMALL in line
    assert not (tmp_path / "r").exists()


def test_an_empty_facility_is_refused_by_hil_export_too(small_ds, tmp_path, capsys):
    """'' would name the current folder: the output was said to be 'inside the input facility folder'."""
    line = _one_error_line(*_cli(["hil", "export", str(small_ds), "--facility", "", "-o", str(tmp_path / "e")], capsys))
    assert line.startswith("--facility '': ") and SMALL in line


@pytest.mark.parametrize("option", ["--hil", "--facility"])
def test_render_hil_with_fits_is_refused(tmp_path, option, capsys):
    line = _one_error_line(*_cli(["render", option, SMALL, "--fits", "-o", str(tmp_path / "r")], capsys))
    assert "--fits" in line and option in line
    assert not (tmp_path / "r").exists()


# ----------------------------------------------------------------------------- Ctrl-C during hil export
def _children(pid: int) -> set:
    kids = set()
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                stat = (entry / "stat").read_text()
            except OSError:
                continue
            if int(stat.rsplit(")", 1)[1].split()[1]) == pid:
                kids.add(int(entry.name))
    return kids


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


@pytest.mark.skipif(not Path("/proc").is_dir(), reason="reads the process table from /proc")
@pytest.mark.parametrize("workers", [1, 2])
def test_ctrl_c_ends_hil_export_with_one_line_no_orphans_and_it_resumes(long_ds, tmp_path, workers, capsys):
    """SIGINT to the whole process group (what a terminal's Ctrl-C does) once a frame is done."""
    out = tmp_path / "e"
    p = subprocess.Popen([sys.executable, "-m", "skynav", "hil", "export", str(long_ds), "--facility", SMALL, "-o",
                          str(out), "-q", "--workers", str(workers)], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                         text=True, start_new_session=True)
    kids, t0 = set(), time.monotonic()
    while p.poll() is None and time.monotonic() - t0 < 300:
        kids |= _children(p.pid)
        if len(list((out / "frames").glob("*.sha256"))) >= 1 if (out / "frames").is_dir() else False:
            break
        time.sleep(0.05)
    assert p.poll() is None, "the export ended before it could be interrupted"
    kids |= _children(p.pid)
    os.killpg(p.pid, signal.SIGINT)
    try:
        _, err = p.communicate(timeout=120)
    except subprocess.TimeoutExpired:
        os.killpg(p.pid, signal.SIGKILL)
        p.communicate()
        pytest.fail("hil export did not end after Ctrl-C")
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert p.returncode == 130 and len(lines) == 1 and lines[0].startswith("skynav: error: interrupted"), err
    deadline = time.monotonic() + 20
    while any(_alive(k) for k in kids) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not [k for k in kids if _alive(k)], "worker processes outlived the export"
    done = len(list((out / "frames").glob("*.sha256")))
    # the same command again finishes the export and keeps the frames already made
    assert main(["hil", "export", str(long_ds), "--facility", SMALL, "-o", str(out), "--workers", "1"]) == 0
    said = capsys.readouterr().out
    assert done >= 1 and f"({done} already there) of {LONG_FRAMES}" in said, said
    assert json.loads((out / "export.json").read_text())["complete"] is True
    assert len(list((out / "frames").glob("*.png"))) == LONG_FRAMES and not list(out.rglob("*.tmp"))


# ----------------------------------------------------------------------------- render --hil: the camera, the layout
def test_render_hil_without_a_scene_uses_the_facility_camera_and_says_so(tmp_path, capsys):
    from skynav.calibration.facility_io import load_facility

    code = main(["render", "--facility", SMALL, "-o", str(tmp_path / "r")])
    out = capsys.readouterr().out
    assert code == 0
    cam = load_facility(SMALL).camera
    said = [ln for ln in out.splitlines() if ln.startswith("no scene file")]
    assert len(said) == 1 and f"{cam.width}x{cam.height} px" in said[0], out
    rec = json.loads((tmp_path / "r" / "frame.json").read_text())
    assert rec["source"]["scene"] == "default" and rec["schema"] == "skynav.hil_frame/2"


@pytest.mark.parametrize("argv, key", [
    (["--set", "camera.exposure_s=0.2"], "camera.exposure_s is 0.2 in the scene, 0.4 in the facility"),
    (["--set", "camera.sensor.read_noise_e=3"], "camera.sensor.read_noise_e is 3"),
    (["SCENE"], "camera.width is 1024 in the scene, 256 in the facility (also camera.height"),
])
def test_render_hil_names_the_camera_key_that_differs(tmp_path, argv, key, capsys):
    scene = str(Path(__file__).resolve().parents[2] / "docs" / "examples" / "default_scene.yaml")
    argv = [scene if a == "SCENE" else a for a in argv]
    line = _one_error_line(*_cli(["render", *argv, "--facility", SMALL, "-o", str(tmp_path / "r")], capsys))
    assert line.startswith("the scene's camera is not the facility's: ") and key in line, line
    assert not (tmp_path / "r").exists()


def test_render_writes_one_layout_with_and_without_hil(tmp_path, capsys):
    """``render -o OUT`` writes ``OUT/NAME.*`` whether it makes a camera frame or a screen frame."""
    assert main(["render", "--facility", SMALL, "-o", str(tmp_path / "screen"), "--name", "f1", "-q"]) == 0
    assert main(["render", "-o", str(tmp_path / "camera"), "--name", "f1", "-q", "--set", "camera.width=64",
                 "--set", "camera.height=64"]) == 0
    capsys.readouterr()
    screen = sorted(p.relative_to(tmp_path / "screen").as_posix() for p in (tmp_path / "screen").rglob("*"))
    camera = sorted(p.relative_to(tmp_path / "camera").as_posix() for p in (tmp_path / "camera").rglob("*"))
    assert screen == ["f1.json", "f1.png"]
    assert camera == ["f1.exr", "f1.json", "f1.png"]
