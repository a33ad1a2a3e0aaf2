"""The render service's answers on the wire: whole for a client that reads slowly, in order for
pipelined requests, with their times in ``Server-Timing``; and the service on uvicorn's public API."""

from __future__ import annotations

import json
import re
import socket
import time
import urllib.parse

from .conftest import small_scene


def _request(scene, outputs) -> bytes:
    body = json.dumps({**scene, "outputs": list(outputs)}).encode()
    return (f"POST /v1/render HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/json\r\n"
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
    """A ~5.2 MB answer (more than a socket's send buffer holds, 4 MiB at most on Linux; a 3072 x
    3072 frame, within the session server's memory budget per request) to a client with a small
    receive buffer that waits before reading: the bytes are those of a client that reads at once."""
    scene = small_scene(size=3072, render={"seed": 7})
    request = _request(scene, ("png", "exr", "truth"))
    with _connect(server.url) as sock:
        sock.sendall(request)
        want_lines, want = _read_answer(sock, bytearray())
    with _connect(server.url, rcvbuf=4096) as sock:
        sock.sendall(request)
        time.sleep(6)   # the frame renders in ~2 s; the answer waits in the buffers
        lines, got = _read_answer(sock, bytearray())
    assert lines[0] == "HTTP/1.1 200 OK"
    assert len(got) > 5_000_000 and got == want

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


def test_every_answer_says_its_times_in_server_timing(server, client):
    """A 200 answer's ``Server-Timing`` (W3C: ``name;dur=MILLISECONDS``) holds the queue, the
    worker's render and the server's own time; the render is the frame's share of the round trip
    the client timed, and the three add up to no more than that round trip."""
    from skynav.service.protocol import parse_server_timing

    scene = small_scene(size=64, render={"seed": 11})
    with _connect(server.url) as sock:
        t0 = time.perf_counter()
        sock.sendall(_request(scene, ("png",)))
        lines, _ = _read_answer(sock, bytearray())
        round_trip_s = time.perf_counter() - t0
    value = next(line.split(": ", 1)[1] for line in lines if line.lower().startswith("server-timing:"))
    assert re.fullmatch(r"queue;dur=\d+\.\d{3}, render;dur=\d+\.\d{3}, service;dur=\d+\.\d{3}", value), value
    times = parse_server_timing(value)
    assert set(times) == {"queue", "render", "service"}
    assert 0 < times["render"] and 0 <= times["queue"] and 0 < times["service"]
    assert sum(times.values()) <= round_trip_s
    r = client.render(scene, outputs=("png", "truth"))
    assert r.render_seconds == r.server_timing["render"] > 0


def test_the_service_uses_only_uvicorns_public_api():
    """No module of the service imports uvicorn's protocol implementations or any name of uvicorn
    that starts with an underscore, nor reads or sets such an attribute of a uvicorn object: an
    update of uvicorn cannot break what it does not promise. Checked on the source (the AST)."""
    import ast
    from pathlib import Path

    import skynav.service

    found = []
    for path in sorted(Path(skynav.service.__file__).parent.glob("*.py")):
        tree = ast.parse(path.read_text(), filename=str(path))
        uvicorn_names = set()
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                for alias in node.names:
                    if alias.name.split(".")[0] == "uvicorn":
                        uvicorn_names.add((alias.asname or alias.name).split(".")[0])
                        if any(part.startswith("_") or part == "protocols" for part in alias.name.split(".")):
                            found.append(f"{path.name}:{node.lineno} import {alias.name}")
            elif isinstance(node, ast.ImportFrom) and (node.module or "").split(".")[0] == "uvicorn":
                parts = node.module.split(".") + [alias.name for alias in node.names]
                if any(part.startswith("_") or part == "protocols" for part in parts):
                    found.append(f"{path.name}:{node.lineno} from {node.module} import ...")
        for node in ast.walk(tree):
            if isinstance(node, ast.Attribute) and node.attr.startswith("_") and not node.attr.startswith("__"):
                base = node.value
                while isinstance(base, ast.Attribute):
                    base = base.value
                if isinstance(base, ast.Name) and base.id in uvicorn_names:
                    found.append(f"{path.name}:{node.lineno} {base.id}....{node.attr}")
            if isinstance(node, ast.Constant) and isinstance(node.value, str) and "uvicorn.protocols" in node.value:
                found.append(f"{path.name}:{node.lineno} names uvicorn.protocols")
        if "_captured_signals" in path.read_text() or "httptools_impl" in path.read_text():
            found.append(f"{path.name}: names a private field of uvicorn")
    assert not found, found
