"""Slow, idle and greedy clients against a real ``skynav serve`` on loopback: header and body
deadlines, the header's size bound, the connection caps that displace idle connections first,
health while the workers are busy, an answer nobody reads.

The server of this module runs with short deadlines and small caps (``ARGS``) so that each case
takes a second or two; other addresses of 127.0.0.0/8 play other clients.
"""

from __future__ import annotations

import json
import socket
import sys
import threading
import time
import urllib.parse

import pytest

from .conftest import small_scene, start_server

ARGS = ("--workers", "1", "--header-timeout", "1", "--body-timeout", "1", "--write-timeout", "2",
        "--max-connections", "100", "--max-connections-per-client", "60")

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="other clients from 127.0.0.2-5 (Linux loopback)")


@pytest.fixture(scope="module")
def tight():
    s = start_server(*ARGS)
    yield s
    assert s.stop() == 0, s.output
    assert "Traceback" not in s.output, s.output


def _connect(url: str, source: str = "127.0.0.1") -> socket.socket:
    u = urllib.parse.urlsplit(url)
    sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    sock.bind((source, 0))
    sock.settimeout(10)
    sock.connect((u.hostname, u.port))
    return sock


def _closed_within(sock: socket.socket, seconds: float) -> tuple[bool, bytes]:
    """(whether the server closed ``sock`` within ``seconds``, what it sent before)."""
    sock.settimeout(0.05)
    got, t_end = b"", time.monotonic() + seconds
    while time.monotonic() < t_end:
        try:
            chunk = sock.recv(65536)
        except socket.timeout:
            continue
        except OSError:
            return True, got
        if not chunk:
            return True, got
        got += chunk
    return False, got


def _health_s(url: str, source: str = "127.0.0.1") -> float:
    """Seconds for a fresh connection from ``source`` to get a 200 from ``/v1/health``."""
    t0 = time.perf_counter()
    with _connect(url, source) as sock:
        sock.sendall(b"GET /v1/health HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
        data = b""
        while b'"status":"ok"' not in data:
            chunk = sock.recv(65536)
            assert chunk, data
            data += chunk
    assert data.startswith(b"HTTP/1.1 200"), data
    return time.perf_counter() - t0


def test_idle_and_dripping_connections_keep_no_one_out(tight):
    """140 connections from one address (past the server's 100 and the address's 60), half silent,
    half dripping a header a byte at a time: fresh clients, of that address and another, get
    their answers at once, and every one of the 140 is closed within the header deadline (1 s)."""
    silent = [_connect(tight.url) for _ in range(70)]
    dripping = [_connect(tight.url) for _ in range(70)]
    for k in range(3):
        for sock in dripping:
            try:
                sock.sendall(b"GET /v1/health HTTP/1.1\r\n"[k:k + 1])
            except OSError:
                pass   # displaced already
    assert _health_s(tight.url) < 1.0
    assert _health_s(tight.url, "127.0.0.2") < 1.0
    t0 = time.monotonic()
    for sock in silent + dripping:
        closed, _ = _closed_within(sock, max(0.0, 3.0 - (time.monotonic() - t0)))
        assert closed, "a connection outlived the header deadline"
        sock.close()


def test_a_dripped_header_gets_408_and_a_huge_one_400(tight):
    with _connect(tight.url) as sock:
        t0 = time.monotonic()
        sock.sendall(b"POST /v1/render HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Slow: ")
        try:
            while time.monotonic() - t0 < 5:
                sock.sendall(b"a")
                time.sleep(0.1)
        except OSError:
            pass
        closed, got = _closed_within(sock, 3)
        assert closed and time.monotonic() - t0 < 3
    assert got.startswith(b"HTTP/1.1 408") and b"--header-timeout" in got, got
    with _connect(tight.url) as sock:   # an endless header line: refused past the bound (16 KiB)
        sent = 0
        try:
            while sent < 64 << 20:
                sock.sendall(b"GET /v1/health HTTP/1.1\r\nX-Long: " if not sent else b"a" * 65536)
                sent += 65536
        except OSError:
            pass
        closed, got = _closed_within(sock, 3)
    assert closed and got.startswith(b"HTTP/1.1 400"), got
    assert sent < 16 << 20, sent   # what the socket buffers held, not the 64 MiB offered
    assert _health_s(tight.url) < 1.0


def test_a_stalled_body_gets_408_within_the_body_deadline(tight):
    with _connect(tight.url) as sock:
        t0 = time.monotonic()
        sock.sendall(b"POST /v1/render HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/json\r\n"
                     b"Content-Length: 1000\r\n\r\n{\"epoch\": ")
        closed, got = _closed_within(sock, 4)
        took = time.monotonic() - t0
    assert closed and 0.9 < took < 3, took
    head, _, body = got.partition(b"\r\n\r\n")
    assert head.startswith(b"HTTP/1.1 408"), got
    assert json.loads(body) == {"error": "request body: not received within 1 s (--body-timeout)"}


def test_one_client_is_capped_and_others_are_served(tight):
    """60 connections of 127.0.0.3 each in the middle of a request (a body on its way): its 61st
    is refused with a 503 line, while 127.0.0.4 is served; an address at its cap with idle
    connections gets its new one, its oldest idle one closed instead."""
    busy = [_connect(tight.url, "127.0.0.3") for _ in range(60)]
    for sock in busy:
        sock.sendall(b"POST /v1/render HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/json\r\n"
                     b"Content-Length: 100\r\n\r\n{")
    time.sleep(0.2)   # the requests are in the application, reading their bodies
    with _connect(tight.url, "127.0.0.3") as extra:
        closed, got = _closed_within(extra, 0.8)
    assert closed and got.startswith(b"HTTP/1.1 503") and b"too many connections" in got, got
    assert _health_s(tight.url, "127.0.0.4") < 1.0
    for sock in busy:
        sock.close()
    idle = [_connect(tight.url, "127.0.0.5") for _ in range(60)]
    time.sleep(0.1)
    assert _health_s(tight.url, "127.0.0.5") < 1.0   # displaces the oldest of the 60
    closed, _ = _closed_within(idle[0], 0.5)
    assert closed
    for sock in idle:
        sock.close()


def test_health_answers_while_the_worker_renders(tight):
    from skynav.service import Client

    client = Client(tight.url)
    t = threading.Thread(target=lambda: client.render(small_scene(size=2048, render={"seed": 5}), outputs=("png",)))
    t.start()
    try:
        probe = Client(tight.url, timeout_s=5)
        t_end = time.monotonic() + 30
        while probe.health()["busy"] == 0:
            assert time.monotonic() < t_end
        t0 = time.perf_counter()
        assert probe.health()["busy"] == 1
        assert time.perf_counter() - t0 < 0.5
    finally:
        t.join(120)


@pytest.mark.slow
def test_an_answer_nobody_reads_loses_its_connection(tight):
    """A client that asks for a 3072 x 3072 frame's PNG, EXR and truth (~5.2 MB, more than the
    socket buffers hold) and reads nothing: the connection is cut once the answer has stalled for
    --write-timeout (2 s), so what the client finds afterwards is less than the whole answer."""
    scene = small_scene(size=3072, render={"seed": 6})
    body = json.dumps({**scene, "outputs": ["png", "exr", "truth"]}).encode()
    u = urllib.parse.urlsplit(tight.url)
    sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    sock.connect((u.hostname, u.port))
    with sock:
        sock.sendall(b"POST /v1/render HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/json\r\n"
                     b"Content-Length: %d\r\n\r\n%s" % (len(body), body))
        time.sleep(20)   # the render (a few seconds) and 2 s of stall
        closed, got = _closed_within(sock, 10)
    head, _, answer = got.partition(b"\r\n\r\n")
    assert head.startswith(b"HTTP/1.1 200"), head[:200]
    n = next(int(line.split(b":")[1]) for line in head.split(b"\r\n") if line.lower().startswith(b"content-length:"))
    assert closed and n > 5_000_000 and len(answer) < n, (n, len(answer))
    assert _health_s(tight.url) < 1.0
