"""Frames of concurrent clients never mix; many connections and clients that hang up leave the
server answering."""

from __future__ import annotations

import json
import socket
import threading
import urllib.parse
from concurrent.futures import ThreadPoolExecutor

from .conftest import small_scene


def _scenes(n):
    # distinct seeds and pointings: a frame delivered to the wrong request would not match
    return [small_scene(size=96, render={"seed": 100 + k}, attitude={"twist_deg": 7.0 * k}) for k in range(n)]


def test_concurrent_clients_get_their_own_frames(client):
    from skynav.service import Client

    scenes = _scenes(6)
    reference = [client.render(s, outputs=("png", "truth")) for s in scenes]   # one at a time
    assert len({r.png for r in reference}) == len(scenes)
    jobs = [k for k in range(len(scenes)) for _ in range(3)]

    def one(k):
        r = Client(client.url).render(scenes[k], outputs=("png", "truth"))
        return k, r

    with ThreadPoolExecutor(max_workers=6) as pool:
        results = list(pool.map(one, jobs[::-1]))
    for k, r in results:
        assert r.png == reference[k].png, k
        assert r.truth_json == reference[k].truth_json, k
        assert r.truth["seeds"] == reference[k].truth["seeds"]


def test_fifty_connections_at_once_leave_it_answering(server, client):
    from skynav.service import Client

    scene = small_scene(size=64)
    want = client.render(scene, outputs=("png",)).png
    barrier = threading.Barrier(50)

    def one(i):
        c = Client(server.url)
        barrier.wait(timeout=60)
        if i % 5 == 0:
            return c.render(scene, outputs=("png",)).png == want
        return c.health()["status"] == "ok"

    with ThreadPoolExecutor(max_workers=50) as pool:
        assert all(pool.map(one, range(50)))
    assert client.health()["status"] == "ok"


def _raw(url, data: bytes, *, read: int = 0):
    u = urllib.parse.urlsplit(url)
    s = socket.create_connection((u.hostname, u.port), timeout=30)
    try:
        s.sendall(data)
        return s.recv(read) if read else b""
    finally:
        s.close()


def test_clients_that_disconnect_mid_request_or_mid_response(server, client):
    scene = small_scene(size=256)
    body = json.dumps({**scene, "outputs": ["png", "exr", "truth"]}).encode()
    head = (f"POST /v1/render HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/json\r\n"
            f"Content-Length: {len(body)}\r\n\r\n").encode()
    for _ in range(4):
        _raw(server.url, head + body[: len(body) // 2])            # hangs up in the middle of its request
        _raw(server.url, head + body, read=64)                      # reads the start of the answer, hangs up
        _raw(server.url, head + body)                               # never reads at all
        _raw(server.url, b"GARBAGE / HTTP/9\r\n\r\n", read=64)      # not HTTP
    assert client.health()["status"] == "ok"
    small = small_scene(size=64)
    assert client.render(small, outputs=("png",)).dn.shape == (64, 64)


def test_workers_are_separate_processes_with_their_share_of_threads(server):
    """Two workers are two processes (renders in parallel, no shared lock), and each starts with
    cores // workers threads for every library that starts a pool (Dr.Jit and OpenEXR through
    SKYNAV_THREADS, OpenBLAS, OpenMP, MKL): pools as wide as the machine would spin against each
    other. A variable the user set is passed through unchanged."""
    import os
    from pathlib import Path

    from skynav.infra.pool import THREAD_VARS

    kids = []
    for st in Path("/proc").glob("[0-9]*/stat"):
        try:
            parent = int(st.read_text().rsplit(")", 1)[1].split()[1])
            cmd = (st.parent / "cmdline").read_bytes()
            environ = (st.parent / "environ").read_bytes().decode(errors="replace")
        except OSError:
            continue
        if parent == server.proc.pid and b"multiprocessing" in cmd and b"resource_tracker" not in cmd:
            kids.append(dict(x.split("=", 1) for x in environ.split("\0") if "=" in x))
    assert len(kids) == 2, "two render workers, each its own process"
    share = str(max(1, (os.cpu_count() or 1) // 2))
    for env in kids:
        for name in THREAD_VARS:
            assert env.get(name) == os.environ.get(name, share), name


def test_a_kept_alive_connection_the_server_closed_while_idle_is_reopened(server):
    """uvicorn closes a kept-alive connection after 5 s without a request; the client's next
    request finds it closed before any answer came, opens a new one and gets its frame."""
    import time

    from skynav.service import Client

    c = Client(server.url)
    scene = small_scene(size=64)
    want = c.render(scene, outputs=("png",)).png
    first = c._local.conn.sock
    time.sleep(6.0)
    assert c.render(scene, outputs=("png",)).png == want
    assert c._local.conn.sock is not first, "a new connection"
    assert c.health()["status"] == "ok"
