"""The client of the render service: what flight software, benches and simulators import.

It loads no renderer, Mitsuba or Dr.Jit (``tests/test_architecture.py`` checks it in a fresh
interpreter): only the standard library (a socket speaking HTTP/1.1 with keep-alive), numpy, and
the frame-file readers of :mod:`skynav.datasets.frame_files` to decode the PNG and EXR it receives.

>>> from skynav.service import Client
>>> client = Client("http://127.0.0.1:8765")                      # doctest: +SKIP
>>> frame = client.render(scene_mapping, outputs=("png", "truth"))  # doctest: +SKIP
>>> frame.dn.shape, frame.truth["bodies"][0]["xy"]                  # doctest: +SKIP
"""

from __future__ import annotations

import io
import json
import signal
import socket
import subprocess
import sys
import threading
import time
import urllib.parse
from dataclasses import dataclass, field

from skynav.datasets.frame_files import read_exr, read_png
from skynav.scenes.errors import SkynavError

from .protocol import API_PREFIX, MULTIPART, OUTPUTS

__all__ = ["Client", "LocalServer", "RenderResult", "ServiceError"]


class ServiceError(SkynavError):
    """The service refused a request (``status`` 4xx: bad input) or could not be reached (``status`` 0)."""

    def __init__(self, message: str, status: int = 0):
        super().__init__(message)
        self.status = status


@dataclass
class RenderResult:
    """The outputs of one ``render`` call. Absent outputs are None."""

    png: bytes | None = None
    exr: bytes | None = None
    truth_json: bytes | None = None
    screen_png: bytes | None = None
    render_seconds: float = float("nan")
    warnings: list = field(default_factory=list)

    @property
    def truth(self) -> dict | None:
        """The ground truth (``skynav.frame/2``), parsed."""
        return None if self.truth_json is None else json.loads(self.truth_json.decode("utf-8"))

    @property
    def dn(self):
        """Digital counts, (H, W) uint8/uint16 (the PNG decoded, sBIT scaling undone)."""
        if self.png is None:
            return None

        return read_png(io.BytesIO(self.png))

    @property
    def electrons(self):
        """Noise-free expected signal per pixel, e-, (H, W) float32 (the EXR's ``electrons`` channel)."""
        return None if self.exr is None else self._exr()["electrons"]

    @property
    def irradiance_w_m2(self):
        return None if self.exr is None else self._exr()["irradiance_w_m2"]

    def _exr(self) -> dict:
        return read_exr(io.BytesIO(self.exr))


class _Closed(ConnectionError):
    """The server closed a kept-alive connection before answering (nothing of an answer was read)."""


class _Connection:
    """One kept-alive HTTP/1.1 connection: a request in one write (Nagle's algorithm off), the
    answer's header parsed here, its body read straight into one buffer.

    ``http.client`` did the same in ~4x the Python (a request's header and body in two writes, the
    answer's header through the e-mail parser, a new buffered reader per answer): ~0.3 ms of the
    client's CPU per frame, on the path of every frame. The server is uvicorn, whose answers all
    carry a Content-Length; one without is refused (a chunked answer, as from a proxy in between).
    """

    def __init__(self, host: str, port: int, timeout_s: float):
        self.host, self.port, self.timeout_s = host, port, timeout_s
        self.host_header = f"[{host}]:{port}" if ":" in host else f"{host}:{port}"
        self.sock = None
        self.rest = b""     # bytes read past the last answer (none from a well-behaved server)

    def close(self) -> None:
        if self.sock is not None:
            self.sock.close()
            self.sock = None
        self.rest = b""

    def request(self, method: str, path: str, body: bytes | None, headers: dict):
        if self.sock is None:
            self.sock = socket.create_connection((self.host, self.port), timeout=self.timeout_s)
            self.sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        lines = [f"{method} {path} HTTP/1.1", f"Host: {self.host_header}"]
        lines += [f"{k}: {v}" for k, v in headers.items()]
        if body is not None:
            lines.append(f"Content-Length: {len(body)}")
        head = ("\r\n".join(lines) + "\r\n\r\n").encode("latin-1")
        self.sock.sendall(head + body if body is not None else head)
        return self._answer()

    def _answer(self):
        buf = self.rest
        while (end := buf.find(b"\r\n\r\n")) < 0:
            if len(buf) > 1 << 16:
                raise ConnectionError("an answer header of more than 64 KiB")
            chunk = self.sock.recv(1 << 16)
            if not chunk:
                if buf:
                    raise ConnectionError("the service closed the connection in the middle of an answer")
                raise _Closed("the service closed the connection")
            buf += chunk
        status_line, *header_lines = buf[:end].decode("latin-1").split("\r\n")
        version, _, rest = status_line.partition(" ")
        if not version.startswith("HTTP/1.") or not rest[:3].isdigit():
            raise ConnectionError(f"not an HTTP answer: {status_line[:80]!r}")
        status = int(rest[:3])
        headers = {}
        for line in header_lines:
            k, _, v = line.partition(":")
            k, v = k.strip().lower(), v.strip()
            headers[k] = f"{headers[k]}, {v}" if k in headers else v
        buf = buf[end + 4:]
        if "content-length" not in headers:   # uvicorn gives every answer one
            self.close()
            raise ConnectionError(f"an answer without Content-Length ({status_line[:80]!r})")
        data, self.rest = self._exactly(int(headers["content-length"]), buf)
        if headers.get("connection", "").lower() == "close":
            self.close()
        return status, headers, data

    def _exactly(self, n: int, buf: bytes) -> tuple[bytes, bytes]:
        """``n`` bytes (``buf`` first, then the socket), and what came past them."""
        if len(buf) >= n:
            return buf[:n], buf[n:]
        out = bytearray(n)
        view = memoryview(out)
        view[:len(buf)] = buf
        got = len(buf)
        while got < n:
            k = self.sock.recv_into(view[got:])
            if not k:
                raise ConnectionError("the service closed the connection in the middle of an answer")
            got += k
        return bytes(out), b""


class Client:
    """A connection to ``skynav serve`` at ``url``; thread-safe (one keep-alive connection per thread).

    Parameters
    ----------
    url : str
        ``http://HOST:PORT`` as the server's ready line prints it.
    token : str, optional
        The server's ``--token`` (sent as ``Authorization: Bearer TOKEN``).
    timeout_s : float
        Socket timeout of one request.
    """

    def __init__(self, url: str, token: str | None = None, *, timeout_s: float = 600.0):
        u = urllib.parse.urlsplit(url)
        if u.scheme != "http" or not u.hostname:
            raise ServiceError(f"{url}: expected http://HOST:PORT (the URL skynav serve prints)")
        self.url, self.token, self.timeout_s = url.rstrip("/"), token, float(timeout_s)
        self._host, self._port = u.hostname, u.port or 80
        self._local = threading.local()

    # ------------------------------------------------------------------ transport
    def _conn(self) -> _Connection:
        c = getattr(self._local, "conn", None)
        if c is None:
            c = self._local.conn = _Connection(self._host, self._port, self.timeout_s)
        return c

    def _request(self, method: str, path: str, body: bytes | None = None):
        """``(status, headers with lower-case names, body)`` of one request."""
        headers = {"Content-Type": "application/json"} if body is not None else {}
        if self.token is not None:
            headers["Authorization"] = f"Bearer {self.token}"
        conn = self._conn()
        for attempt in (0, 1):
            fresh = conn.sock is None
            try:
                return conn.request(method, API_PREFIX + path, body, headers)
            except (_Closed, BrokenPipeError, ConnectionResetError) as exc:
                conn.close()
                # a kept-alive connection the server closed while it was idle (uvicorn closes them
                # after 5 s): nothing of an answer came, so the request was not taken; once more
                if attempt or fresh:
                    raise ServiceError(f"{self.url}: the service closed the connection ({exc})") from None
            except OSError as exc:
                conn.close()
                raise ServiceError(f"{self.url}: cannot reach the service ({exc.strerror or exc})") from None

    @staticmethod
    def _raise_for(status: int, data: bytes) -> None:
        try:
            message = json.loads(data.decode("utf-8"))["error"]
        except Exception:  # noqa: BLE001 - not our JSON: show the start of it
            message = data[:200].decode("utf-8", "replace")
        raise ServiceError(f"service: {message}", status)

    # ------------------------------------------------------------------ API
    def health(self) -> dict:
        status, _, data = self._request("GET", "/health")
        if status != 200:
            self._raise_for(status, data)
        return json.loads(data)

    def wait_ready(self, timeout_s: float = 120.0) -> dict:
        """Poll ``/v1/health`` until it answers (a server still warming up does not listen yet)."""
        t_end = time.monotonic() + timeout_s
        while True:
            try:
                return self.health()
            except ServiceError:
                if time.monotonic() > t_end:
                    raise
                time.sleep(0.2)

    def render(self, scene: dict, outputs=("png", "truth")) -> RenderResult:
        """Render one frame of ``scene`` (a mapping with the keys of a scene file).

        ``outputs``: any of ``png``, ``exr``, ``truth``, ``screen_png`` (the latter when the server
        has a facility). Raises :class:`ServiceError` for a refused request (its one-line message).
        """
        if isinstance(outputs, str):
            outputs = (outputs,)
        outputs = tuple(outputs)
        for o in outputs:
            if o not in OUTPUTS:
                raise ServiceError(f"outputs: unknown output {o!r}; allowed: {', '.join(OUTPUTS)}")
        body = json.dumps({**scene, "outputs": list(outputs)}).encode("utf-8")
        status, headers, data = self._request("POST", "/render", body)
        if status != 200:
            self._raise_for(status, data)
        ctype = headers.get("content-type", "")
        parts = parse_multipart(data, ctype) if ctype.startswith(MULTIPART) else {outputs[0]: data}
        res = RenderResult(png=parts.get("png"), exr=parts.get("exr"), truth_json=parts.get("truth"),
                           screen_png=parts.get("screen_png"))
        try:
            res.render_seconds = float(headers.get("skynav-render-seconds", "nan"))
        except ValueError:
            pass
        w = headers.get("skynav-warnings")
        res.warnings = w.split(" | ") if w else []
        return res

    def close(self) -> None:
        c = getattr(self._local, "conn", None)
        if c is not None:
            c.close()
            self._local.conn = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def parse_multipart(data: bytes, content_type: str) -> dict:
    """``{name: bytes}`` of the server's multipart/mixed answer (each part has a Content-Length)."""
    boundary = None
    for param in content_type.split(";")[1:]:
        k, _, v = param.strip().partition("=")
        if k.lower() == "boundary":
            boundary = v.strip('"')
    if not boundary:
        raise ServiceError("service: a multipart answer without a boundary")
    delim = f"--{boundary}".encode("ascii")
    parts, pos = {}, 0
    while True:
        if not data.startswith(delim, pos):
            raise ServiceError("service: a malformed multipart answer")
        pos += len(delim)
        if data.startswith(b"--", pos):
            return parts
        pos += 2  # CRLF
        end = data.index(b"\r\n\r\n", pos)
        hdrs = {}
        for line in data[pos:end].decode("ascii").split("\r\n"):
            k, _, v = line.partition(":")
            hdrs[k.strip().lower()] = v.strip()
        name = hdrs["content-disposition"].split('name="', 1)[1].split('"', 1)[0]
        n = int(hdrs["content-length"])
        start = end + 4
        parts[name] = data[start:start + n]
        pos = start + n + 2


class LocalServer:
    """``skynav serve --port 0`` as a child process, for a program that wants its own server.

    >>> with LocalServer(workers=1) as url:       # doctest: +SKIP
    ...     frame = Client(url).render(scene)
    """

    def __init__(self, *args: str, workers: int = 1, timeout_s: float = 600.0):
        self.args, self.workers, self.timeout_s = args, int(workers), float(timeout_s)
        self.proc = None
        self.url = None

    def __enter__(self) -> str:
        self.proc = subprocess.Popen([sys.executable, "-m", "skynav", "serve", "--port", "0", "--workers",
                                      str(self.workers), *self.args], stdout=subprocess.PIPE, text=True)
        t_end = time.monotonic() + self.timeout_s
        while self.url is None:
            line = self.proc.stdout.readline()
            if not line or time.monotonic() > t_end:
                self.__exit__()
                raise ServiceError("skynav serve did not start (its error is printed above)")
            if "ready at " in line:
                self.url = line.split("ready at ", 1)[1].split()[0]
        return self.url

    def __exit__(self, *exc):
        if self.proc is not None and self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(120)
            except Exception:  # noqa: BLE001 - it did not stop: make it
                self.proc.kill()
                self.proc.wait()
        if self.proc is not None and self.proc.stdout is not None:
            self.proc.stdout.close()
