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
    head = (f"POST /v1/render HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\n"
            f"Content-Length: {len(body)}\r\n\r\n").encode()
    for _ in range(4):
        _raw(server.url, head + body[: len(body) // 2])            # hangs up in the middle of its request
        _raw(server.url, head + body, read=64)                      # reads the start of the answer, hangs up
        _raw(server.url, head + body)                               # never reads at all
        _raw(server.url, b"GARBAGE / HTTP/9\r\n\r\n", read=64)      # not HTTP
    assert client.health()["status"] == "ok"
    small = small_scene(size=64)
    assert client.render(small, outputs=("png",)).dn.shape == (64, 64)
