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
import math
import signal
import subprocess
import sys
import threading
import time
import urllib.parse
from dataclasses import dataclass, field

import orjson
from skynav.datasets.frame_files import read_exr, read_png
from skynav.infra.errors import SkynavError

from .connection import Closed, Connection, Malformed, byte_count
from .protocol import API_PREFIX, MULTIPART, OUTPUTS, parse_server_timing

__all__ = ["Client", "LocalServer", "RenderResult", "ServiceError"]


class ServiceError(SkynavError):
    """The service refused a request (``status`` 4xx: bad input) or could not be reached (``status`` 0).

    Parameters
    ----------
    message : str
        One line naming the bad input and what is allowed (the server's ``error``, prefixed
        ``service:``), or why the service could not be reached.
    status : int
        The HTTP status of the refusal (4xx for bad input, 5xx for a failed render), or 0 when
        no answer came (connection refused, closed or timed out).

    Examples
    --------
    A URL that is not ``http://HOST:PORT`` is refused before any connection is made:

    >>> from skynav.service import Client, ServiceError
    >>> try:
    ...     Client("ftp://127.0.0.1:8765")
    ... except ServiceError as exc:
    ...     print(exc, exc.status)
    ftp://127.0.0.1:8765: expected http://HOST:PORT (the URL skynav serve prints) 0
    """

    def __init__(self, message: str, status: int = 0):
        super().__init__(message)
        self.status = status


@dataclass
class RenderResult:
    """The outputs of one :meth:`Client.render` call, as the server sent them; absent outputs are None.

    The files' bytes are kept as received; :attr:`dn`, :attr:`electrons`, :attr:`irradiance_w_m2`
    and :attr:`truth` decode them on each access.

    Attributes
    ----------
    png : bytes or None
        The frame's digital counts as a PNG (greyscale, sBIT-scaled; docs/conventions.md "Files").
    exr : bytes or None
        The float images as OpenEXR: channels ``electrons`` (e-) and ``irradiance_w_m2``
        (W/m^2 at the pupil, per pixel).
    truth_json : bytes or None
        The ground truth, a ``skynav.frame/2`` JSON document (UTF-8).
    screen_png : bytes or None
        The bench screen's frame (DN of the display) as a PNG, when the server has a facility.
    render_seconds : float
        The worker's time to render and encode the frame, s (``render`` of ``Server-Timing``);
        NaN if not sent.
    server_timing : dict
        The answer's ``Server-Timing`` durations, s: ``queue`` (waiting for a worker), ``render``,
        ``service`` (the rest of the server's time on the request).
    warnings : list of str
        The server's warnings for this request, one line each.

    Examples
    --------
    >>> import numpy as np
    >>> from skynav.datasets.frame_files import png_bytes
    >>> from skynav.service import RenderResult
    >>> res = RenderResult(png=png_bytes(np.array([[0, 4095]], dtype=np.uint16), bit_depth=12))
    >>> res.dn.tolist(), res.truth is None
    ([[0, 4095]], True)
    """

    png: bytes | None = None
    exr: bytes | None = None
    truth_json: bytes | None = None
    screen_png: bytes | None = None
    render_seconds: float = float("nan")
    server_timing: dict = field(default_factory=dict)
    warnings: list = field(default_factory=list)

    @property
    def truth(self) -> dict | None:
        """The ground truth (``skynav.frame/2``, docs/conventions.md "Files") as a dict, or None."""
        return None if self.truth_json is None else json.loads(self.truth_json.decode("utf-8"))

    @property
    def dn(self):
        """Digital counts, DN, (H, W) uint8 or uint16 (the PNG decoded, sBIT scaling undone), or None."""
        if self.png is None:
            return None

        return read_png(io.BytesIO(self.png))

    @property
    def electrons(self):
        """Noise-free expected signal per pixel, e-, (H, W) float32 (the EXR's ``electrons`` channel), or None."""
        return None if self.exr is None else self._exr()["electrons"]

    @property
    def irradiance_w_m2(self):
        """Irradiance at the pupil per pixel, W/m^2, (H, W) float32 (the EXR's channel), or None."""
        return None if self.exr is None else self._exr()["irradiance_w_m2"]

    def _exr(self) -> dict:
        return read_exr(io.BytesIO(self.exr))


class Client:
    """A connection to ``skynav serve`` at ``url``; thread-safe (one keep-alive connection per thread).

    Making a client connects to nothing; the first request opens the connection, and a
    connection the server closed while idle is opened again once.

    Parameters
    ----------
    url : str
        ``http://HOST:PORT`` as the server's ready line prints it.
    token : str, optional
        The server's ``--token`` (sent as ``Authorization: Bearer TOKEN``).
    timeout_s : float
        Deadline of one call, s: connecting, sending and the whole answer (a server that drips
        its answer does not extend it).

    Raises
    ------
    ServiceError
        ``url`` is not an ``http://HOST:PORT`` URL.

    Examples
    --------
    >>> from skynav.service import Client
    >>> client = Client("http://127.0.0.1:8765/", timeout_s=30)
    >>> client.url, client.timeout_s
    ('http://127.0.0.1:8765', 30.0)

    With a server running (``skynav serve``, or :class:`LocalServer`), one frame::

        frame = client.render(scene_mapping, outputs=("png", "truth"))
        frame.dn.shape, frame.truth["bodies"][0]["xy"]
    """

    def __init__(self, url: str, token: str | None = None, *, timeout_s: float = 600.0):
        u = urllib.parse.urlsplit(url)
        if u.scheme != "http" or not u.hostname:
            raise ServiceError(f"{url}: expected http://HOST:PORT (the URL skynav serve prints)")
        self.url, self.token, self.timeout_s = url.rstrip("/"), token, float(timeout_s)
        self._host, self._port = u.hostname, u.port or 80
        self._local = threading.local()
        self._heads: dict = {}

    # ------------------------------------------------------------------ transport
    def _conn(self) -> Connection:
        c = getattr(self._local, "conn", None)
        if c is None:
            c = self._local.conn = Connection(self._host, self._port)
        return c

    def _request(self, method: str, path: str, body: bytes | None = None):
        """``(status, headers with lower-case names, body)`` of one request, within ``timeout_s``
        from now; the body a memoryview valid until this thread's next request."""
        deadline = time.monotonic() + self.timeout_s
        conn = self._conn()
        head = self._heads.get((method, path))
        if head is None:
            headers = {"Content-Type": "application/json"} if method == "POST" else {}
            if self.token is not None:
                headers["Authorization"] = f"Bearer {self.token}"
            head = self._heads[(method, path)] = conn.head(method, API_PREFIX + path, headers)
        conn.drop_if_stale()
        for attempt in (0, 1):
            fresh = conn.sock is None
            try:
                return conn.request(head, body, deadline)
            except (Closed, BrokenPipeError, ConnectionResetError) as exc:
                conn.close()
                # a kept-alive connection the server closed while it was idle (uvicorn closes them
                # after 5 s): nothing of an answer came, so the request was not taken; once more
                if attempt or fresh:
                    raise ServiceError(f"{self.url}: the service closed the connection ({exc})") from None
            except TimeoutError:
                conn.close()
                raise ServiceError(f"{self.url}: no complete answer within timeout_s = {self.timeout_s:g} s") from None
            except Malformed as exc:
                conn.close()
                raise ServiceError(f"{self.url}: a malformed answer: {exc}") from None
            except OSError as exc:
                conn.close()
                raise ServiceError(f"{self.url}: cannot reach the service ({exc.strerror or exc})") from None

    @staticmethod
    def _raise_for(status: int, data) -> None:
        data = bytes(data)
        try:
            message = json.loads(data.decode("utf-8"))["error"]
        except Exception:  # noqa: BLE001 - not our JSON: show the start of it
            message = data[:200].decode("utf-8", "replace")
        raise ServiceError(f"service: {message}", status)

    # ------------------------------------------------------------------ API
    def health(self) -> dict:
        """The server's ``GET /v1/health`` answer.

        Returns
        -------
        dict
            The parsed JSON: ``status`` (``"ok"``), ``api``, ``workers``, ``busy``,
            ``waiting``, the ``outputs`` it serves and its ``facility`` (docs/service.md).

        Raises
        ------
        ServiceError
            The server cannot be reached (``status`` 0) or refused the request.
        """
        status, _, data = self._request("GET", "/health")
        if status != 200:
            self._raise_for(status, data)
        try:
            doc = json.loads(bytes(data))
        except ValueError:
            doc = None
        if not isinstance(doc, dict):
            raise ServiceError(f"{self.url}: a malformed answer: the health answer is not a JSON object")
        return doc

    def wait_ready(self, timeout_s: float = 120.0) -> dict:
        """Poll ``/v1/health`` until it answers (a server still warming up does not listen yet).

        Parameters
        ----------
        timeout_s : float
            How long to keep polling (every 0.2 s), s.

        Returns
        -------
        dict
            The first health answer (:meth:`health`).

        Raises
        ------
        ServiceError
            No answer within ``timeout_s``: the last error.
        """
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

        Parameters
        ----------
        scene : dict
            A scene mapping, with the keys and units of a scene file (degrees, ISO epochs in TDB,
            km; docs/conventions.md "Choices made in the code"), plus optional ``seed``.
        outputs : str or sequence of str
            Any of ``png``, ``exr``, ``truth``, ``screen_png`` (the latter when the server has a
            facility).

        Returns
        -------
        RenderResult
            The requested outputs, the server's render time and warnings.

        Raises
        ------
        ServiceError
            A refused request (its one-line message, ``status`` 4xx) or an unreachable server.
        """
        if isinstance(outputs, str):
            outputs = (outputs,)
        outputs = tuple(outputs)
        for o in outputs:
            if o not in OUTPUTS:
                raise ServiceError(f"outputs: unknown output {o!r}; allowed: {', '.join(OUTPUTS)}")
        status, headers, data = self._request("POST", "/render", request_body(scene, outputs))
        if status != 200:
            self._raise_for(status, data)
        ctype = headers.get("content-type", "")
        parts = parse_multipart(data, ctype) if ctype.startswith(MULTIPART) else {outputs[0]: bytes(data)}
        res = RenderResult(png=parts.get("png"), exr=parts.get("exr"), truth_json=parts.get("truth"),
                           screen_png=parts.get("screen_png"))
        res.server_timing = parse_server_timing(headers.get("server-timing", ""))
        res.render_seconds = res.server_timing.get("render", float("nan"))
        w = headers.get("skynav-warnings")
        res.warnings = w.split(" | ") if w else []
        return res

    def close(self) -> None:
        """Close this thread's connection (the next request opens a new one)."""
        c = getattr(self._local, "conn", None)
        if c is not None:
            c.close()
            self._local.conn = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def request_body(scene: dict, outputs: tuple) -> bytes:
    """The JSON body of a render request: the scene mapping and its ``outputs``.

    orjson where it can hold the mapping (plain Python numbers, strings, lists, dicts with string
    keys: the faster writer when the caches are cold, as they are after a frame's render); the standard library otherwise (numpy numbers, other keys), and for
    a mapping with a non-finite number, which it writes as ``NaN``/``Infinity`` for the server to
    refuse by name (orjson would write ``null``).
    """
    doc = {**scene, "outputs": list(outputs)}
    try:
        body = orjson.dumps(doc)
    except TypeError:   # orjson.JSONEncodeError too
        return json.dumps(doc).encode("utf-8")
    if b"null" in body and _non_finite(doc):
        return json.dumps(doc).encode("utf-8")
    return body


def _non_finite(value) -> bool:
    if isinstance(value, float):
        return not math.isfinite(value)
    if isinstance(value, dict):
        return any(_non_finite(v) for v in value.values())
    if isinstance(value, (list, tuple)):
        return any(_non_finite(v) for v in value)
    return False


def parse_multipart(data, content_type: str) -> dict:
    """``{name: bytes}`` of the server's multipart/mixed answer (each part has a Content-Length);
    ``data`` bytes or a memoryview (each part is copied out of it once). An answer that is not
    such a body raises :class:`ServiceError` naming what is wrong."""
    boundary = None
    for param in content_type.split(";")[1:]:
        k, _, v = param.strip().partition("=")
        if k.lower() == "boundary":
            boundary = v.strip('"')
    if not boundary:
        raise ServiceError("service: a malformed answer: a multipart answer without a boundary")
    delim = f"--{boundary}".encode("latin-1")
    data = memoryview(data)
    parts, pos = {}, 0
    while True:
        if data[pos:pos + len(delim)] != delim:
            raise ServiceError(f"service: a malformed answer: no multipart delimiter at byte {pos}")
        pos += len(delim)
        if data[pos:pos + 2] == b"--":
            return parts
        pos += 2  # CRLF
        name, n, start = _part_head(bytes(data[pos:pos + 4096]), pos)   # a part's header lines (~120 bytes)
        if start + n + 2 > len(data):
            raise ServiceError(f"service: a malformed answer: multipart part {name!r} of {n} bytes runs past the "
                               f"end of the answer ({len(data)} bytes)")
        parts[name] = bytes(data[start:start + n])
        pos = start + n + 2


def _part_head(head: bytes, pos: int) -> tuple:
    """``(name, byte count, where its bytes start)`` of the multipart part whose header starts
    ``head``, at byte ``pos`` of the answer; :class:`ServiceError` naming what is missing."""
    end = head.find(b"\r\n\r\n")
    if end < 0:
        raise ServiceError(f"service: a malformed answer: a multipart part at byte {pos} has no end of header")
    hdrs = {}
    for line in head[:end].decode("latin-1").split("\r\n"):
        k, _, v = line.partition(":")
        hdrs[k.strip().lower()] = v.strip()
    _, found, rest = hdrs.get("content-disposition", "").partition('name="')
    if not found or '"' not in rest:
        raise ServiceError(f"service: a malformed answer: the multipart part at byte {pos} has no "
                           "Content-Disposition with a name")
    name = rest.split('"', 1)[0]
    n = byte_count(hdrs.get("content-length", ""))
    if n is None:
        raise ServiceError(f"service: a malformed answer: multipart part {name!r}: Content-Length "
                           f"{hdrs.get('content-length', '')[:40]!r} is not a byte count")
    return name, n, pos + end + 4


class LocalServer:
    """``skynav serve --port 0`` as a child process, for a program that wants its own server.

    Used as a context manager: entering starts the server and returns its URL once it is ready;
    leaving stops it (SIGTERM, then a kill after 120 s).

    Parameters
    ----------
    *args : str
        More command-line arguments of ``skynav serve`` (e.g. ``"--facility", "bench.yaml"``).
    workers : int
        Number of worker processes (``--workers``).
    timeout_s : float
        How long to wait for the server's ready line, s.

    Raises
    ------
    ServiceError
        On entering, when the server did not print its ready line in time (its error is printed).

    Examples
    --------
    Nothing starts until the ``with`` block:

    >>> from skynav.service import LocalServer
    >>> server = LocalServer("--token", "secret", workers=2)
    >>> server.args, server.workers, server.url
    (('--token', 'secret'), 2, None)

    A server and one frame (starting it takes seconds: the workers load the catalogue and the
    kernels)::

        with LocalServer(workers=1) as url:
            frame = Client(url).render(scene_mapping)
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
