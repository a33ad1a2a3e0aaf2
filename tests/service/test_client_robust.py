"""The Python client against servers that misbehave: a real HTTP server on loopback (a raw socket
in a thread of the test) sends the bytes of each case, and every call ends within its deadline as
an answer or a one-line :class:`ServiceError` naming what was wrong."""

from __future__ import annotations

import json
import socket
import threading
import time

import pytest

from skynav.service import Client, ServiceError
from skynav.service.client import parse_multipart


def _read_request(conn) -> bytes:
    """One HTTP request from ``conn`` (its header and its Content-Length body); b"" at its end."""
    data = b""
    while b"\r\n\r\n" not in data:
        chunk = conn.recv(65536)
        if not chunk:
            return b""
        data += chunk
    head, _, body = data.partition(b"\r\n\r\n")
    n = next((int(line.split(b":")[1]) for line in head.split(b"\r\n") if line.lower().startswith(b"content-length:")), 0)
    while len(body) < n:
        body += conn.recv(65536)
    return head


class RawServer:
    """A server on 127.0.0.1 that answers the k-th request of each connection with
    ``answers(connection number, k, conn)`` (what it sends is the test's)."""

    def __init__(self, answer):
        self.answer, self.connections = answer, 0
        self.sock = socket.create_server(("127.0.0.1", 0))
        self.url = f"http://127.0.0.1:{self.sock.getsockname()[1]}"
        self.done = threading.Event()
        threading.Thread(target=self._accept, daemon=True).start()

    def _accept(self):
        while not self.done.is_set():
            try:
                conn, _ = self.sock.accept()
            except OSError:
                return
            self.connections += 1
            threading.Thread(target=self._serve, args=(conn, self.connections), daemon=True).start()

    def _serve(self, conn, number):
        with conn:
            try:
                for k in range(100):
                    if not _read_request(conn):
                        return
                    self.answer(number, k, conn)
            except OSError:   # the client went away (as it does at its deadline)
                return

    def close(self):
        self.done.set()
        self.sock.close()


@pytest.fixture
def raw_server():
    servers = []

    def make(answer):
        servers.append(RawServer(answer))
        return servers[-1]

    yield make
    for s in servers:
        s.close()


def _health(text: str) -> bytes:
    body = json.dumps({"status": "ok", "text": text}).encode()
    return b"HTTP/1.1 200 OK\r\ncontent-type: application/json\r\ncontent-length: %d\r\n\r\n%s" % (len(body), body)


def test_a_dripping_server_ends_the_call_at_its_deadline(raw_server):
    """One byte of answer every 0.2 s: the call ends at ``timeout_s`` (each byte does not restart it)."""
    def drip(number, k, conn):
        for byte in b"HTTP/1.1 200 OK\r\ncontent-length: 100000\r\n\r\n" + b"x" * 100000:
            conn.sendall(bytes([byte]))
            time.sleep(0.2)

    server = raw_server(drip)
    t0 = time.monotonic()
    with pytest.raises(ServiceError) as e:
        Client(server.url, timeout_s=1.5).health()
    took = time.monotonic() - t0
    assert "no complete answer within timeout_s = 1.5 s" in str(e.value) and e.value.status == 0
    assert 1.4 < took < 3.0, took


@pytest.mark.parametrize("head, words", [
    (b"HTTP/1.1 200 OK\r\ncontent-length: abc\r\n\r\n", "Content-Length 'abc': not a byte count"),
    (b"HTTP/1.1 200 OK\r\ncontent-length: -5\r\n\r\n", "Content-Length '-5': not a byte count"),
    (b"HTTP/1.1 200 OK\r\ncontent-length: 1e15\r\n\r\n", "Content-Length '1e15': not a byte count"),
    (b"HTTP/1.1 200 OK\r\ncontent-length: 1000000000000000\r\n\r\n", "Content-Length 1000000000000000: more than"),
    (b"HTTP/1.1 200 OK\r\ncontent-length: 4\r\ncontent-length: 5\r\n\r\n", "Content-Length '4, 5'"),
    (b"HTTP/1.1 200 OK\r\ntransfer-encoding: chunked\r\n\r\n", "without Content-Length"),
    (b"SSH-2.0-OpenSSH_9.6\r\n\r\n", "not an HTTP answer"),
    (b"HTTP/1.1 200 OK\r\n" + b"x-filler: " + b"y" * 70000 + b"\r\n\r\n", "header of more than 64 KiB"),
    (_health("")[:-5] + b"{{{{{", "not a JSON object"),
])
def test_a_malformed_answer_is_a_service_error_naming_it(raw_server, head, words):
    server = raw_server(lambda number, k, conn: conn.sendall(head))
    t0 = time.monotonic()
    with pytest.raises(ServiceError) as e:
        Client(server.url, timeout_s=5).health()
    assert words in str(e.value), str(e.value)
    assert "\n" not in str(e.value) and str(e.value).startswith(server.url)
    assert time.monotonic() - t0 < 4


@pytest.mark.parametrize("late", [False, True], ids=["with-the-answer", "while-idle"])
def test_bytes_after_an_answer_are_never_the_next_answer(raw_server, late):
    """The first connection sends a forged second answer after the first (in the same write, or
    0.2 s later while the connection is idle): the next call gets its own answer from a fresh
    connection."""
    def answer(number, k, conn):
        if number == 1:
            conn.sendall(_health("first") + (b"" if late else _health("forged")))
            if late:
                time.sleep(0.2)
                conn.sendall(_health("forged"))
        else:
            conn.sendall(_health(f"connection {number}, request {k}"))

    server = raw_server(answer)
    client = Client(server.url, timeout_s=5)
    assert client.health()["text"] == "first"
    time.sleep(0.5)
    assert client.health()["text"] == "connection 2, request 0"
    assert client.health()["text"] == "connection 2, request 1"   # a clean connection is kept


@pytest.mark.parametrize("part_head, words", [
    (b"Content-Type: image/png\r\nContent-Length: 4", "no Content-Disposition with a name"),
    (b"Content-Disposition: inline\r\nContent-Length: 4", "no Content-Disposition with a name"),
    (b'Content-Disposition: inline; name="png"\r\nContent-Length: x4', "part 'png': Content-Length 'x4'"),
    (b'Content-Disposition: inline; name="png"\r\nContent-Length: 400', "part 'png' of 400 bytes runs past the end"),
])
def test_a_malformed_multipart_answer_is_a_service_error(part_head, words):
    body = b"--B\r\n" + part_head + b"\r\n\r\nPNG!\r\n--B--\r\n"
    with pytest.raises(ServiceError) as e:
        parse_multipart(body, 'multipart/mixed; boundary="B"')
    assert words in str(e.value) and "\n" not in str(e.value), str(e.value)


def test_a_malformed_multipart_render_answer_from_a_server(raw_server):
    body = b"--B\r\nContent-Type: image/png\r\nContent-Length: 4\r\n\r\nPNG!\r\n--B--\r\n"
    head = (b'HTTP/1.1 200 OK\r\ncontent-type: multipart/mixed; boundary="B"\r\ncontent-length: %d\r\n\r\n'
            % len(body))
    server = raw_server(lambda number, k, conn: conn.sendall(head + body))
    with pytest.raises(ServiceError) as e:
        Client(server.url, timeout_s=5).render({"epoch": "2027-02-01"}, outputs=("png", "truth"))
    assert "no Content-Disposition with a name" in str(e.value)


def test_a_server_that_never_answers_and_one_that_refuses(raw_server):
    """Silence ends at the deadline; a closed port is 'cannot reach' at once."""
    server = raw_server(lambda number, k, conn: time.sleep(10))
    t0 = time.monotonic()
    with pytest.raises(ServiceError, match="within timeout_s = 1 s"):
        Client(server.url, timeout_s=1).health()
    assert time.monotonic() - t0 < 2
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    with pytest.raises(ServiceError, match="cannot reach the service"):
        Client(f"http://127.0.0.1:{port}", timeout_s=5).health()
