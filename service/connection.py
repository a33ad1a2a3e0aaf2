"""One kept-alive HTTP/1.1 connection of the render service's client (:mod:`skynav.service.client`).

The standard library only: the client's import loads no renderer, Mitsuba, Dr.Jit or web server.
"""

from __future__ import annotations

import math
import socket
import time


class Closed(ConnectionError):
    """The server closed a kept-alive connection before answering (nothing of an answer was read)."""


class Malformed(Exception):
    """The server's answer is not HTTP this client can read; one line naming what is wrong."""


#: The largest answer body the client takes, bytes (its Content-Length): a 4096 x 4096 frame's
#: PNG, EXR and truth together are under 200 MB.
MAX_ANSWER_BYTES = 1 << 30


def byte_count(text: str) -> int | None:
    """``text`` as a byte count (ASCII digits only), or None."""
    return int(text) if text.isascii() and text.isdigit() else None


class Connection:
    """One kept-alive HTTP/1.1 connection: a request in one write (Nagle's algorithm off), the
    answer's header parsed here, the answer read into one buffer that the connection keeps.

    ``http.client`` does the same with more Python on the path of every frame (a request's header
    and body in two writes, the answer's header through the e-mail parser, a new buffered reader
    per answer). The server is uvicorn, whose answers all
    carry a Content-Length; one without is refused (a chunked answer, as from a proxy in between).

    The buffer grows to the largest answer and is read into again by the next one: the kernel
    copies an answer into memory that is already mapped (a fresh ~250 KB buffer per frame is
    fresh pages, or at least a zero-fill), and the caller copies out of it only the bytes it keeps
    (:meth:`request` returns a view that holds until the next request on this connection).

    Every socket operation of a request waits at most until its ``deadline`` (``time.monotonic``
    seconds; :class:`TimeoutError` after it), however the server drips its bytes. The connection
    is closed after an answer with bytes past its end, and is not reused when anything arrived
    while it was idle: one request, one answer, never a stale one.
    """

    def __init__(self, host: str, port: int):
        self.host, self.port = host, port
        self.host_header = f"[{host}]:{port}" if ":" in host else f"{host}:{port}"
        self.sock = None
        self.buf = bytearray(1 << 17)
        self.deadline = math.inf

    def close(self) -> None:
        if self.sock is not None:
            self.sock.close()
            self.sock = None

    def drop_if_stale(self) -> None:
        """Close a kept-alive connection on which the server sent anything since its last answer
        (bytes no request asked for, or its end): the next request opens a fresh one."""
        if self.sock is None:
            return
        self.sock.settimeout(0.0)
        try:
            self.sock.recv(1, socket.MSG_PEEK)
        except BlockingIOError:
            return   # nothing to read: the connection is as the last answer left it
        except OSError:
            pass
        self.close()

    def head(self, method: str, path: str, headers: dict) -> bytes:
        """The request line and header lines of a request, less its Content-Length and the blank
        line (the same for every request of a kind: :class:`Client` keeps them)."""
        lines = [f"{method} {path} HTTP/1.1", f"Host: {self.host_header}", *(f"{k}: {v}" for k, v in headers.items())]
        return ("\r\n".join(lines) + "\r\n").encode("latin-1")

    def _left(self) -> float:
        left = self.deadline - time.monotonic()
        if left <= 0:
            raise TimeoutError("timed out")
        return left

    def request(self, head: bytes, body: bytes | None, deadline: float):
        """Send ``head`` (:meth:`head`) and ``body``; ``(status, headers with lower-case names, body
        as a memoryview into this connection's buffer, valid until its next request)``."""
        self.deadline = deadline
        if self.sock is None:
            self.sock = socket.create_connection((self.host, self.port), timeout=self._left())
            self.sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.sock.settimeout(self._left())   # sendall: the whole send within it
        if body is None:
            self.sock.sendall(head + b"\r\n")
        else:
            self.sock.sendall(b"%sContent-Length: %d\r\n\r\n%s" % (head, len(body), body))
        return self._answer()

    def _recv_into(self, view, got: int) -> int:
        self.sock.settimeout(self._left())
        k = self.sock.recv_into(view)
        if not k:
            if got:
                raise ConnectionError("the service closed the connection in the middle of an answer")
            raise Closed("the service closed the connection")
        return k

    def _header(self):
        """``(status, headers, status line, where the body starts, bytes read)`` of an answer."""
        buf, got = self.buf, 0
        while (end := buf.find(b"\r\n\r\n", 0, got)) < 0:
            if got >= 1 << 16:
                raise Malformed("an answer header of more than 64 KiB")
            with memoryview(buf) as view:
                got += self._recv_into(view[got:], got)
        if end > 1 << 16:
            raise Malformed("an answer header of more than 64 KiB")
        status_line, *header_lines = buf[:end].decode("latin-1").split("\r\n")
        version, _, rest = status_line.partition(" ")
        if not version.startswith("HTTP/1.") or not (rest[:3].isascii() and rest[:3].isdigit()):
            raise Malformed(f"not an HTTP answer: {status_line[:80]!r}")
        headers = {}
        for line in header_lines:
            k, _, v = line.partition(":")
            k, v = k.strip().lower(), v.strip()
            headers[k] = f"{headers[k]}, {v}" if k in headers else v
        return int(rest[:3]), headers, status_line, end + 4, got

    def _answer(self):
        status, headers, status_line, start, got = self._header()
        if "content-length" not in headers:   # uvicorn gives every answer one
            raise Malformed(f"an answer without Content-Length ({status_line[:80]!r})")
        n = byte_count(headers["content-length"])
        if n is None:
            raise Malformed(f"Content-Length {headers['content-length'][:40]!r}: not a byte count")
        if n > MAX_ANSWER_BYTES:
            raise Malformed(f"Content-Length {n}: more than the {MAX_ANSWER_BYTES} bytes the client takes")
        stop = start + n
        buf = self.buf
        while got < stop:
            if got == len(buf):   # a larger answer than any before: a larger buffer as its bytes come
                grown = bytearray(min(stop, 2 * len(buf)))
                grown[:got] = buf
                self.buf = buf = grown
            with memoryview(buf) as view:
                got += self._recv_into(view[got:min(stop, len(buf))], got)
        if got > stop or headers.get("connection", "").lower() == "close":
            self.close()   # bytes past the answer are no answer to anything: never read as the next one
        return status, headers, memoryview(buf)[start:stop]
