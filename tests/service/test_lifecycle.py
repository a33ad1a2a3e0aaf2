"""Security and lifecycle: loopback by default, the token, SIGTERM finishes running renders."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import threading
import time

import pytest

from .conftest import small_scene, start_server, worker_pids

TOKEN = "0123456789abcdef-test-token"


def _serve(*args):
    return subprocess.run([sys.executable, "-m", "skynav", "serve", *args], capture_output=True, text=True, timeout=120)


@pytest.mark.parametrize("args, words", [
    (["--host", "0.0.0.0"], "--token"),
    (["--host", "0.0.0.0", "--token", "short"], "at least 16"),
    (["--port", "70000"], "--port"),
    (["--workers", "0"], "--workers"),
    (["--facility", "no-such-facility.yaml"], "no such facility"),
])
def test_refused_start_is_one_line(args, words):
    run = _serve(*args)
    assert run.returncode == 2
    lines = run.stderr.strip().splitlines()
    assert len(lines) == 1 and words in lines[0] and "Traceback" not in run.stderr, run.stderr


def test_default_binds_loopback_and_help_names_the_bounds():
    run = _serve("--help")
    assert run.returncode == 0
    text = " ".join(run.stdout.split())
    for words in ("127.0.0.1", "--max-request-bytes", "--max-camera-pixels", "--max-queue", "screen_png",
                  "--header-timeout S", "(default 10)", "--max-header-bytes N", "(default 16384)",
                  "--max-connections-per-client N"):
        assert words in text


@pytest.mark.slow
def test_screen_png_is_the_bytes_of_render_hil(tmp_path):
    from skynav.scenes.presets import preset_mapping
    from skynav.service import Client, ServiceError

    s = start_server("--workers", "1", "--facility", "screen")
    try:
        good = Client(s.url)
        assert good.health()["facility"] == "screen" and "screen_png" in good.health()["outputs"]
        # the bench screen frame: the bytes of skynav render --hil (same code, same seed)
        screen = good.render(preset_mapping("default"), outputs=("screen_png",)).screen_png
        run = subprocess.run([sys.executable, "-m", "skynav", "render", "--hil", "screen", "-o", str(tmp_path / "hil")],
                             capture_output=True, text=True, timeout=300)
        assert run.returncode == 0, run.stderr
        assert screen == (tmp_path / "hil" / "frame.png").read_bytes()
        with pytest.raises(ServiceError) as e:     # a camera that is not the facility's
            good.render(small_scene(size=64), outputs=("screen_png",))
        assert e.value.status == 400 and "facility" in str(e.value)
    finally:
        assert s.stop() == 0


def test_token_then_sigterm_finishes_the_running_render():
    from skynav.service import Client, ServiceError

    s = start_server("--workers", "1", "--token", TOKEN)
    try:
        assert s.url.startswith("http://127.0.0.1:")
        scene = small_scene(size=512)
        with pytest.raises(ServiceError) as e:
            Client(s.url).render(scene)
        assert e.value.status == 401
        with pytest.raises(ServiceError) as e:
            Client(s.url, token=TOKEN + "x").render(scene)
        assert e.value.status == 401
        good = Client(s.url, token=TOKEN)
        assert good.health()["status"] == "ok"          # health needs no token
        want = good.render(scene, outputs=("png",)).png
        got = {}

        def slow():
            got["png"] = Client(s.url, token=TOKEN).render(scene, outputs=("png",)).png

        t = threading.Thread(target=slow)
        t.start()
        time.sleep(0.1)   # the request is in (or queued for) the worker
        rc = s.stop(signal.SIGTERM, timeout_s=120)
        t.join(120)
        assert rc == 0, s.output
        assert got.get("png") == want
        assert "stopped" in s.output and "Traceback" not in s.output
    finally:
        if s.proc.poll() is None:
            s.proc.kill()


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="finds the worker through /proc")
def test_a_killed_worker_is_one_503_then_a_fresh_worker_serves():
    """The server talks to its worker in the event loop: a worker killed mid-frame (as the
    out-of-memory killer would) is a 503 one-liner for that request, is replaced, and the next
    request gets its frame from the new worker; the server still stops cleanly."""
    import os

    from skynav.service import Client, ServiceError

    s = start_server("--workers", "1")
    try:
        client = Client(s.url)
        scene = small_scene(size=96)
        want = client.render(scene, outputs=("png",)).png
        (victim,) = worker_pids(s.proc.pid)
        big = small_scene(size=4096)   # the largest frame the server takes: ~1 s or more
        caught = {}

        def doomed():
            try:
                Client(s.url).render(big, outputs=("png", "exr", "truth"))
            except ServiceError as exc:
                caught["e"] = exc

        t = threading.Thread(target=doomed)
        t.start()
        t_end = time.monotonic() + 60
        while client.health()["busy"] == 0 and time.monotonic() < t_end:
            time.sleep(0.005)
        os.kill(victim, signal.SIGKILL)   # while the worker renders that frame
        t.join(300)
        assert caught["e"].status == 503 and "worker died" in str(caught["e"]), caught
        assert "\n" not in str(caught["e"])
        assert client.render(scene, outputs=("png",)).png == want
        (fresh,) = worker_pids(s.proc.pid)
        assert fresh != victim
        assert s.stop() == 0, s.output
        assert "Traceback" not in s.output, s.output
    finally:
        if s.proc.poll() is None:
            s.proc.kill()
