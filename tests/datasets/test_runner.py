"""Datasets are reproducible byte for byte whatever the executor, and survive a SIGKILL.

The same 50-frame recipe (256 x 256 camera) is made with 1 worker (in process, the reference),
2 spawned worker processes, a 2-worker Dask ``LocalCluster`` with worker processes, and by a
subprocess killed with SIGKILL mid-way and then resumed; every file (frames, index, manifest)
must have the same SHA-256 in all four.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

import skynav.datasets as D
from skynav.datasets import IncompleteDatasetError, generate, verify

from .conftest import small_recipe, tree_sha256


def test_reference_is_complete_and_verifies(reference_dataset):
    out, summary, shas = reference_dataset
    assert summary.frames_total == 50 and summary.frames_rendered == 50
    assert {"manifest.json", "index.csv"} <= set(shas)
    assert sum(1 for k in shas if k.startswith("frames/")) == 200  # png, exr, json + the checksum record x 50
    report = verify(out)
    assert report.ok, report.lines()
    m = json.loads((out / "manifest.json").read_text())
    assert m["complete"] is True and m["master_seed"] == 424242 and m["counts"]["frames"] == 50
    # every file but the manifest itself is checksummed in the manifest
    assert set(m["files"]) == set(shas) - {"manifest.json"}
    assert all(m["files"][k] == shas[k] for k in m["files"])


def test_two_worker_processes_identical(reference_dataset, tmp_path, monkeypatch):
    from skynav.datasets import execute

    out, _, ref = reference_dataset
    s = generate(small_recipe(), tmp_path / "ds", workers=2, progress=False)  # too few frames for a helper
    assert s.workers == 2 and s.executor.startswith("processes")
    assert tree_sha256(tmp_path / "ds") == ref
    monkeypatch.setattr(execute.HelpersPay, "__call__", lambda self, made, left, seconds: True)  # a helper at once
    s = generate(small_recipe(), tmp_path / "ds2", workers=2, progress=False)
    assert tree_sha256(tmp_path / "ds2") == ref


def test_a_helper_starts_only_once_the_frames_left_pay_its_start_up():
    from skynav.datasets.execute import HelpersPay

    pays = HelpersPay(imports_s=1.0, factor=1.5, jiffies=lambda: None)  # the machine unknown: idle
    assert not pays(0, 400, 0.0)
    assert not pays(1, 399, 2.0) and not pays(2, 398, 2.025)  # the first frame took 2 s: the start-up
    assert pays(3, 397, 2.05)  # 397 frames at 25 ms = 9.9 s > 1.5 x (2 + 1) s
    pays = HelpersPay(imports_s=1.0, factor=1.5, jiffies=lambda: None)
    pays(1, 59, 2.0)
    assert not pays(3, 57, 2.05)  # 57 frames at 25 ms = 1.4 s: the helper would not pay


def test_a_helper_starts_only_where_a_core_is_idle(monkeypatch):
    from skynav.datasets import execute

    monkeypatch.setattr(execute.os, "cpu_count", lambda: 2)
    ticks = iter([(0, 0), (20, 200), (40, 400), (150, 600)])  # idle, total: 0.2, then 1.1 cores idle
    pays = execute.HelpersPay(imports_s=1.0, factor=1.5, window_s=0.5, jiffies=lambda: next(ticks))
    pays(1, 999, 1.0)
    assert not pays(3, 997, 1.1)  # frames enough, but the window since the first look is 0.1 s
    assert not pays(4, 996, 1.6)  # 0.2 cores idle: the machine is busy
    assert not pays(5, 995, 1.7)  # too soon to look again
    assert not pays(6, 994, 2.2)  # 0.2 cores idle again
    assert pays(7, 993, 2.8)  # 1.1 cores idle
    assert execute.cpu_jiffies() is None or execute.cpu_jiffies()[1] > 0


def test_dask_local_cluster_identical(reference_dataset, tmp_path):
    distributed = pytest.importorskip("distributed")
    _, _, ref = reference_dataset
    # real distributed: scheduler + 2 worker processes (spawned), one thread each
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
        # by address, as a remote scheduler would be given (generate opens and closes its Client)
        s = generate(small_recipe(), tmp_path / "ds", dask_scheduler=cluster.scheduler_address, progress=False)
    assert s.executor == "dask" and s.workers == 2
    assert tree_sha256(tmp_path / "ds") == ref


def _count_json(frames_dir: Path) -> int:
    return sum(1 for p in frames_dir.glob("*.json")) if frames_dir.is_dir() else 0


def _spawn_generator(recipe: dict, out: Path, options: str, prelude: str = "") -> subprocess.Popen:
    """``generate(recipe, out, <options>)`` in a separate Python process, after ``prelude``."""
    code = ("import json, sys\n"
            "from skynav.datasets import generate\n"
            f"{prelude}"
            f"generate(json.loads(sys.argv[1]), sys.argv[2], {options})\n")
    return subprocess.Popen([sys.executable, "-c", code, json.dumps(recipe), str(out)])


def _wait_until(proc: subprocess.Popen, done, *, poll_s: float, timeout_s: float = 180.0) -> None:
    """Poll ``done()`` until true; fail if the generator ends first or takes over ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    while not done():
        assert proc.poll() is None, f"the generator ended before it could be killed (rc {proc.returncode})"
        assert time.monotonic() < deadline, "the generator is too slow"
        time.sleep(poll_s)


def _count_records(frames_dir: Path) -> int:
    return sum(1 for p in frames_dir.glob("*.sha256")) if frames_dir.is_dir() else 0


def test_sigkill_then_resume_identical(reference_dataset, tmp_path):
    _, _, ref = reference_dataset
    out = tmp_path / "ds"
    proc = _spawn_generator(small_recipe(), out, "workers=1, progress=False, flush_every_s=0.0")
    try:
        # wait for 12 committed frames: a frame's record (NNNNNN.sha256) is written after its
        # files, so counting JSON files could count a frame the kill leaves uncommitted
        _wait_until(proc, lambda: _count_records(out / "frames") >= 12, poll_s=0.02)
        os.kill(proc.pid, signal.SIGKILL)
    finally:
        proc.wait(30)
    assert proc.returncode == -signal.SIGKILL, f"rc {proc.returncode}, {_count_json(out / 'frames')} frames" 
    m = json.loads((out / "manifest.json").read_text())
    assert m["complete"] is False
    # the reader refuses the half-written dataset with a clear message
    with pytest.raises(IncompleteDatasetError, match="incomplete dataset"):
        D.open(out)
    # make it worse: a stale temp file, a frame missing one file, and a flipped byte in a
    # frame whose checksum the manifest recorded
    (out / "frames" / ".000049.png.999.deadbeef.tmp").write_bytes(b"partial")
    (out / "frames" / "000003.exr").unlink()
    recorded_png = sorted(k for k in m["files"] if k.endswith(".png"))[1]
    data = bytearray((out / recorded_png).read_bytes())
    data[len(data) // 2] ^= 0xFF
    (out / recorded_png).write_bytes(bytes(data))

    s = generate(small_recipe(), out, workers=1, progress=False)
    assert s.frames_reused >= 10 and s.frames_rendered == 50 - s.frames_reused, s
    got = tree_sha256(out)
    assert sorted(got) == sorted(ref)
    assert [k for k in ref if got[k] != ref[k]] == []
    assert D.open(out)[0].dn.shape == (256, 256)


def test_resume_refuses_a_different_recipe(reference_dataset, tmp_path):
    out, _, _ = reference_dataset
    copy = tmp_path / "ds"
    shutil.copytree(out, copy)
    other = small_recipe()
    other["seed"] = 7
    with pytest.raises(D.DatasetMismatchError, match="seed"):
        generate(other, copy, workers=1, progress=False)


def test_verify_reports_each_damage_in_one_line(reference_dataset, tmp_path):
    out, _, _ = reference_dataset
    copy = tmp_path / "ds"
    shutil.copytree(out, copy)
    png = copy / "frames" / "000004.png"
    data = bytearray(png.read_bytes())
    data[100] ^= 0x01  # one flipped bit
    png.write_bytes(bytes(data))
    for ext in ("png", "exr", "json"):
        (copy / "frames" / f"000007.{ext}").unlink()
    js = copy / "frames" / "000011.json"
    js.write_bytes(js.read_bytes()[: js.stat().st_size // 2])
    report = verify(copy)
    assert not report.ok
    assert len(report.problems) == 3, report.problems
    joined = "\n".join(report.problems)
    assert "frames/000004.png: SHA-256 mismatch" in joined
    assert "frame 7 (frames/000007.*): frame missing" in joined
    assert "frames/000011.json: truncated or invalid JSON" in joined


def test_reader_lazy_records(reference_dataset):
    out, _, _ = reference_dataset
    ds = D.open(out)
    assert len(ds) == 50
    rec = ds[-1]
    assert rec.index == 49 and rec._exr is None  # EXR not read yet
    dn, truth = rec
    assert dn.dtype.name == "uint8" and truth["schema"] == "skynav.frame/2"
    assert rec.electrons.dtype.name == "float32" and rec.electrons.shape == (256, 256)
    assert truth["seeds"]["frame"]["entropy"] == [424242, 49]
    assert truth["dataset"]["frame"] == 49
    with pytest.raises(D.FrameIndexError):
        ds[50]
    with pytest.raises(AttributeError):
        rec.dn = None
    assert len(ds.index) == 50 and ds.index[3]["frame"] == "3"


def test_regenerate_one_frame_alone(reference_dataset, tmp_path):
    out, _, ref = reference_dataset
    res = D.regenerate_frame(out, 17, tmp_path)
    for rel, sha in res.files.items():
        assert ref[rel] == sha


def test_visible_planet_filter_keeps_only_scenes_with_a_visible_planet(tmp_path):
    s = generate(small_recipe(frames=3, keep=["visible_planet"]), tmp_path / "ds", workers=1, progress=False)
    ds = D.open(tmp_path / "ds")
    for rec in ds:
        assert any(b["visible"] for b in rec.truth["bodies"])
    m = ds.manifest["counts"]
    assert m["scenes_kept"] == 3 and m["scenes_drawn"] == s.draws >= 3


def test_info_and_preview(reference_dataset, tmp_path):
    from PIL import Image

    out, _, _ = reference_dataset
    rows = dict(D.info(out)["rows"])
    assert rows["frames"] == "50" and rows["complete"] == "yes" and "256 x 256" in rows["camera"]
    png = D.preview(out, tmp_path / "sheet.png", count=6, columns=3, tile_px=128)
    with Image.open(png) as im:
        assert im.mode == "RGB" and im.size == (3 * 128 + 4 * 4, 2 * 128 + 3 * 4)


def _children(pid: int) -> list:
    kids = []
    for st in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = st.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == pid:
            kids.append(int(st.parent.name))
    return kids


def _helpers(pid: int) -> list:
    """The spawned helpers of process ``pid`` alive now (not multiprocessing's resource tracker)."""
    out = []
    for k in _children(pid):
        try:
            cmd = Path(f"/proc/{k}/cmdline").read_bytes()
        except OSError:
            continue
        if b"spawn_main" in cmd and _alive(k):
            out.append(k)
    return out


def _alive(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads /proc")
def test_pool_workers_end_when_the_generator_is_killed(tmp_path):
    """SIGKILL to ``dataset generate``'s process leaves no worker behind (they used to wait for work
    forever, holding a Mitsuba process's memory each)."""
    out = tmp_path / "ds"
    # a helper at once, whatever the machine's load (it would start once it pays)
    prelude = "from skynav.datasets import execute\nexecute.HelpersPay.__call__ = lambda self, *a: True\n"
    proc = _spawn_generator(small_recipe(200), out, "workers=2, progress=False", prelude)
    try:
        _wait_until(proc, lambda: len(_helpers(proc.pid)) >= 1 and _count_json(out / "frames") >= 2, poll_s=0.05)
        kids = [k for k in _children(proc.pid) if _alive(k)]
        assert _helpers(proc.pid), kids
        os.kill(proc.pid, signal.SIGKILL)
    finally:
        proc.wait(30)
    deadline = time.monotonic() + 20   # the watchdog polls every 0.5 s; a worker may be mid-frame
    while any(_alive(k) for k in kids) and time.monotonic() < deadline:
        time.sleep(0.1)
    left = [k for k in kids if _alive(k)]
    for k in left:
        os.kill(k, signal.SIGKILL)
    assert not left, f"workers {left} outlived their killed parent"
