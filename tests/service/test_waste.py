"""No work for no one: a queued request whose client hung up is not rendered, and a worker that
died while idle is replaced before it is given a request (a real ``skynav serve`` on loopback)."""

from __future__ import annotations

import json
import os
import signal
import socket
import sys
import threading
import time
import urllib.parse

import pytest

from .conftest import small_scene, worker_pids


def _raw_request(url: str, scene: dict) -> socket.socket:
    """A connection that has sent one render request (PNG only) and reads nothing."""
    u = urllib.parse.urlsplit(url)
    body = json.dumps({**scene, "outputs": ["png"]}).encode()
    sock = socket.create_connection((u.hostname, u.port), timeout=30)
    sock.sendall(b"POST /v1/render HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/json\r\n"
                 b"Content-Length: %d\r\n\r\n%s" % (len(body), body))
    return sock


def _exited(pid: int) -> bool:
    """Whether process ``pid`` has ended: all its threads (its files, and its pipe to the server,
    close with the last). Its command line empties, and its main thread is a zombie, while its
    other threads still exit, tens of ms on."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            state = f.read().rsplit(")", 1)[1].split()[0]
        return state in "ZX" and os.listdir(f"/proc/{pid}/task") == [str(pid)]
    except FileNotFoundError:
        return True


def _wait_for(predicate, timeout_s=30.0):
    t_end = time.monotonic() + timeout_s
    while not predicate():
        assert time.monotonic() < t_end, "timed out"
        time.sleep(0.01)


def test_queued_requests_whose_clients_hung_up_are_not_rendered(server, client):
    """Both workers render a frame; six large frames queue and their clients hang up; a small
    frame asked then starts as soon as a worker is free, not after the six (rendered, they would
    hold both workers for three 4096 x 4096 frames each)."""
    from skynav.service import Client

    t_end = {}

    def render(k):
        Client(server.url).render(small_scene(size=2048, render={"seed": 300 + k}), outputs=("png",))
        t_end[k] = time.perf_counter()

    threads = [threading.Thread(target=render, args=(k,)) for k in range(2)]
    for t in threads:
        t.start()
    _wait_for(lambda: client.health()["busy"] == 2)
    gone = [_raw_request(server.url, small_scene(size=4096, render={"seed": 302 + k})) for k in range(6)]
    _wait_for(lambda: client.health()["waiting"] == 6)
    for sock in gone:
        sock.close()
    t_probe = time.perf_counter()
    probe = client.render(small_scene(size=64, render={"seed": 310}), outputs=("png",))
    for t in threads:
        t.join(120)
    started_after_s = t_probe + probe.server_timing["queue"] - min(t_end.values())
    assert started_after_s < 1.0, (started_after_s, probe.server_timing)
    health = client.health()
    assert health["busy"] == 0 and health["waiting"] == 0, health


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="finds the workers through /proc")
def test_a_worker_killed_while_idle_costs_no_request_a_503(server, client):
    """A worker killed with SIGKILL between requests (as the out-of-memory killer would): every
    following request gets its frame, the same bytes as before, and the worker is replaced."""
    scene = small_scene(size=96, render={"seed": 320})
    want = client.render(scene, outputs=("png",)).png
    before = worker_pids(server.proc.pid)
    assert len(before) == 2
    os.kill(before[0], signal.SIGKILL)
    _wait_for(lambda: _exited(before[0]))
    for _ in range(4):   # the idle queue hands the workers out in turn: the dead one is met
        assert client.render(scene, outputs=("png",)).png == want
    _wait_for(lambda: len(set(worker_pids(server.proc.pid)) - set(before)) == 1, timeout_s=120)
    assert "died while idle" in server.output
