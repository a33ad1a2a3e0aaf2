"""The speed figures of the README and the closing notes come from ``benchmarks/`` scripts: each
named there runs here in its quickest form, so that a script that no longer runs is found by the
suite, not by the next person who needs its numbers. Nothing is timed: the lines the figures are
read from must be printed, with numbers in them."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _run(script: str, *args: str) -> str:
    proc = subprocess.run([sys.executable, str(ROOT / "benchmarks" / script), *args], capture_output=True, text=True,
                          cwd=ROOT, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return proc.stdout


def test_dataset_bench_prints_the_file_system_and_each_preset_ratio(tmp_path):
    out = _run("dataset_bench.py", "--small", "--no-scaling", "--split-frames", "2", "--warmup", "1", "--repeat", "1",
               "--dir", str(tmp_path))
    where = re.search(r"datasets written under (\S+), on (.+)", out)
    assert where and Path(where.group(1)).parent == tmp_path, out
    assert "mount options" in where.group(2) or "unknown" in where.group(2)
    for preset in ("montecarlo", "sequence"):
        line = re.search(rf"{preset} preset: dataset frame / its bare render, 1 thread, median of 1: ([0-9.]+) x", out)
        assert line and float(line.group(1)) > 1.0, out  # a dataset frame is a render and more
    assert not any(tmp_path.iterdir())  # its temporary folder is gone


def test_dataset_bench_scaling_prints_each_ratio_with_the_machines_ceiling(tmp_path):
    out = _run("dataset_bench.py", "--small", "--frames", "48", "--split-frames", "2", "--warmup", "1", "--repeat", "1",
               "--dir", str(tmp_path))
    cores = re.search(r"cores, pure-Python loop .*; two such processes = ([0-9.]+) x one on the faster core", out)
    assert cores and 0.5 < float(cores.group(1)) < 2.5, out  # two processes give at most about twice one
    for two, one in (("2 workers", "1 worker, 1 thread"), ("2 workers", "1 worker, 1 core"),
                     ("2 processes", "1 worker, 1 thread"), ("2 workers", "2 processes")):
        line = re.search(rf"scaling {two} / {one}: ([0-9.]+) x steady state", out)
        assert line and float(line.group(1)) > 0, out
    pair = re.search(r"2 processes +#1: steady state [0-9.]+ frames/s \((\d+) frames\); (\d+) frames in", out)
    assert pair and int(pair.group(2)) == 96, out  # two processes of 48 frames each, their frames summed
    # the same code and the same seed in every set-up (the pair's second folder too): one set of bytes
    assert "folders byte-identical: True" in out, out


def test_encoder_bench_prints_each_fast_paths_share_of_a_frame():
    out = _run("encoder_bench.py", "--small", "--frames", "2", "--warmup", "1")
    for name in ("PNG (zlib-ng Z_RLE, unfiltered) against Pillow", "EXR (sparse RLE) against OpenEXR's RLE"):
        line = re.search(rf"{re.escape(name)}: [0-9.]+ against [0-9.]+ ms; saves (-?[0-9.]+) % of the frame", out)
        assert line, out
    assert "decoded pixels identical: True" in out, out


def test_render_bench_prints_both_paths_against_numpys_variates():
    out = _run("render_bench.py", "--repeat", "2")
    for path in ("llvm ", "numpy"):
        line = re.search(rf"render, {path} sensor path: .* ratio to numpy variates +([0-9.]+)", out)
        if path == "llvm " and line is None:
            assert "llvm path: unavailable" in out, out  # no LLVM 19 here: the script says so instead
            continue
        assert line and float(line.group(1)) > 0, out


def test_gpu_bench_runs_without_a_gpu_on_the_cpu_backends_and_says_why_not_on_cuda():
    """Without a GPU the script refuses ``cuda`` in one line (exit 2) and gives the CPU's figures
    with ``--backends llvm numpy``; on a GPU machine ``test_gpu_bench_prints_cuda_figures`` runs it."""
    from skynav.renderer import jit_backend

    if not jit_backend.probe_cuda().available:
        proc = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "gpu_bench.py"), "--no-monte-carlo"],
                              capture_output=True, text=True, cwd=ROOT, timeout=600)
        assert proc.returncode == 2 and proc.stdout == "", proc
        assert re.fullmatch(r"gpu_bench: Dr\.Jit's CUDA backend does not work here \(.+\); run with --backends "
                            r"llvm numpy for the CPU's figures\n", proc.stderr), proc.stderr
    out = _run("gpu_bench.py", "--backends", "llvm", "numpy", "--repeat", "2", "--workers", "1", "--frames-per-worker", "4",
               "--small", "--batch", "--batch-sizes", "2", "--batch-px", "64")
    assert re.search(r"sensor numpy: frame +[0-9.]+ ms = +[0-9.]+ frames/s .* the sensor alone +[0-9.]+ ms", out), out
    assert re.search(r" 1 worker , sensor numpy: +[0-9.]+ frames/s steady \(64 frames", out), out
    if "sensor llvm" in out:  # the batched frames on the first Dr.Jit backend there is
        assert re.search(r"64 px, in memory: batch +2: +[0-9.]+ frames/s wall", out), out
        assert re.search(r"batched frames on llvm: nvidia-smi GPU utilisation while measuring: .+", out), out


def test_batch_bench_prints_each_batch_against_the_per_frame_path():
    from skynav.renderer import jit_backend

    if not jit_backend.llvm_available():
        pytest.skip("Dr.Jit's LLVM backend does not work here")
    out = _run("batch_bench.py", "--px", "64", "--sizes", "1", "2", "--repeat", "1", "--baseline-frames", "2", "--written")
    for mode in ("in memory", "written"):
        assert re.search(rf"64 px, {mode}: per-frame path +[0-9.]+ frames/s wall", out), out
        for n in (1, 2):
            line = re.search(rf"64 px, {mode}: batch +{n}: +[0-9.]+ frames/s wall \( *([0-9.]+)x the per-frame path\), "
                             r"+[0-9.]+ per CPU-s .*; per frame: optics [0-9.]+ ms, launch [0-9.]+ ms, sensor wait", out)
            assert line and float(line.group(1)) > 0, out


def test_batch_bench_times_the_bodies_blur_on_both_sides():
    from skynav.renderer import jit_backend

    if not jit_backend.llvm_available():
        pytest.skip("Dr.Jit's LLVM backend does not work here")
    out = _run("batch_bench.py", "--px", "64", "--sizes", "1", "--repeat", "1", "--baseline-frames", "1",
               "--scene", "earth_departure", "--bodies")
    assert re.search(r"64 px, in memory: batch +1: +[0-9.]+ frames/s wall", out), out
    for psf in ("the camera's PSF", "an Airy PSF"):
        assert re.search(rf"earth_departure \(1024 px\), {psf}: ray-traced bodies \(earth 40x40 px, [0-9]+ lit.*\) "
                         r"blurred and composited: numpy [0-9.]+ ms, Dr.Jit llvm [0-9.]+ ms a frame", out), out


@pytest.mark.gpu
def test_gpu_bench_prints_cuda_figures():
    out = _run("gpu_bench.py", "--backends", "cuda", "numpy", "--repeat", "2", "--workers", "1", "--frames-per-worker", "4",
               "--small")
    assert re.search(r"sensor cuda : frame +[0-9.]+ ms = +[0-9.]+ frames/s \( *[0-9.]+x the numpy frame\)", out), out
    assert re.search(r"1 worker: cuda / numpy [0-9.]+x", out), out
