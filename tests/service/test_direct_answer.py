"""A 200 answer written by the worker straight to the client's socket (``skynav.direct``): the
same bytes as uvicorn would write, whole for a client that reads slowly, in order for pipelined
requests, and no client socket left in the worker."""

from __future__ import annotations

import asyncio
import json
import logging
import os
import socket
import sys
import time
import urllib.parse

import pytest

from .conftest import small_scene


class _Transport:
    def __init__(self):
        self.data = []

    def write(self, data):
        self.data.append(bytes(data))

    def is_closing(self):
        return False

    def close(self):
        pass


@pytest.mark.parametrize("keep_alive", [True, False])
@pytest.mark.parametrize("lines", [[], ["camera: one warning", "and a second"]])
def test_the_workers_head_is_the_one_uvicorn_writes(keep_alive, lines):
    """answer_head against uvicorn's own RequestResponseCycle.send for the same answer."""
    from uvicorn.protocols.http.flow_control import FlowControl
    from uvicorn.protocols.http.httptools_impl import RequestResponseCycle

    from skynav.service.protocol import answer_head, answer_headers, uvicorn_takes

    defaults = [(b"date", b"Thu, 26 Nov 2026 11:00:00 GMT"), (b"server", b"uvicorn")]
    headers = answer_headers('multipart/mixed; boundary="b"', 0.0123456789, lines)
    assert uvicorn_takes(headers)
    transport = _Transport()
    cycle = RequestResponseCycle(
        scope={"type": "http", "method": "POST", "path": "/v1/render", "http_version": "1.1", "headers": []},
        transport=transport, flow=FlowControl(transport), logger=logging.getLogger("test"),
        access_logger=logging.getLogger("test"), access_log=False, default_headers=defaults,
        message_event=asyncio.Event(), expect_100_continue=False, keep_alive=keep_alive, on_response=lambda: None)
    asyncio.run(cycle.send({"type": "http.response.start", "status": 200,
                            "headers": [*headers, (b"content-length", b"245036")]}))
    mine = answer_head(b"".join(b"%s: %s\r\n" % h for h in defaults), headers, 245036, keep_alive)
    assert transport.data == [mine]
    assert not uvicorn_takes(answer_headers("image/png", 0.1, ["a bell \x07 in a warning"]))


def _request(scene, outputs) -> bytes:
    body = json.dumps({**scene, "outputs": list(outputs)}).encode()
    return (f"POST /v1/render HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\n"
            f"Content-Length: {len(body)}\r\n\r\n").encode() + body


def _read_answer(sock, buf: bytearray) -> tuple[list, bytes]:
    """(header lines, body) of one answer read from ``sock``; ``buf`` keeps what came after it."""
    while b"\r\n\r\n" not in buf:
        chunk = sock.recv(65536)
        assert chunk, "the server closed the connection"
        buf += chunk
    end = buf.index(b"\r\n\r\n")
    lines = buf[:end].decode("latin-1").split("\r\n")
    n = next(int(v) for k, _, v in (line.partition(": ") for line in lines[1:]) if k.lower() == "content-length")
    while len(buf) < end + 4 + n:
        chunk = sock.recv(1 << 20)
        assert chunk, "the server closed the connection in the middle of an answer"
        buf += chunk
    body = bytes(buf[end + 4:end + 4 + n])
    del buf[:end + 4 + n]
    return lines, body


def _connect(url, rcvbuf=None):
    u = urllib.parse.urlsplit(url)
    sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    if rcvbuf:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, rcvbuf)
    sock.settimeout(120)
    sock.connect((u.hostname, u.port))
    return sock


def test_a_client_that_reads_slowly_gets_the_whole_answer(server):
    """An ~8 MB answer (more than a socket's send buffer holds, 4 MiB at most on Linux) to a client
    with a small receive buffer that waits before reading: the worker's socket takes a part of it,
    the server writes the rest; the bytes are those of a client that reads at once."""
    scene = small_scene(size=4096, render={"seed": 7})
    request = _request(scene, ("png", "exr", "truth"))
    with _connect(server.url) as sock:
        sock.sendall(request)
        want_lines, want = _read_answer(sock, bytearray())
    with _connect(server.url, rcvbuf=4096) as sock:
        sock.sendall(request)
        time.sleep(6)   # the frame renders in ~2 s; the answer waits in the buffers
        lines, got = _read_answer(sock, bytearray())
    assert lines[0] == "HTTP/1.1 200 OK"
    assert len(got) > 8_000_000 and got == want

    def names(ls):
        return [line.split(":")[0] for line in ls]

    assert names(lines) == names(want_lines)


def test_pipelined_requests_get_their_answers_in_order(server, client):
    """Three requests in one write on one connection (the third a bad one): three answers, in
    order, each the bytes of the same request alone; then the connection serves a fourth."""
    from skynav.service.client import parse_multipart

    scenes = [small_scene(size=96, render={"seed": 200 + k}) for k in range(3)]
    want = [client.render(s, outputs=("png", "truth")) for s in scenes[:2]]
    bad = small_scene(size=96, camera={"width": -1})
    with _connect(server.url) as sock:
        sock.sendall(_request(scenes[0], ("png", "truth")) + _request(scenes[1], ("png", "truth"))
                     + _request(bad, ("png",)))
        buf = bytearray()
        for k in range(2):
            lines, body = _read_answer(sock, buf)
            assert lines[0] == "HTTP/1.1 200 OK", lines
            ctype = next(line.split(": ", 1)[1] for line in lines if line.lower().startswith("content-type:"))
            parts = parse_multipart(body, ctype)
            assert parts["png"] == want[k].png and parts["truth"] == want[k].truth_json, k
        lines, body = _read_answer(sock, buf)
        assert lines[0].startswith("HTTP/1.1 400") and b"camera" in body, (lines, body)
        sock.sendall(_request(scenes[2], ("png",)))
        lines, body = _read_answer(sock, buf)
        assert lines[0] == "HTTP/1.1 200 OK" and body == client.render(scenes[2], outputs=("png",)).png


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads the workers' file descriptors in /proc")
def test_the_workers_keep_no_client_socket(server, client):
    """A worker holds a client's socket only while it writes that client's answer."""
    from .test_lifecycle import _worker_pids

    def sockets(pid):
        found = set()
        for fd in os.listdir(f"/proc/{pid}/fd"):
            try:
                target = os.readlink(f"/proc/{pid}/fd/{fd}")
            except OSError:
                continue
            if target.startswith("socket:"):
                found.add(target)
        return found

    def idle():   # a worker tells the server it is done after it has closed the client's socket
        t_end = time.monotonic() + 120
        while client.health()["busy"] and time.monotonic() < t_end:
            time.sleep(0.05)

    workers = _worker_pids(server.proc.pid)
    assert workers
    idle()   # frames of earlier tests' clients that hung up may still be rendering
    before = {p: sockets(p) for p in workers}
    for k in range(6):
        client.render(small_scene(size=64, render={"seed": 300 + k}), outputs=("png",))
    idle()
    assert {p: sockets(p) for p in workers} == before


def test_a_uvicorn_cycle_without_what_the_direct_answer_uses_sends_it_through_uvicorn():
    """Another uvicorn whose request-response cycle lacks an attribute the direct answer reads or
    sets gets the ordinary path (a hand-over slower), never an error; a cycle with them all, idle,
    gets the direct one."""
    from skynav.service.server import _Direct

    class Transport:
        def is_closing(self):
            return False

        def get_write_buffer_size(self):
            return 0

    class Cycle:
        disconnected = response_started = response_complete = False
        default_headers = [(b"server", b"uvicorn")]
        keep_alive = True
        message_event = asyncio.Event()

        def on_response(self):
            pass

    assert _Direct(Cycle(), Transport()).usable() is True
    for missing in ("default_headers", "keep_alive", "on_response", "message_event", "response_complete"):
        partial = type("Partial", (), {k: v for k, v in vars(Cycle).items() if k != missing and not k.startswith("__")})
        assert _Direct(partial(), Transport()).usable() is False, missing
    busy = Cycle()
    busy.response_started = True
    assert _Direct(busy, Transport()).usable() is False
