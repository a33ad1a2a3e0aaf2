"""Crash consistency: whatever kills a run, the resume ends byte-identical or refuses with one line.

(Byte-identical is a determinism demand here: the same code with the same seeds, on one machine.)

- A run killed before it finished, one PNG corrupted and another truncated
  to 0 bytes, then resumed; both must be made again (a resume keeps a frame only if its per-frame
  checksum record, its hashes and its decoding agree), and ``verify`` must catch a damaged image
  even when its (damaged) hash was recorded.
- SIGKILL at chosen points: a subprocess counts the renames of its atomic writes (every frame
  file, checksum record, manifest checkpoint, index) and kills itself with SIGKILL at the N-th,
  after its temp file is complete or half written. 20 points, 4 of them followed by a resume that
  is itself killed; every final resume must give the same SHA-256 for every file as a run never
  interrupted.
- A full disk, twice: a real 400 KiB tmpfs mounted by the test (root only, skipped elsewhere)
  fills mid-run, then is grown and the run resumed; and, everywhere, ``ENOSPC`` raised by the
  writer at the 7th write (monkeypatched). The command line must say it in one line, and the
  resume must end identical. A read-only mount checks the "not writable" refusal.
"""

from __future__ import annotations

import errno
import json
import os
import random
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from skynav.datasets import generate, verify

from .conftest import small_recipe, tree_sha256

N_FRAMES = 6


def recipe() -> dict:
    return small_recipe(frames=N_FRAMES)


@pytest.fixture(scope="module")
def small_reference(tmp_path_factory):
    """The 6-frame recipe made once, uninterrupted, in this process: the bytes to match."""
    out = tmp_path_factory.mktemp("ref6") / "ds"
    generate(recipe(), out, workers=1, progress=False)
    return tree_sha256(out)


def test_issue_11_defect_killed_corrupted_truncated_then_resumed(small_reference, tmp_path):
    out = tmp_path / "ds"
    # a run stopped before the end (max_frames: same state as a kill after 4 frames' files)
    generate(recipe(), out, workers=1, progress=False, max_frames=4)
    png1, png2 = out / "frames" / "000001.png", out / "frames" / "000002.png"
    data = bytearray(png1.read_bytes())
    data[len(data) // 2] ^= 0xFF
    png1.write_bytes(bytes(data))  # corrupted
    png2.write_bytes(b"")  # truncated to 0 bytes (a full disk, a dead node)
    s = generate(recipe(), out, workers=1, progress=False)
    assert s.frames_reused == 2 and s.frames_rendered == N_FRAMES - 2, s  # frames 1 and 2 made again
    assert tree_sha256(out) == small_reference
    assert verify(out).ok


def test_verify_catches_a_damaged_image_whose_hash_was_recorded(small_reference, tmp_path):
    """The 0.3.0 defect: damaged bytes checksummed into the manifest; verify must decode."""
    out = tmp_path / "ds"
    generate(recipe(), out, workers=1, progress=False)
    png = out / "frames" / "000003.png"
    png.write_bytes(png.read_bytes()[:40])  # truncated mid-chunk
    m = json.loads((out / "manifest.json").read_text())
    import hashlib

    m["files"]["frames/000003.png"] = hashlib.sha256(png.read_bytes()).hexdigest()
    (out / "manifest.json").write_text(json.dumps(m, indent=2) + "\n")
    report = verify(out)
    assert not report.ok and len(report.problems) == 1, report.problems
    assert report.problems[0].startswith("frames/000003.png: does not decode as PNG")
    # and the command line: exit 1, the problem on stdout
    from skynav.cli import main

    assert main(["dataset", "verify", str(out), "-q"]) == 1


def test_preview_and_info_on_a_damaged_dataset_say_one_line(tmp_path, capsys):
    from skynav.cli import main

    out = tmp_path / "ds"
    generate(recipe(), out, workers=1, progress=False)
    (out / "frames" / "000000.png").write_bytes(b"")
    (out / "index.csv").write_bytes(b"\xff\xfe\x00garbage")
    capsys.readouterr()
    assert main(["dataset", "preview", str(out), "-o", str(tmp_path / "p.png")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "000000.png" in err[0] and "damaged" in err[0], err
    assert main(["dataset", "info", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "index.csv" in err[0], err


_KILLER = r"""
import json, os, signal, sys
import skynav.datasets.frame_files as ff
die_at, half = int(sys.argv[3]), sys.argv[4] == "half"
state = {"n": 0}
real_replace = os.replace
def replace(src, dst):
    state["n"] += 1
    if state["n"] == die_at:
        if half:  # the temp file half written: as if the process died mid-write
            data = open(src, "rb").read()
            open(src, "wb").write(data[: len(data) // 2])
        os.kill(os.getpid(), signal.SIGKILL)
    return real_replace(src, dst)
ff.os.replace = replace
from skynav.datasets import generate
generate(json.loads(sys.argv[1]), sys.argv[2], workers=1, progress=False, flush_every_s=0.0)
"""


def _run_killed(out: Path, die_at: int, half: bool) -> int:
    proc = subprocess.run([sys.executable, "-c", _KILLER, json.dumps(recipe()), str(out), str(die_at),
                           "half" if half else "whole"], capture_output=True, timeout=300)
    return proc.returncode


# 20 kill points out of the 33 renames of a 6-frame run with a checkpoint per frame (manifest,
# then per frame png, exr, json, record, manifest; then index, final manifest), seeded: the same
# points every run; 4 of them with a second kill during the resume
RENAMES_IN_A_RUN = 33
_rng = random.Random(11)
KILL_POINTS = sorted(_rng.sample(range(1, RENAMES_IN_A_RUN + 1), 20))
DOUBLE = set(_rng.sample(KILL_POINTS, 4))


@pytest.mark.parametrize("die_at", KILL_POINTS)
def test_sigkill_at_a_write_then_resume_identical(small_reference, tmp_path, die_at):
    out = tmp_path / "ds"
    rc = _run_killed(out, die_at, half=die_at % 2 == 0)
    assert rc == -signal.SIGKILL, rc  # every point is inside the run
    if die_at in DOUBLE:  # kill the resume too, a few writes in
        rc2 = _run_killed(out, 3, half=True)
        assert rc2 in (0, -signal.SIGKILL), rc2
    generate(recipe(), out, workers=1, progress=False)
    assert tree_sha256(out) == small_reference
    assert verify(out).ok


def test_full_disk_is_one_line_and_the_resume_ends_identical(small_reference, tmp_path, monkeypatch, capsys):
    """ENOSPC simulated at the 7th write (runs where no file system can be mounted)."""
    import skynav.infra.atomic_files as af
    from skynav.cli import main

    real = af.atomic_path
    calls = {"n": 0}

    def full(path, **kw):
        calls["n"] += 1
        if calls["n"] == 7:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))
        return real(path, **kw)

    monkeypatch.setattr(af, "atomic_path", full)  # its one home: every atomic write goes through it
    out = tmp_path / "ds"
    recipe_file = tmp_path / "r.json"
    recipe_file.write_text(json.dumps(recipe()))
    code = main(["dataset", "generate", str(recipe_file), "-o", str(out), "--workers", "1", "-q"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "no space left" in err[0], err
    monkeypatch.setattr(af, "atomic_path", real)
    generate(recipe(), out, workers=1, progress=False)
    assert tree_sha256(out) == small_reference


def test_two_generators_on_one_folder_the_second_is_refused(tmp_path):
    """Two real processes: the second says who runs, in one line, exit 2; the first completes."""
    out = tmp_path / "ds"
    rf = tmp_path / "r.json"
    r = small_recipe(frames=12)
    rf.write_text(json.dumps(r))
    cmd = [sys.executable, "-m", "skynav", "dataset", "generate", str(rf), "-o", str(out), "--workers", "1", "-q"]
    first = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    import time

    deadline = time.monotonic() + 120
    while not (out / ".skynav.lock").exists() or not (out / ".skynav.lock").read_text().strip():
        assert first.poll() is None and time.monotonic() < deadline
        time.sleep(0.05)
    # the first is paused while the second tries: a small dataset is made in well under the
    # second's start-up time, so without the pause the second could find it done, not running
    os.kill(first.pid, signal.SIGSTOP)
    try:
        second = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    finally:
        os.kill(first.pid, signal.SIGCONT)
    first.wait(300)
    assert first.returncode == 0, first.stderr.read()
    lines = second.stderr.strip().splitlines()
    assert second.returncode == 2 and len(lines) == 1, second.stderr
    assert f"already running (pid {first.pid} on host" in lines[0]
    assert not (out / ".skynav.lock").exists() and verify(out).ok


def test_a_stale_lock_of_a_killed_run_is_taken_over(tmp_path):
    out = tmp_path / "ds"
    rc = _run_killed(out, 9, half=False)
    assert rc == -signal.SIGKILL and (out / ".skynav.lock").exists()  # left behind, not held
    generate(recipe(), out, workers=1, progress=False)
    assert verify(out).ok and not (out / ".skynav.lock").exists()


@pytest.fixture
def small_tmpfs(tmp_path):
    """A tmpfs of 400 KiB (half of the 6-frame dataset) mounted for the test (root only; skipped where mounting is not allowed)."""
    mnt = tmp_path / "mnt"
    mnt.mkdir()
    if os.geteuid() != 0:
        pytest.skip("mounting a size-limited tmpfs needs root")
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=400k", "tmpfs", str(mnt)], capture_output=True)
    if r.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {r.stderr.decode().strip()}")
    try:
        yield mnt
    finally:
        subprocess.run(["umount", "-l", str(mnt)], capture_output=True)


def test_real_full_disk_then_more_space_resumes_identical(small_reference, small_tmpfs):
    """A 400 KiB file system fills mid-run (ENOSPC from the kernel); one line, exit 2; after the
    file system is grown (remount), the same command resumes to the uninterrupted bytes."""
    out = small_tmpfs / "ds"
    rf = small_tmpfs.parent / "r.json"
    rf.write_text(json.dumps(recipe()))
    cmd = [sys.executable, "-m", "skynav", "dataset", "generate", str(rf), "-o", str(out), "--workers", "1", "-q"]
    first = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    lines = first.stderr.strip().splitlines()
    assert first.returncode == 2 and "Traceback" not in first.stderr, first.stderr
    assert "no space left" in lines[-1] and lines[-1].startswith("skynav: error:"), lines
    assert json.loads((out / "manifest.json").read_text())["complete"] is False
    subprocess.run(["mount", "-o", "remount,size=64m", str(small_tmpfs)], check=True)
    second = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert second.returncode == 0, second.stderr
    assert tree_sha256(out) == small_reference


def test_read_only_output_folder_is_one_line(small_tmpfs, capsys):
    from skynav.cli import main

    subprocess.run(["mount", "-o", "remount,ro", str(small_tmpfs)], check=True)
    assert main(["dataset", "generate", "montecarlo", "-o", str(small_tmpfs / "ds"), "-q", "--count", "1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "not writable" in err[0] and str(small_tmpfs) in err[0], err
    assert main(["render", "-o", str(small_tmpfs / "r")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "not writable" in err[0], err


def test_a_frame_that_fails_leaves_the_frames_before_it_written(small_reference, tmp_path, monkeypatch):
    """The runner writes frame k on its writer thread while it makes frame k + 1: a failure while
    frame k + 1 is made (here its scene build) must still leave frame k written with its record,
    and the resume must end identical."""
    from skynav.datasets import execute
    from skynav.datasets.journal import read_record, record_relpath

    real = execute.build_scene
    calls = {"n": 0}

    def fails_third(*a, **kw):
        calls["n"] += 1
        if calls["n"] == 3:
            raise RuntimeError("scene build failed")
        return real(*a, **kw)

    monkeypatch.setattr(execute, "build_scene", fails_third)
    out = tmp_path / "ds"
    with pytest.raises(RuntimeError, match="scene build failed"):
        generate(recipe(), out, workers=1, progress=False)
    for k in (0, 1):  # made before the failure: written, with their records
        assert (out / record_relpath(k)).is_file() and read_record(out, k), k
    assert not (out / record_relpath(2)).exists()
    monkeypatch.setattr(execute, "build_scene", real)
    generate(recipe(), out, workers=1, progress=False)
    assert tree_sha256(out) == small_reference
