"""Two runs at once and killed runs of ``calibrate simulate`` and ``hil export``.

A second run on a folder another run holds is refused in one line (the folder lock of ``dataset
generate``); a run killed part-way and run again gives the bytes of one uninterrupted run; an
export whose ``export.json`` was lost is remade whole, never kept blindly.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import pytest

from skynav.__main__ import main


def _files(folder):
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob("*"))
            if p.is_file() and not p.name.startswith(".")}


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    from skynav import datasets
    from skynav.calibration.facility_io import load_facility
    from skynav.calibration.bench_files import write_patterns

    tmp = tmp_path_factory.mktemp("runs_at_once")
    fac = load_facility("screen_small")
    write_patterns(fac, tmp / "pats", phases=2)
    recipe = datasets.preset_recipe("montecarlo")
    recipe.update(frames=2, formats=["png", "json"], camera=fac.camera.to_dict())
    datasets.generate(recipe, tmp / "ds", workers=1, progress=False)
    return tmp


def _one_line(capsys, code, text):
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and text in err[0], err


@pytest.mark.parametrize("command", ["simulate", "export", "patterns"])
def test_a_second_run_on_a_held_folder_is_refused(inputs, tmp_path, capsys, command):
    from skynav.datasets.lock import dataset_lock

    out = tmp_path / "out"
    out.mkdir()
    argv = {"simulate": ["calibrate", "simulate", "screen_small", "--patterns", str(inputs / "pats"), "-o", str(out),
                         "--frames", "1", "-q"],
            "export": ["hil", "export", str(inputs / "ds"), "--facility", "screen_small", "-o", str(out), "-q"],
            "patterns": ["calibrate", "patterns", "screen_small", "-o", str(out), "-q"]}[command]
    with dataset_lock(out):  # another live run holds the folder
        _one_line(capsys, main(argv), "already running")
    assert [p.name for p in out.iterdir() if p.name != ".skynav.lock"] in ([], ["frames"])


def _kill_after_first_file(argv, folder, pattern):
    p = subprocess.Popen([sys.executable, "-m", "skynav", *argv], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    deadline = time.time() + 120
    while time.time() < deadline and p.poll() is None:
        if folder.is_dir() and any(folder.rglob(pattern)):
            break
        time.sleep(0.02)
    if p.poll() is None:
        os.kill(p.pid, signal.SIGKILL)
    p.wait()


def test_a_killed_simulate_run_again_gives_the_uninterrupted_bytes(inputs, tmp_path):
    argv = lambda out: ["calibrate", "simulate", "screen_small", "--patterns", str(inputs / "pats"), "-o", str(out),  # noqa: E731
                        "--frames", "2", "--seed", "5", "-q"]
    assert main(argv(tmp_path / "whole")) == 0
    _kill_after_first_file(argv(tmp_path / "killed"), tmp_path / "killed", "dots_00.png")
    assert main(argv(tmp_path / "killed")) == 0
    assert _files(tmp_path / "killed") == _files(tmp_path / "whole")


def test_a_killed_export_run_again_gives_the_uninterrupted_bytes(inputs, tmp_path):
    argv = lambda out: ["hil", "export", str(inputs / "ds"), "--facility", "screen_small", "-o", str(out), "-q"]  # noqa: E731
    assert main(argv(tmp_path / "whole")) == 0
    _kill_after_first_file(argv(tmp_path / "killed"), tmp_path / "killed", "000000.png")
    assert main(argv(tmp_path / "killed")) == 0
    strip = lambda files: {k: v for k, v in files.items() if k != "export.json"}  # noqa: E731
    assert strip(_files(tmp_path / "killed")) == strip(_files(tmp_path / "whole"))


@pytest.mark.parametrize("damage", ["lost", "damaged"])
def test_an_export_without_its_manifest_is_remade_for_the_new_facility(inputs, tmp_path, damage):
    """export.json lost or damaged, then an export with another facility: every frame is of the new
    facility (the same bytes as a fresh export with it), none kept from the old one."""
    other = ["--set", "screen.bit_depth=8"]
    out, fresh = tmp_path / "out", tmp_path / "fresh"
    assert main(["hil", "export", str(inputs / "ds"), "--facility", "screen_small", "-o", str(out), "-q"]) == 0
    if damage == "lost":
        (out / "export.json").unlink()
    else:
        (out / "export.json").write_text("{trunc")
    assert main(["hil", "export", str(inputs / "ds"), "--facility", "screen_small", "-o", str(out), "-q", *other]) == 0
    assert main(["hil", "export", str(inputs / "ds"), "--facility", "screen_small", "-o", str(fresh), "-q", *other]) == 0
    strip = lambda files: {k: v for k, v in files.items() if k != "export.json"}  # noqa: E731
    assert strip(_files(out)) == strip(_files(fresh))
    assert json.loads((out / "frames" / "000000.json").read_text())["facility"]["screen"]["bit_depth"] == 8
