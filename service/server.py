"""``skynav serve``: the HTTP server (Starlette on uvicorn) in front of warm render workers.

The server process checks a request's envelope (token, media type, size, JSON object, outputs)
and hands it to an idle worker process (:mod:`skynav.service.worker`), which validates the scene
once, with the scene-file validator (:func:`skynav.scenes.config.scene_spec_from_mapping`, so
errors use the scene-file words: a ``bad`` answer becomes the 400's line), and renders it; the
server renders nothing itself and writes no file. A 200 answer the worker writes to the client's
socket itself, which the server hands it with the request (:class:`_Direct`). ``POST
/v1/render`` is a plain ASGI endpoint (:class:`RenderEndpoint`) in front of the Starlette
application that serves the rest. Concurrency is bounded: ``workers`` frames render at once,
``max_queue`` more wait, the next gets 503. Every error is a 4xx/5xx with a one-line JSON body ``{"error": "..."}``.
"""

from __future__ import annotations

import array
import asyncio
import contextlib
import hmac
import ipaddress
import json
import multiprocessing
import os
import pickle
import socket
import struct
import sys
import time
import traceback
from concurrent.futures import ThreadPoolExecutor
from contextlib import asynccontextmanager
from dataclasses import dataclass

import uvicorn
from starlette.applications import Starlette
from starlette.exceptions import HTTPException
from starlette.responses import JSONResponse
from starlette.routing import Route

try:  # uvicorn's httptools protocol (httptools is a dependency), for the direct answer (_http_protocol)
    from uvicorn.protocols.http.httptools_impl import HttpToolsProtocol
except ImportError:
    HttpToolsProtocol = None

from skynav.infra.pool import WorkerThreads

from .openapi import openapi_document
from .protocol import (
    API_PREFIX,
    AUTH_HEADER,
    MAX_CAMERA_PIXELS,
    MAX_QUEUE,
    MAX_REQUEST_BYTES,
    OUTPUTS,
    SCENE_KEYS,
    answer_headers,
    read_json,
)
from .worker import frame_head, worker_main

RENDER_PATH = f"{API_PREFIX}/render"


class ServiceStartError(Exception):
    """The server could not start (a worker failed to warm up, a bad facility); one line."""


@dataclass
class Limits:
    max_request_bytes: int = MAX_REQUEST_BYTES
    max_camera_pixels: int = MAX_CAMERA_PIXELS
    max_queue: int = MAX_QUEUE


class _Answers(asyncio.BufferedProtocol):
    """The server's end of a worker's pipe: its answers, read straight into their buffers.

    The worker frames each message as :class:`multiprocessing.connection.Connection` does (a
    4-byte big-endian signed length, -1 then an 8-byte length from 2 GiB, then the bytes). An
    answer is one pickled message ``(kind, one line)``, or for ``ok`` and ``sent`` two in one
    write (:class:`skynav.service.worker._Pipe`): the pickled ``("ok", content type, warnings,
    seconds)`` and the body's raw bytes, or ``("sent", ok)`` and what the client's socket did not
    take of the answer the worker wrote to it (:class:`_Direct`; nothing, unless the answer is
    larger than the socket's send buffer or the client reads slowly). The event loop reads into
    the buffer :meth:`get_buffer` hands it, sized to what comes next (the length, the pickle, the
    body), so a body lands in a buffer of its own size at once: no stream buffer in between, no
    copy, no Python for each chunk.
    """

    def __init__(self):
        self.lost = False
        self._pending = None   # (future, done) of the request in the worker
        self._head = None      # the ("ok", ...) of the answer whose body is being read
        self._length = bytearray(8)
        self._read_length()

    def expect(self, done) -> asyncio.Future:
        """The future of the next answer (a request is about to be written); ``done(died)`` is
        called once that answer has been read, or the pipe lost, whatever became of the future
        (its request may have been cancelled: its client went away)."""
        future = asyncio.get_running_loop().create_future()
        self._pending = (future, done)
        return future

    def _next(self, what: str, buf) -> None:
        self._what, self._buf, self._view, self._got = what, buf, memoryview(buf), 0

    def _read_length(self) -> None:
        self._next("length", memoryview(self._length)[:4])

    def get_buffer(self, sizehint):
        return self._view[self._got:]

    def buffer_updated(self, nbytes) -> None:
        self._got += nbytes
        while self._got == len(self._view):     # this item is complete: on to the next
            if self._what == "length":
                (size,) = struct.unpack_from("!i", self._length)
                if size == -1:
                    self._next("long length", memoryview(self._length))
                    continue
                self._payload(size)
            elif self._what == "long length":
                self._payload(struct.unpack_from("!Q", self._length)[0])
            elif self._what == "message":
                answer = pickle.loads(self._buf)
                self._read_length()
                if answer[0] in ("ok", "sent"):
                    self._head = answer
                else:
                    self._deliver(answer)
            else:   # the body of an ok answer
                answer, self._head = (*self._head, self._buf), None
                self._read_length()
                self._deliver(answer)

    def _payload(self, size: int) -> None:
        self._next("message" if self._head is None else "body", bytearray(size))

    def _deliver(self, answer) -> None:
        if self._pending is None:
            return
        (future, done), self._pending = self._pending, None
        done(False)
        if not future.done():
            future.set_result(answer)

    def connection_lost(self, exc) -> None:
        self.lost = True
        if self._pending is None:
            return
        (future, done), self._pending = self._pending, None
        done(True)
        if not future.done():
            future.set_exception(EOFError("the render worker is gone"))


class _Worker:
    def __init__(self, ctx, facility, threads):
        self.conn, child = ctx.Pipe()
        # the serial of the last answer the worker began to write to a client itself (shared memory:
        # read when the worker died, to know whether part of that answer may be with the client)
        self.writing = ctx.RawValue("q", 0)
        self.serial = 0
        self.process = ctx.Process(target=worker_main, args=(child, facility, threads, self.writing), daemon=True)
        # the spawned worker reads its thread budget from the environment it starts with: Dr.Jit
        # and OpenEXR (SKYNAV_THREADS) and OpenBLAS/OpenMP/MKL alike, so that N workers on N cores
        # do not each start a pool as wide as the machine
        with WorkerThreads(1, threads=threads):
            self.process.start()
        child.close()
        self.transport = self.answers = None

    def wait_ready(self, timeout_s: float) -> dict:
        if not self.conn.poll(timeout_s):
            raise ServiceStartError(f"a render worker did not warm up within {timeout_s:.0f} s")
        try:
            kind, info = self.conn.recv()
        except (EOFError, OSError):
            raise ServiceStartError(f"a render worker died while warming up (exit code {self.process.exitcode})") from None
        if kind != "ready":
            raise ServiceStartError(info)
        return info

    async def attach(self) -> None:
        """Open this worker's pipe in the running event loop (after :meth:`wait_ready`).

        The server then talks to the worker without a thread, in the loop that also serves HTTP:
        the request is written to the pipe's transport, the answer read by :class:`_Answers`
        straight into its buffers as its bytes come. The worker side keeps its
        :class:`multiprocessing.connection.Connection`, whose framing both speak.
        """
        sock = socket.socket(fileno=os.dup(self.conn.fileno()))
        loop = asyncio.get_running_loop()
        self.transport, self.answers = await loop.create_unix_connection(_Answers, sock=sock)
        self.sock = socket.socket(fileno=os.dup(self.conn.fileno()))   # for the requests that carry a socket
        self.sock.setblocking(False)

    def request(self, body, outputs, max_pixels, done, direct=None) -> tuple:
        """Send one request (``body``: its JSON, which the worker reads again for the scene);
        ``(future of the worker's answer, serial)`` (the future's exception EOFError when the
        worker died).

        ``direct``: the :class:`_Direct` of the request's connection, or None. With it the
        client's socket goes along (``SCM_RIGHTS``), and the worker writes a 200 answer to the
        client itself; its answer here is then ``("sent", ok, the bytes the socket did not
        take)``, and ``serial`` the number the worker puts in :attr:`writing` before it writes.
        ``done(died)`` is called once the answer has been read or the worker is gone (at once,
        with True, when it was gone already). An ``ok`` answer is ``("ok", content type,
        warnings, seconds, body)``, the body the raw bytes of the HTTP answer's body (a
        :class:`bytearray`, read into once and handed to the response as it is); the others are
        ``(kind, one line)``.
        """
        if self.transport is None or self.transport.is_closing() or self.answers.lost:
            done(True)
            raise EOFError("the render worker is gone")
        fd = head = None
        if direct is not None and self.transport.get_write_buffer_size() == 0:
            fd = direct.fileno()
            if fd is not None:
                self.serial += 1
                head = (*direct.head_info(), self.serial)
        data = pickle.dumps((bytes(body), outputs, max_pixels, head), protocol=pickle.HIGHEST_PROTOCOL)
        data = frame_head(len(data)) + data
        future = self.answers.expect(done)
        sent = 0
        if fd is not None:   # the pipe is empty (one request at a time): this small write goes whole
            with contextlib.suppress(BlockingIOError, InterruptedError):
                sent = self.sock.sendmsg([data], [(socket.SOL_SOCKET, socket.SCM_RIGHTS, array.array("i", [fd]))])
        if sent < len(data):   # without the socket (when none of it went), the worker answers here
            self.transport.write(data[sent:])
        return future, (self.serial if sent else None)

    def detach(self) -> None:
        if self.transport is not None:
            self.transport.close()
            self.sock.close()
            self.transport = self.answers = self.sock = None

    def stop(self, timeout_s: float = 30.0) -> None:
        try:
            self.conn.send(None)
        except (OSError, ValueError):
            pass
        self.process.join(timeout_s)
        if self.process.is_alive():
            self.process.terminate()
            self.process.join(5)


class WorkerPool:
    """``n`` warm render processes; :meth:`render` waits for an idle one."""

    def __init__(self, n: int, *, facility=None, threads=None, limits: Limits = Limits()):
        self.n, self.facility_arg, self.limits = n, facility, limits
        self.threads = threads or max(1, (os.cpu_count() or 1) // max(1, n))   # per worker
        self._ctx = multiprocessing.get_context("spawn")
        self.workers: list[_Worker] = []
        self.info: dict = {}
        self.busy = 0
        self.waiting = 0
        self._idle: asyncio.Queue | None = None
        self._replacing: set = set()
        self._executor = ThreadPoolExecutor(max_workers=max(1, n), thread_name_prefix="skynav-render")

    def start(self, timeout_s: float = 600.0) -> float:
        t0 = time.perf_counter()
        try:
            self.workers = [_Worker(self._ctx, self.facility_arg, self.threads) for _ in range(self.n)]
            infos = [w.wait_ready(timeout_s) for w in self.workers]
        except BaseException:
            self.stop()
            raise
        self.info = infos[0]
        return time.perf_counter() - t0

    async def attach(self) -> None:
        """Make the idle queue and the workers' streams in the running event loop (the app's startup)."""
        self._idle = asyncio.Queue()
        for w in self.workers:
            await w.attach()
            self._idle.put_nowait(w)

    def detach(self) -> None:
        """Close the workers' streams (the app's shutdown, once the last request has its answer)."""
        for w in self.workers:
            w.detach()

    async def render(self, body: bytes, outputs: tuple, direct=None):
        """The worker's answer to one request (:meth:`_Worker.request`): ``body`` the request's
        JSON (whose envelope :func:`parse_request` has checked); ``direct``: the request's
        :class:`_Direct`, or None (the answer comes back here)."""
        if self.busy >= self.n and self.waiting >= self.limits.max_queue:
            raise _HTTPError(503, f"the server is busy ({self.busy} frames rendering, {self.waiting} waiting; "
                                  f"the queue holds {self.limits.max_queue}); try again")
        self.waiting += 1
        try:
            worker = await self._idle.get()
        finally:
            self.waiting -= 1
        self.busy += 1
        # the worker goes back to the idle queue when its answer has been read (_Answers calls
        # done), even if this request is cancelled before (its client went away): the next
        # request never reads this one's frame
        serial = None
        try:
            future, serial = worker.request(body, outputs, self.limits.max_camera_pixels,
                                            lambda died: self._answered(worker, died),
                                            direct if direct is not None and direct.usable() else None)
            return await future
        except EOFError:
            if serial is not None and worker.writing.value == serial:
                raise _AnswerCut from None
            raise _HTTPError(503, "the render worker died while rendering this frame (out of memory?); "
                                  "ask for a smaller camera or try again") from None

    def _answered(self, worker: _Worker, died: bool) -> None:
        self.busy -= 1
        if not died:
            self._idle.put_nowait(worker)
            return
        # the process died (killed, out of memory): its request gets a 503 now, a fresh worker
        # takes its place when warm (the requests that come meanwhile wait for it)
        task = asyncio.ensure_future(self._replace(worker))
        self._replacing.add(task)
        task.add_done_callback(self._replacing.discard)

    async def _replace(self, dead: _Worker) -> None:
        dead.detach()
        dead.stop(1)
        try:
            worker = await asyncio.get_running_loop().run_in_executor(self._executor, self._respawn)
            await worker.attach()
        except Exception as exc:  # noqa: BLE001 - logged; the next request tries again
            print(f"skynav serve: a render worker could not be replaced: {' '.join(str(exc).split())}", file=sys.stderr)
            self._idle.put_nowait(dead)
            return
        self.workers[self.workers.index(dead)] = worker
        self._idle.put_nowait(worker)

    def _respawn(self) -> _Worker:
        w = _Worker(self._ctx, self.facility_arg, self.threads)
        w.wait_ready(600)
        return w

    def stop(self) -> None:
        for w in self.workers:
            w.stop()
        self._executor.shutdown(wait=False)


class _AnswerCut(Exception):
    """The worker died while it wrote an answer to the client: part of it may be there."""


class _HTTPError(Exception):
    def __init__(self, status: int, message: str):
        super().__init__(message)
        self.status, self.message = status, " ".join(str(message).split())


def _error(status: int, message: str):
    return JSONResponse({"error": " ".join(str(message).split())}, status_code=status)


def parse_request(body: bytes, *, has_facility: bool, limits: Limits) -> tuple:
    """Check a request body's envelope (a JSON object; its outputs): the outputs asked for;
    raises :class:`_HTTPError` (400) with one line.

    The scene itself is validated by the worker (the same validator as scene files; doing it here
    as well cost ~1 ms of the ~9 ms a request then added to a frame), which reads it from the same
    bytes with the same reader (:func:`skynav.service.protocol.read_json`)."""
    try:
        doc = read_json(body)
    except (UnicodeDecodeError, ValueError, RecursionError) as exc:
        raise _HTTPError(400, f"request body: not a JSON object ({str(exc).splitlines()[0][:120]})") from None
    if not isinstance(doc, dict):
        raise _HTTPError(400, "request body: expected a JSON object with the keys of a scene file ("
                              + ", ".join(SCENE_KEYS) + ") and outputs")
    outputs = doc.get("outputs", ["png", "truth"])
    allowed = [o for o in OUTPUTS if o != "screen_png" or has_facility]
    if isinstance(outputs, str):
        outputs = [outputs]
    if (not isinstance(outputs, list) or not outputs or not all(isinstance(o, str) for o in outputs)
            or len(set(outputs)) != len(outputs)):
        raise _HTTPError(400, f"outputs = {_short(outputs)}: expected a list of distinct names from: {', '.join(allowed)}")
    for o in outputs:
        if o not in allowed:
            why = " (this server has no facility: start it with --facility)" if o == "screen_png" else ""
            raise _HTTPError(400, f"outputs: unknown output {_short(o)}; allowed: {', '.join(allowed)}{why}")
    return tuple(outputs)


def _short(value) -> str:
    text = json.dumps(value) if not isinstance(value, str) else repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _error_body(message) -> bytes:
    """The one-line JSON error, the bytes Starlette's JSONResponse makes of ``{"error": message}``."""
    return json.dumps({"error": " ".join(str(message).split())}, ensure_ascii=False, allow_nan=False,
                      separators=(",", ":")).encode("utf-8")


class _ClientGone(Exception):
    """The client hung up before its request body was read."""


class RenderEndpoint:
    """``POST /v1/render`` as a plain ASGI application.

    :func:`build_app` puts it in front of the Starlette application (every other path and method,
    and the lifespan, go to Starlette; it is also Starlette's route for the path, so that another
    method gets Starlette's 405): a request is read from the ASGI messages, handed to the pool,
    and its answer's body (the worker's buffer) sent as it is, without Starlette's middleware,
    routing, Request and Response objects on the path of every frame (~0.1 ms of the server's
    CPU per frame). The checks and the errors are the ones a Starlette endpoint would make.
    """

    def __init__(self, pool: WorkerPool, *, token: str | None, limits: Limits, has_facility: bool):
        self.pool, self.limits, self.has_facility = pool, limits, has_facility
        self.token = None if token is None else token.encode()

    async def __call__(self, scope, receive, send) -> None:
        try:
            status, headers, body = await self._answer(scope, receive)
            if status == 0:   # the worker wrote the answer to the client: body is what the socket did not take
                scope["extensions"]["skynav.direct"].finish(headers, body)
                return
        except _AnswerCut:   # the client has a part of an answer: only closing the connection tells it
            scope["extensions"]["skynav.direct"].finish(False, b"")
            return
        except _ClientGone:
            status, headers, body = 400, [], b""   # no one reads it (uvicorn drops it)
        except Exception as exc:  # noqa: BLE001 - a bug: logged here, one line to the client
            print(f"skynav serve: internal error on POST {scope['path']}: {exc.__class__.__name__}: {exc}",
                  file=sys.stderr)
            traceback.print_exc(file=sys.stderr)
            status, headers, body = 500, [], _error_body("internal error; see the server's log")
        if not headers:
            headers = [(b"content-type", b"application/json")]
        headers.append((b"content-length", b"%d" % len(body)))
        await send({"type": "http.response.start", "status": status, "headers": headers})
        await send({"type": "http.response.body", "body": body})

    async def _answer(self, scope, receive):
        """``(status, headers, body)`` of one request."""
        auth = ctype = declared = None
        for name, value in scope["headers"]:   # the first of each, as Starlette's headers.get
            if name == b"authorization":
                auth = value if auth is None else auth
            elif name == b"content-type":
                ctype = value if ctype is None else ctype
            elif name == b"content-length":
                declared = value if declared is None else declared
        try:
            if self.token is not None:
                scheme, _, value = (auth or b"").decode("latin-1").partition(" ")
                if not (scheme.lower() == "bearer"
                        and hmac.compare_digest(value.strip().encode("latin-1"), self.token)):
                    raise _HTTPError(401, "Authorization: expected 'Bearer TOKEN' with the server's --token")
            kind = (ctype or b"application/json").decode("latin-1").split(";")[0].strip().lower()
            if kind not in ("application/json", "application/x-www-form-urlencoded", ""):
                raise _HTTPError(415, f"Content-Type {kind!r}: send the scene mapping as application/json")
            body = await self._body(receive, declared)
            outputs = parse_request(body, has_facility=self.has_facility, limits=self.limits)
            extensions = scope.get("extensions")
            answer = await self.pool.render(body, outputs, extensions and extensions.get("skynav.direct"))
        except _HTTPError as exc:
            return exc.status, [], _error_body(exc.message)
        if answer[0] == "sent":
            return 0, answer[1], answer[2]
        if answer[0] != "ok":
            return (400 if answer[0] == "bad" else 500), [], _error_body(answer[1])
        _, ctype, lines, seconds, body = answer
        return 200, answer_headers(ctype, seconds, lines), body

    async def _body(self, receive, declared) -> bytes:
        bound = self.limits.max_request_bytes
        if declared is not None:
            try:
                n = int(declared)
            except ValueError:
                raise _HTTPError(400, f"Content-Length {declared.decode('latin-1')!r}: not a number") from None
            if n > bound:
                raise _HTTPError(413, f"request body: {n} bytes; at most {bound} (--max-request-bytes)")
        chunks, size = [], 0
        while True:
            message = await receive()
            if message["type"] != "http.request":   # http.disconnect
                raise _ClientGone
            chunk = message.get("body", b"")
            size += len(chunk)
            if size > bound:
                raise _HTTPError(413, f"request body: more than {bound} bytes (--max-request-bytes)")
            chunks.append(chunk)
            if not message.get("more_body", False):
                return chunks[0] if len(chunks) == 1 else b"".join(chunks)


def build_app(pool: WorkerPool, *, token: str | None = None, limits: Limits = Limits()):
    """The ASGI application of protocol v1 around a started :class:`WorkerPool`: Starlette's, with
    ``POST /v1/render`` taken by a :class:`RenderEndpoint` in front of it."""
    has_facility = pool.info.get("facility") is not None
    document = openapi_document()
    render = RenderEndpoint(pool, token=token, limits=limits, has_facility=has_facility)

    async def health(request):
        return JSONResponse({"status": "ok", "api": "v1", "workers": pool.n, "busy": pool.busy, "waiting": pool.waiting,
                             "outputs": [o for o in OUTPUTS if o != "screen_png" or has_facility],
                             "facility": pool.info.get("facility")})

    async def openapi(request):
        return JSONResponse(document)

    async def http_error(request, exc):
        return _error(exc.status_code, f"{request.method} {request.url.path}: {exc.detail}")

    async def internal_error(request, exc):
        print(f"skynav serve: internal error on {request.method} {request.url.path}: {exc.__class__.__name__}: {exc}",
              file=sys.stderr)
        return _error(500, "internal error; see the server's log")

    routes = [Route(f"{API_PREFIX}/health", health, methods=["GET"]),
              Route(f"{API_PREFIX}/openapi.json", openapi, methods=["GET"]),
              Route(RENDER_PATH, render, methods=["POST"])]

    @asynccontextmanager
    async def lifespan(app):
        await pool.attach()
        yield
        pool.detach()

    app = Starlette(routes=routes, lifespan=lifespan,
                    exception_handlers={HTTPException: http_error, Exception: internal_error})

    async def front(scope, receive, send):
        if scope["type"] == "http" and scope["method"] == "POST" and scope["path"] == RENDER_PATH:
            await render(scope, receive, send)
        else:
            await app(scope, receive, send)

    return front


class _Direct:
    """What a ``POST /v1/render`` scope carries as its extension ``skynav.direct``
    (:func:`_http_protocol`): the request's uvicorn request-response cycle and transport.

    With it a 200 answer takes one hand-over less: the client's socket goes to the worker with
    the request, the worker writes the answer's head and body to it (``skynav.service.worker``,
    the head the bytes uvicorn writes: :func:`skynav.service.protocol.answer_head`), then tells
    the server, and :meth:`finish` ends the cycle as uvicorn's ``send`` does after a body, without
    writing. The client has its frame while the server reads the worker's word, instead of after
    the server has read the frame from the worker and written it out again. Only when the
    connection is idle (nothing of an earlier answer left in uvicorn's write buffer); errors and
    every other path go through uvicorn as before.
    """

    __slots__ = ("cycle", "transport")

    def __init__(self, cycle, transport):
        self.cycle, self.transport = cycle, transport

    def usable(self) -> bool:
        """Whether the worker may write this answer. False too where uvicorn's cycle lacks what
        :meth:`head_info` and :meth:`finish` use (another uvicorn than the tested ones): the
        answer then goes through uvicorn, a hand-over slower, never wrong."""
        cycle, transport = self.cycle, self.transport
        try:
            ready = not (cycle.disconnected or cycle.response_started or cycle.response_complete)
            known = cycle.default_headers is not None and cycle.keep_alive in (True, False) \
                and callable(cycle.on_response) and callable(cycle.message_event.set)
        except AttributeError:
            return False
        return ready and known and not transport.is_closing() and transport.get_write_buffer_size() == 0

    def fileno(self) -> int | None:
        sock = self.transport.get_extra_info("socket")
        return None if sock is None else sock.fileno()

    def head_info(self) -> tuple:
        """``(uvicorn's default header lines, keep-alive)``: what the worker needs for the head."""
        cycle = self.cycle
        return b"".join(b"%s: %s\r\n" % h for h in cycle.default_headers), cycle.keep_alive

    def finish(self, ok: bool, rest) -> None:
        """The worker wrote the answer (``ok``; ``rest``: what the socket did not take, written
        here), or the client is gone or has part of an answer (not ``ok``: the connection closes)."""
        cycle, transport = self.cycle, self.transport
        cycle.response_started = True
        if not ok:
            transport.close()
        elif rest and not transport.is_closing():
            transport.write(rest)
        cycle.response_complete = True
        cycle.message_event.set()
        if not cycle.keep_alive:
            transport.close()
        cycle.on_response()


def _http_protocol():
    """uvicorn's httptools protocol with the ``skynav.direct`` extension in the scope of ``POST
    /v1/render``; None where httptools is missing (uvicorn's own choice then)."""
    if HttpToolsProtocol is None:
        return None

    class _Protocol(HttpToolsProtocol):
        def on_headers_complete(self) -> None:
            super().on_headers_complete()
            scope = self.scope
            if scope.get("path") == RENDER_PATH and scope.get("method") == "POST" and self.cycle is not None \
                    and self.cycle.scope is scope:
                scope["extensions"] = {"skynav.direct": _Direct(self.cycle, self.transport)}

    return _Protocol


def is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def _server_class():
    class _Server(uvicorn.Server):
        """uvicorn's server, without re-raising SIGINT/SIGTERM after its graceful shutdown: the
        caller still has to stop the worker processes, then returns normally."""

        @contextlib.contextmanager
        def capture_signals(self):
            with super().capture_signals():
                yield
                captured = getattr(self, "_captured_signals", None)
                if captured:
                    self.stopped_by = list(captured)
                    captured.clear()

    return _Server


def _run(coro, config) -> None:
    """Run ``coro`` on the event loop uvicorn's ``--loop`` setting picks (``auto``: uvloop where
    installed, else asyncio's)."""
    factory = config.get_loop_factory() if hasattr(config, "get_loop_factory") else None
    if factory is None or sys.version_info < (3, 11):   # asyncio.Runner is 3.11's
        if hasattr(config, "setup_event_loop"):   # uvicorn < 0.36: sets the policy
            config.setup_event_loop()
        asyncio.run(coro)
        return
    with asyncio.Runner(loop_factory=factory) as runner:
        runner.run(coro)


def serve(*, host: str = "127.0.0.1", port: int = 8765, workers: int = 1, facility=None, token: str | None = None,
          limits: Limits = Limits(), threads=None, ready=print) -> None:
    """Bind, warm the workers, print the ready line through ``ready``, serve until SIGINT/SIGTERM.

    On a signal uvicorn stops accepting, lets the running renders finish and answer, then the
    workers are stopped.
    """
    _Server = _server_class()
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    sock = socket.socket(family, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        sock.bind((host, port))
    except OSError as exc:
        sock.close()
        raise ServiceStartError(f"--host {host} --port {port}: cannot listen there ({exc.strerror or exc})") from None
    if family in (socket.AF_INET, socket.AF_INET6):   # small answers on kept-alive connections: no Nagle wait
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    sock.listen(128)
    bound_port = sock.getsockname()[1]
    pool = WorkerPool(workers, facility=facility, threads=threads, limits=limits)
    try:
        warm_s = pool.start()
    except BaseException:
        sock.close()
        raise
    try:
        app = build_app(pool, token=token, limits=limits)
        # http and loop "auto": httptools' parser and uvloop where installed (they are dependencies),
        # h11 and asyncio's loop otherwise; together they take ~0.3 ms of the server's CPU per frame
        # proxy_headers off: the server is not behind a proxy (a client's X-Forwarded-For means
        # nothing here), and uvicorn's middleware for it is one more layer on every request
        # http: httptools' protocol with the skynav.direct extension (_http_protocol)
        config = uvicorn.Config(app, http=_http_protocol() or "auto", log_level="warning", access_log=False,
                                lifespan="on", proxy_headers=False, timeout_graceful_shutdown=600,
                                limit_concurrency=limits.max_queue * 4 + workers + 64)
        server = _Server(config)

        async def main():
            task = asyncio.ensure_future(server.serve(sockets=[sock]))
            while not server.started and not task.done():
                await asyncio.sleep(0.01)
            if server.started:
                shown = f"[{host}]" if family == socket.AF_INET6 else host
                ready(f"skynav serve: ready at http://{shown}:{bound_port} ({workers} worker{'s' if workers != 1 else ''}"
                      f"{', facility ' + str(pool.info['facility']) if pool.info.get('facility') else ''}; "
                      f"warm in {warm_s:.1f} s)")
            await task

        _run(main(), config)
    finally:
        pool.stop()
        sock.close()
