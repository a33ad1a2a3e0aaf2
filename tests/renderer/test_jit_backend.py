"""The LLVM/CUDA probe: subprocess isolation, the disable switch, the disk cache."""

from __future__ import annotations

import json
import os

import pytest

from skynav.infra.errors import SkynavError
from skynav.renderer import jit_backend as jb

LLVM15 = "/usr/lib/x86_64-linux-gnu/libLLVM-15.so"


@pytest.fixture
def fresh_probe(tmp_path, monkeypatch):
    """Isolated cache dir and empty in-process memo; the memo is cleared again afterwards so
    other tests see the real machine's verdict."""
    monkeypatch.setenv("SKYNAV_CACHE_DIR", str(tmp_path))
    monkeypatch.delenv("SKYNAV_DISABLE_LLVM", raising=False)
    jb._clear_memo()
    yield tmp_path
    jb._clear_memo()


def test_llvm_major_version_from_names():
    assert jb.llvm_major_version("/usr/lib/x86_64-linux-gnu/libLLVM-19.so") == 19
    assert jb.llvm_major_version("/lib/x86_64-linux-gnu/libLLVM.so.19.1") == 19
    assert jb.llvm_major_version("/usr/lib/llvm-14/lib/libLLVM-14.0.6.so.1") == 14
    assert jb.llvm_major_version("/usr/lib/llvm-18/lib/libLLVM.so") == 18
    assert jb.llvm_major_version("/opt/x/libfoo.so") is None


def test_find_libllvm_honours_env_and_prefers_new(monkeypatch):
    monkeypatch.setenv("DRJIT_LIBLLVM_PATH", "/some/where/libLLVM-99.so")
    assert jb.find_libllvm() == "/some/where/libLLVM-99.so"
    monkeypatch.delenv("DRJIT_LIBLLVM_PATH")
    found = jb.find_libllvm()
    if found is not None:  # whatever it found must be new enough
        assert jb.llvm_major_version(found) >= jb.MIN_LLVM_MAJOR


@pytest.mark.skipif(not os.path.exists(LLVM15), reason="needs the system libLLVM-15 to provoke the abort")
def test_probe_survives_broken_llvm(fresh_probe, monkeypatch):
    # With LLVM 15 Dr.Jit's first kernel aborts the process (SIGABRT in instruction selection):
    # the probe must run that in a child, report it, and leave this process alive.
    monkeypatch.setenv("DRJIT_LIBLLVM_PATH", LLVM15)
    status = jb.probe_llvm(timeout_s=120)
    assert status.available is False
    assert status.libllvm == LLVM15
    assert "failed" in status.reason or "timed out" in status.reason
    assert os.getpid() > 0  # still here
    # and configure_llvm does not bless the broken library
    assert jb.configure_llvm().available is False


def test_disable_switch(fresh_probe, monkeypatch):
    monkeypatch.setenv("SKYNAV_DISABLE_LLVM", "1")
    status = jb.probe_llvm()
    assert status.available is False and "SKYNAV_DISABLE_LLVM" in status.reason
    assert jb.llvm_available() is False


def test_auto_sensor_backend_prefers_llvm_then_cuda_then_numpy(fresh_probe, monkeypatch):
    """``backend="auto"`` is LLVM where it works, else CUDA where it works, else numpy; a backend
    asked for by name that does not work here is one line naming it and why."""
    monkeypatch.setenv("SKYNAV_DISABLE_LLVM", "1")
    monkeypatch.setenv("SKYNAV_DISABLE_CUDA", "1")
    assert jb.auto_sensor_backend() == "numpy"
    for name, switch in (("llvm", "SKYNAV_DISABLE_LLVM"), ("cuda", "SKYNAV_DISABLE_CUDA")):
        with pytest.raises(jb.BackendUnavailableError, match=f"^backend='{name}' requested but .*{switch}"):
            jb.require(name)
    monkeypatch.delenv("SKYNAV_DISABLE_CUDA")
    cuda = jb.probe_cuda().available
    assert jb.auto_sensor_backend() == ("cuda" if cuda else "numpy")
    monkeypatch.delenv("SKYNAV_DISABLE_LLVM")
    assert jb.auto_sensor_backend() == ("llvm" if jb.probe_llvm().available else "cuda" if cuda else "numpy")


def test_cache_file_is_reused(fresh_probe, monkeypatch):
    monkeypatch.setenv("DRJIT_LIBLLVM_PATH", jb.find_libllvm() or LLVM15)
    calls = []
    real = jb._run_probe

    def counting(*a, **k):
        calls.append(a)
        return real(*a, **k)

    monkeypatch.setattr(jb, "_run_probe", counting)
    first = jb.probe_llvm(timeout_s=120)
    assert len(calls) == 1
    data = json.loads(jb.cache_path().read_text())
    assert len(data) == 1 and next(iter(data.values()))["available"] == first.available
    jb._clear_memo()  # a new process would start with an empty memo: only the file remains

    def forbidden(*a, **k):
        raise AssertionError("probe subprocess re-run although the cache is valid")

    monkeypatch.setattr(jb, "_run_probe", forbidden)
    second = jb.probe_llvm()
    assert second.available == first.available and second.reason.endswith("(cached)")
    # a different library (different key) is probed afresh
    monkeypatch.setattr(jb, "_run_probe", lambda *a, **k: (False, "stub verdict"))
    jb._clear_memo()
    monkeypatch.setenv("DRJIT_LIBLLVM_PATH", str(fresh_probe / "libLLVM-20.so"))
    third = jb.probe_llvm()
    assert third.available is False and "stub verdict" in third.reason
    assert len(json.loads(jb.cache_path().read_text())) == 2


def test_select_variant_is_consistent(fresh_probe):
    variant, reason = jb.select_mitsuba_variant()
    assert variant in ("cuda_ad_spectral", "llvm_ad_spectral", "scalar_spectral")
    assert reason
    if variant == "llvm_ad_spectral":
        assert jb.probe_llvm().available


def test_disable_switch_sends_sensor_to_numpy(fresh_probe, monkeypatch):
    import numpy as np

    from skynav.renderer.detector import Sensor
    from skynav.scenes.camera import SensorParams

    monkeypatch.setenv("SKYNAV_DISABLE_LLVM", "1")
    monkeypatch.setenv("SKYNAV_DISABLE_CUDA", "1")   # else "auto" is the GPU's kernel on a GPU machine
    s = Sensor(SensorParams(), (8, 8))
    d = s.expose_details(np.full((8, 8), 100.0), 0.1, np.random.default_rng(0))
    assert d.backend == "numpy"
    with pytest.raises(jb.BackendUnavailableError, match="SKYNAV_DISABLE_LLVM"):
        s.expose(np.full((8, 8), 100.0), 0.1, np.random.default_rng(0), backend="llvm")


def test_importing_renderer_does_not_initialise_llvm(tmp_path):
    # A fresh interpreter imports every skynav.renderer module, THEN configure_llvm() points
    # Dr.Jit at the good libLLVM, and an LLVM exposure runs: this only works if no import
    # initialised the LLVM backend (with whatever default library) before.
    import subprocess
    import sys

    status = jb.configure_llvm()
    if not status.available:
        pytest.skip(f"LLVM backend unavailable: {status.reason}")
    code = (
        "import importlib, pkgutil, os, sys\n"
        "import skynav.renderer as R\n"
        "for m in pkgutil.iter_modules(R.__path__):\n"
        "    importlib.import_module('skynav.renderer.' + m.name)\n"
        "from skynav.renderer import jit_backend, detector\n"
        "from skynav.scenes.camera import SensorParams\n"
        "import numpy as np\n"
        "assert jit_backend.configure_llvm().available\n"
        "d = detector.Sensor(SensorParams(), (8, 8)).expose_details(np.full((8, 8), 50.0), 0.1, np.random.default_rng(0), backend='llvm')\n"
        "print('OK', d.backend)\n"
    )
    env = {k: v for k, v in os.environ.items() if k != "DRJIT_LIBLLVM_PATH"}
    env["SKYNAV_CACHE_DIR"] = str(tmp_path)
    proc = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0 and "OK llvm" in proc.stdout, proc.stderr[-2000:]


def test_thread_budget_parses_and_refuses_bad_values(monkeypatch):
    monkeypatch.delenv("SKYNAV_THREADS", raising=False)
    assert jb.thread_budget() is None
    monkeypatch.setenv("SKYNAV_THREADS", "3")
    assert jb.thread_budget() == 3
    for bad in ("0", "-2", "two", "1.5"):
        monkeypatch.setenv("SKYNAV_THREADS", bad)
        with pytest.raises(SkynavError, match="SKYNAV_THREADS"):
            jb.thread_budget()


def test_thread_budget_sizes_drjit_and_openexr_pools(tmp_path):
    # In a fresh interpreter (the pools are process-wide): SKYNAV_THREADS=1 gives Dr.Jit one
    # thread and OpenEXR none (compression in the caller); unset, OpenEXR gets the cores.
    import subprocess
    import sys

    status = jb.configure_llvm()
    code = (
        "import io, numpy as np, OpenEXR\n"
        "from skynav.renderer import jit_backend\n"
        "from skynav.datasets import frame_files\n"
        "ok = jit_backend.configure_llvm().available\n"
        "import drjit as dr\n"
        "frame_files.write_exr(io.BytesIO() if False else r'%s', {'a': np.zeros((4, 4), np.float32)})\n"
        "print(dr.thread_count() if ok else -1, OpenEXR.global_thread_count())\n" % (tmp_path / "a.exr")
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         env={**os.environ, "SKYNAV_THREADS": "1"}, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    jit, exr = map(int, out.stdout.split())
    assert exr == 0
    if status.available:
        assert jit == 1
    env = {k: v for k, v in os.environ.items() if k != "SKYNAV_THREADS"}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    cores = os.cpu_count() or 1
    assert int(out.stdout.split()[1]) == (cores if cores >= 2 else 0)


def test_frames_with_different_cosmic_ray_hits_replay_without_recording_again(tmp_path):
    # Each frame's cosmic rays hit another number of pixels. The whole-image kernel is a Dr.Jit
    # frozen function replayed frame after frame; the hit pixels' kernel is one too, replayed on
    # lanes padded to a power of two: were every new count recorded again, Dr.Jit would print "The
    # frozen function has been recorded N times" into a dataset run's output after ten. Counts of
    # 1 to 300 (sizes 64, 128, 256, 512). A fresh interpreter: the log is the process's.
    import subprocess
    import sys

    status = jb.configure_llvm()
    if not status.available:
        pytest.skip(f"LLVM backend unavailable: {status.reason}")
    code = (
        "import numpy as np\n"
        "from skynav.renderer import jit_backend, detector\n"
        "from skynav.scenes.camera import SensorParams\n"
        "assert jit_backend.configure_llvm().available\n"
        "s = detector.Sensor(SensorParams(), (32, 32))\n"
        "for k in list(range(14)) + [70, 140, 200, 299] * 4:\n"
        "    x = detector.PixelCharge(index=np.arange(k + 1) * 3, electrons=np.full(k + 1, 900.0))\n"
        "    s.expose(np.full((32, 32), 50.0), 0.1, np.random.default_rng(k), backend='llvm', extra_charge_e=x)\n"
        "print('OK')\n"
    )
    env = dict(os.environ, SKYNAV_CACHE_DIR=str(tmp_path))
    proc = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0 and "OK" in proc.stdout, proc.stderr[-2000:]
    assert "recorded" not in proc.stderr + proc.stdout, proc.stderr[-2000:]
