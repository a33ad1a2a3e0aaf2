"""The one place that probes Dr.Jit's LLVM / CUDA backends and picks Dr.Jit / Mitsuba variants.

Why this module exists
----------------------
Dr.Jit's LLVM backend needs libLLVM >= 19. On a machine whose default libLLVM is older (Debian 12
ships 14 and 15), ``import drjit`` and ``mi.set_variant("llvm_ad_*")`` succeed, and then the FIRST
kernel aborts the whole process in LLVM's instruction selection ("Cannot select ... fmaximum"). A
Python ``try`` cannot catch that. So the backends are probed in a SUBPROCESS (a tiny Dr.Jit kernel
and a tiny Mitsuba render), with a timeout; the verdict is cached on disk (keyed by the drjit and
mitsuba versions and the libLLVM path and mtime) and memoised in-process.

Dr.Jit reads ``DRJIT_LIBLLVM_PATH`` when its LLVM backend first initialises, which happens at the
first LLVM array operation or ``mi.set_variant("llvm_*")`` -- not at ``import drjit``.
:func:`configure_llvm` sets that variable before anything in skynav touches the LLVM backend; the
rest of ``skynav.renderer`` imports drjit/mitsuba lazily, inside functions, after calling it.

Environment
-----------
``SKYNAV_DISABLE_LLVM=1``
    Forces the LLVM backend unavailable (numpy / scalar paths); checked on every call.
``SKYNAV_DISABLE_CUDA=1``
    Same for CUDA.
``DRJIT_LIBLLVM_PATH``
    Honoured if already set (the probe then tests exactly that library).
``SKYNAV_THREADS=N``
    Threads this process may use: the size of Dr.Jit's CPU thread pool and of OpenEXR's
    (default: one per core). The dataset runner sets it to ``cores // workers`` in its worker
    processes so that N processes do not each start pools as wide as the machine and fight over
    the cores.
"""

from __future__ import annotations

import glob
import hashlib
import json
import logging
import os
import re
import subprocess
import sys
import tempfile
import threading
from dataclasses import dataclass
from importlib import metadata
from pathlib import Path

from skynav.infra.data_files import cache_dir
from skynav.infra.threads import thread_budget

from .errors import BackendUnavailableError  # noqa: F401  (its home is renderer/errors.py; re-exported)

log = logging.getLogger(__name__)

MIN_LLVM_MAJOR = 19
"""Oldest libLLVM major version Dr.Jit 1.x generates valid code for."""

DEFAULT_TIMEOUT_S = 180.0
"""Subprocess probe timeout, s (a cold Mitsuba LLVM render JIT-compiles a few kernels)."""

_CACHE_NAME = "jit_backend_probe.json"
_SEARCH_GLOBS = (
    "/usr/lib/x86_64-linux-gnu/libLLVM*.so*",
    "/usr/lib/aarch64-linux-gnu/libLLVM*.so*",
    "/usr/lib/llvm-*/lib/libLLVM*.so*",
    "/usr/lib64/libLLVM*.so*",
    "/usr/local/lib/libLLVM*.so*",
    "/opt/homebrew/opt/llvm/lib/libLLVM*.dylib",
    "/usr/local/opt/llvm/lib/libLLVM*.dylib",
)


@dataclass(frozen=True, kw_only=True)
class BackendStatus:
    """Verdict of a backend probe.

    Attributes
    ----------
    available : bool
        True if a Dr.Jit kernel and a Mitsuba render ran in a subprocess.
    reason : str
        One line: why (un)available.
    libllvm : str or None
        The libLLVM shared library the verdict is about (LLVM probes only).
    """

    available: bool
    reason: str
    libllvm: str | None = None


_lock = threading.RLock()
_memo: dict[tuple, BackendStatus] = {}
_variant_notice_done = False
_threads_applied: int | None = None


def _truthy(name: str) -> bool:
    return os.environ.get(name, "").strip().lower() not in ("", "0", "false", "no", "off")


def llvm_major_version(path: str) -> int | None:
    """Major version encoded in a libLLVM file name (``libLLVM-19.so``, ``libLLVM.so.19.1``,
    ``/usr/lib/llvm-18/lib/libLLVM.so``), or None if it cannot be told from the name."""
    name = os.path.basename(path)
    m = re.match(r"libLLVM[-.](?:so\.)?(\d+)", name)
    if m:
        return int(m.group(1))
    m = re.search(r"llvm-(\d+)", path)
    if m:
        return int(m.group(1))
    return None


_candidates_memo: list[str] | None = None


def _candidates() -> list[str]:
    global _candidates_memo
    if _candidates_memo is None:
        _candidates_memo = _search_candidates()
    return list(_candidates_memo)


def _search_candidates() -> list[str]:
    paths: set[str] = set()
    for pattern in _SEARCH_GLOBS:
        paths.update(glob.glob(pattern))
    try:
        out = subprocess.run(["ldconfig", "-p"], capture_output=True, text=True, timeout=10).stdout
        for line in out.splitlines():
            if "libLLVM" in line and "=>" in line:
                paths.add(line.split("=>", 1)[1].strip())
    except (OSError, subprocess.SubprocessError):
        pass
    # shared objects only: skip static archives and the split component libraries (libLLVMCore...)
    return sorted(p for p in paths if re.match(r"libLLVM([-.]|\.so)", os.path.basename(p)) and os.path.isfile(p))


def find_libllvm() -> str | None:
    """Path of the libLLVM Dr.Jit should use, or None.

    An existing ``DRJIT_LIBLLVM_PATH`` is honoured as is (even if old: the probe then says so).
    Otherwise the newest libLLVM >= 19 found in the usual system places and ``ldconfig -p``.
    """
    env = os.environ.get("DRJIT_LIBLLVM_PATH")
    if env:
        return env
    best: tuple[int, int, str] | None = None
    for path in _candidates():
        major = llvm_major_version(path)
        if major is None or major < MIN_LLVM_MAJOR:
            continue
        # prefer the newest major; among equals prefer the shortest, unversioned-looking name
        key = (major, -len(os.path.basename(path)), path)
        if best is None or key > best:
            best = key
    return best[2] if best else None


def _version(dist: str) -> str:
    try:
        return metadata.version(dist)
    except metadata.PackageNotFoundError:
        return "missing"


def _cache_key(kind: str, libllvm: str | None) -> str:
    parts = [kind, "drjit=" + _version("drjit"), "mitsuba=" + _version("mitsuba"), sys.version.split()[0]]
    if libllvm is not None:
        try:
            mtime = os.stat(libllvm).st_mtime_ns
        except OSError:
            mtime = -1
        parts += [os.path.realpath(libllvm), str(mtime)]
    if kind == "cuda":
        try:
            parts.append(Path("/proc/driver/nvidia/version").read_text()[:200])
        except OSError:
            parts.append("no-nvidia-driver")
    return hashlib.sha256("|".join(parts).encode()).hexdigest()[:24]


def cache_path() -> Path:
    """Path of the on-disk probe cache (JSON, one entry per key)."""
    return cache_dir() / _CACHE_NAME


def _cache_read() -> dict:
    try:
        with open(cache_path()) as f:
            data = json.load(f)
        return data if isinstance(data, dict) else {}
    except (OSError, ValueError):
        return {}


def _cache_write(key: str, status: BackendStatus) -> None:
    data = _cache_read()
    data[key] = {"available": status.available, "reason": status.reason, "libllvm": status.libllvm}
    path = cache_path()
    try:  # atomic: temp file + rename
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=".probe-", suffix=".json")
        with os.fdopen(fd, "w") as f:
            json.dump(data, f, indent=1, sort_keys=True)
        os.replace(tmp, path)
    except OSError as exc:  # a read-only cache is not fatal
        log.debug("cannot write probe cache %s: %s", path, exc)


# The probe program. It prints one JSON line on success; an abort, a crash or a hang is a failure.
_PROBE_SCRIPT = r"""
import json, sys
variant = sys.argv[1]
backend = variant.split("_", 1)[0]
import drjit as dr
if backend == "llvm":
    from drjit.llvm import Float
else:
    from drjit.cuda import Float
x = dr.arange(Float, 16)
total = float(dr.sum(dr.maximum(x * 0.5, 1.0))[0])
assert abs(total - 61.5) < 1e-4, total  # 0.5 * sum(0..15) = 60, plus max() lifting 0 and 0.5 to 1
import mitsuba as mi
mi.set_variant(variant)
scene = mi.load_dict({
    "type": "scene",
    "integrator": {"type": "path", "max_depth": 2},
    "sensor": {"type": "perspective",
               "film": {"type": "hdrfilm", "width": 4, "height": 4, "rfilter": {"type": "box"}},
               "sampler": {"type": "independent", "sample_count": 1}},
    "shape": {"type": "sphere", "to_world": mi.ScalarTransform4f().translate([0, 0, 5])},
    "emitter": {"type": "constant"},
})
import numpy as np
img = np.asarray(mi.render(scene, spp=1))
assert img.shape[:2] == (4, 4) and np.all(np.isfinite(img)), img.shape
print(json.dumps({"ok": True, "drjit": dr.__version__, "mitsuba": mi.__version__, "mean": float(img.mean())}))
"""


def _run_probe(variant: str, env_update: dict, timeout_s: float) -> tuple[bool, str]:
    env = dict(os.environ)
    env.update(env_update)
    env.setdefault("DRJIT_NUM_THREADS", "1")
    try:
        proc = subprocess.run(
            [sys.executable, "-c", _PROBE_SCRIPT, variant],
            env=env,
            capture_output=True,
            text=True,
            timeout=timeout_s,
        )
    except subprocess.TimeoutExpired:
        return False, f"{variant} probe timed out after {timeout_s:.0f} s"
    except OSError as exc:
        return False, f"{variant} probe could not start: {exc}"
    if proc.returncode == 0 and '"ok": true' in proc.stdout:
        return True, f"{variant} probe rendered"
    tail = (proc.stderr or proc.stdout or "").strip().splitlines()
    last = tail[-1][:200] if tail else "no output"
    if proc.returncode < 0:
        how = f"killed by signal {-proc.returncode}"
    else:
        how = f"exit code {proc.returncode}"
    return False, f"{variant} probe failed ({how}): {last}"


def probe_llvm(*, timeout_s: float = DEFAULT_TIMEOUT_S, use_cache: bool = True) -> BackendStatus:
    """Whether Dr.Jit's LLVM backend (and Mitsuba's ``llvm_ad_spectral``) work here.

    Runs a tiny Dr.Jit kernel and a 4x4 ``llvm_ad_spectral`` render in a subprocess with
    ``DRJIT_LIBLLVM_PATH`` set to :func:`find_libllvm`, so that an abort in an old libLLVM cannot
    kill this process. Cached on disk (see :func:`cache_path`) and memoised in-process.

    Parameters
    ----------
    timeout_s : float
        Subprocess time limit, s.
    use_cache : bool
        False: ignore (but refresh) the disk cache and the in-process memo.

    Returns
    -------
    BackendStatus
    """
    if _truthy("SKYNAV_DISABLE_LLVM"):
        return BackendStatus(available=False, reason="disabled by SKYNAV_DISABLE_LLVM", libllvm=None)
    lib = find_libllvm()
    if lib is None:
        return BackendStatus(available=False, reason=f"no libLLVM >= {MIN_LLVM_MAJOR} found (apt-get install libllvm{MIN_LLVM_MAJOR}, or set DRJIT_LIBLLVM_PATH)", libllvm=None)
    with _lock:
        if use_cache and ("llvm", lib) in _memo:  # cheap in-process check first (every expose() asks)
            return _memo[("llvm", lib)]
        key = _cache_key("llvm", lib)
        if use_cache:
            entry = _cache_read().get(key)
            if entry is not None:
                status = BackendStatus(available=bool(entry["available"]), reason=str(entry["reason"]) + " (cached)", libllvm=entry.get("libllvm"))
                _memo[("llvm", lib)] = status
                return status
        ok, why = _run_probe("llvm_ad_spectral", {"DRJIT_LIBLLVM_PATH": lib}, timeout_s)
        status = BackendStatus(available=ok, reason=f"{why} with {lib}", libllvm=lib)
        _cache_write(key, status)
        _memo[("llvm", lib)] = status
        return status


def probe_cuda(*, timeout_s: float = DEFAULT_TIMEOUT_S, use_cache: bool = True) -> BackendStatus:
    """Whether Dr.Jit's CUDA backend and Mitsuba's ``cuda_ad_spectral`` work here (subprocess,
    cached like :func:`probe_llvm`). ``SKYNAV_DISABLE_CUDA=1`` forces unavailable."""
    if _truthy("SKYNAV_DISABLE_CUDA"):
        return BackendStatus(available=False, reason="disabled by SKYNAV_DISABLE_CUDA")
    with _lock:
        if use_cache and ("cuda", None) in _memo:
            return _memo[("cuda", None)]
        key = _cache_key("cuda", None)
        if use_cache:
            entry = _cache_read().get(key)
            if entry is not None:
                status = BackendStatus(available=bool(entry["available"]), reason=str(entry["reason"]) + " (cached)")
                _memo[("cuda", None)] = status
                return status
        env = {}
        lib = find_libllvm()
        if lib is not None:  # the CUDA variant may still touch LLVM for host-side work
            env["DRJIT_LIBLLVM_PATH"] = lib
        ok, why = _run_probe("cuda_ad_spectral", env, timeout_s)
        status = BackendStatus(available=ok, reason=why)
        _cache_write(key, status)
        _memo[("cuda", None)] = status
        return status


def configure_llvm() -> BackendStatus:
    """Probe LLVM and, if it works, point ``DRJIT_LIBLLVM_PATH`` at the good libLLVM.

    Call this before anything in this process uses Dr.Jit's LLVM backend (every skynav module
    that uses it does so first). If the backend is unavailable, nothing is changed, and callers
    must use their numpy / scalar paths.
    """
    status = probe_llvm()
    if status.available and status.libllvm:
        current = os.environ.get("DRJIT_LIBLLVM_PATH")
        if current != status.libllvm:
            os.environ["DRJIT_LIBLLVM_PATH"] = status.libllvm
    if status.available:
        _apply_thread_count()
    return status


def _apply_thread_count() -> None:
    """Apply ``SKYNAV_THREADS`` to Dr.Jit's thread pool, once per value (after a good probe)."""
    global _threads_applied
    n = thread_budget()
    if n is None:
        return
    with _lock:
        if _threads_applied != n:
            # Dr.Jit only once the LLVM backend is chosen: import skynav.renderer loads neither Dr.Jit nor Mitsuba
            import drjit as dr

            dr.set_thread_count(n)
            _threads_applied = n


def llvm_available() -> bool:
    """Shorthand: :func:`configure_llvm` and return whether the LLVM backend may be used."""
    return configure_llvm().available


def auto_sensor_backend() -> str:
    """The sensor backend ``"auto"`` stands for here: ``"llvm"`` where Dr.Jit's LLVM backend
    works, else ``"cuda"`` where its CUDA backend works, else ``"numpy"``.

    LLVM comes first: the sensor's kernel is bound by memory bandwidth, and a GPU adds the copies of the image to it and back; a machine with both keeps the
    bits it had. A GPU machine without libLLVM >= 19 gets the GPU kernel rather than numpy.
    """
    if llvm_available():
        return "llvm"
    return "cuda" if probe_cuda().available else "numpy"


def require(backend: str) -> BackendStatus:
    """Make sure the Dr.Jit backend ``"llvm"`` or ``"cuda"`` works here (configured, for LLVM);
    :class:`BackendUnavailableError` naming it and why not otherwise."""
    status = configure_llvm() if backend == "llvm" else probe_cuda()
    if not status.available:
        name = {"llvm": "LLVM", "cuda": "CUDA"}[backend]
        raise BackendUnavailableError(f"backend={backend!r} requested but Dr.Jit's {name} backend is unavailable: "
                                      f"{status.reason}; use backend='numpy' or 'auto'")
    return status


def select_mitsuba_variant() -> tuple[str, str]:
    """The Mitsuba variant to use: ``cuda_ad_spectral`` if CUDA works, else ``llvm_ad_spectral``
    if LLVM works, else ``scalar_spectral``; with the reason, logged once per process
    (INFO).

    Returns
    -------
    variant : str
    reason : str
    """
    global _variant_notice_done
    cuda = probe_cuda()
    if cuda.available:
        variant, reason = "cuda_ad_spectral", cuda.reason
    else:
        llvm = configure_llvm()
        if llvm.available:
            variant, reason = "llvm_ad_spectral", f"{llvm.reason}; no usable CUDA GPU"
        else:
            variant, reason = "scalar_spectral", f"LLVM: {llvm.reason}; no usable CUDA GPU"
    with _lock:
        if not _variant_notice_done:
            _variant_notice_done = True
            # a note, not a problem: the command line shows it (unless -q), a library user
            # sees it with logging at INFO; spawned workers have no handler, so a run says it once
            log.info("Mitsuba variant %s (%s)", variant, reason)
            log.debug("CUDA probe: %s", cuda.reason)
    return variant, reason


def _clear_memo() -> None:
    """Forget in-process verdicts (tests)."""
    global _variant_notice_done, _candidates_memo
    with _lock:
        _memo.clear()
        _candidates_memo = None
        _variant_notice_done = False
