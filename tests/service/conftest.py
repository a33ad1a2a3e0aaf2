"""A real ``skynav serve`` process on 127.0.0.1 (an ephemeral port) for the service tests.

One server with two workers serves the whole session (it takes ~10 s to warm up); tests that must
stop or configure a server start their own with :func:`start_server`.
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

READY = re.compile(r"ready at (http://\S+)")


class Server:
    def __init__(self, proc, url, lines):
        self.proc, self.url, self.lines = proc, url, lines

    def stop(self, sig=signal.SIGTERM, timeout_s=60) -> int:
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
        return self.proc.wait(timeout_s)

    @property
    def output(self) -> str:
        return "".join(self.lines)


def start_server(*args, timeout_s=180, env=None) -> Server:
    """``skynav serve --port 0 ARGS`` as a subprocess; waits for its ready line."""
    cmd = [sys.executable, "-m", "skynav", "serve", "--port", "0", *args]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            env={**os.environ, **(env or {})})
    lines, found = [], []

    def pump():
        for line in proc.stdout:
            lines.append(line)
            m = READY.search(line)
            if m and not found:
                found.append(m.group(1))

    threading.Thread(target=pump, daemon=True).start()
    t_end = time.monotonic() + timeout_s
    while not found:
        if proc.poll() is not None or time.monotonic() > t_end:
            proc.kill()
            proc.wait(10)
            raise RuntimeError(f"skynav serve did not start: {''.join(lines)[-2000:]}")
        time.sleep(0.05)
    return Server(proc, found[0], lines)


@pytest.fixture(scope="session")
def server():
    s = start_server("--workers", "2")
    yield s
    s.stop()


@pytest.fixture(scope="session")
def client(server):
    from skynav.service import Client

    return Client(server.url)


def small_scene(name="default", *, size=128, **changes):
    """A built-in scene with a ``size`` x ``size`` camera (same plate scale) and ``changes`` merged in."""
    from skynav.scenes.presets import preset_mapping

    m = preset_mapping(name)
    m["camera"].update({"width": size, "height": size})
    for key, value in changes.items():
        m.setdefault(key, {}).update(value)
    return m


def worker_pids(server_pid: int) -> list[int]:
    """The pids of the render workers of the server process ``server_pid`` (Linux: /proc)."""
    pids = []
    for st in Path("/proc").glob("[0-9]*/stat"):
        try:
            parent = int(st.read_text().rsplit(")", 1)[1].split()[1])
            cmd = (st.parent / "cmdline").read_bytes()
        except OSError:
            continue
        if parent == server_pid and b"multiprocessing" in cmd and b"resource_tracker" not in cmd:
            pids.append(int(st.parent.name))
    return pids
