"""``skynav serve``: the HTTP server (Starlette on uvicorn) in front of warm render workers.

The server process parses and validates requests (the scene-file validator,
:func:`skynav.scenes.config.scene_spec_from_mapping`, so errors use the scene-file words) and hands
each valid one to an idle worker process (:mod:`skynav.service.worker`); it renders nothing itself
and writes no file. Concurrency is bounded: ``workers`` frames render at once, ``max_queue`` more
wait, the next gets 503. Every error is a 4xx/5xx with a one-line JSON body ``{"error": "..."}``.
"""

from __future__ import annotations

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
from concurrent.futures import ThreadPoolExecutor
from contextlib import asynccontextmanager
from dataclasses import dataclass

import uvicorn
from starlette.applications import Starlette
from starlette.exceptions import HTTPException
from starlette.requests import ClientDisconnect
from starlette.responses import JSONResponse, Response
from starlette.routing import Route

from skynav.datasets.pool import WorkerThreads

from .openapi import openapi_document
from .protocol import (
    API_PREFIX,
    AUTH_HEADER,
    MAX_CAMERA_PIXELS,
    MAX_QUEUE,
    MAX_REQUEST_BYTES,
    OUTPUTS,
    SCENE_KEYS,
)
from .worker import frame_head, worker_main


#: Read buffer of a worker's stream: above a frame's answer, so that its bytes are read in one go
#: rather than with the transport paused and resumed (asyncio's default is 64 KiB).
_STREAM_LIMIT = 16 * 1024 * 1024


class ServiceStartError(Exception):
    """The server could not start (a worker failed to warm up, a bad facility); one line."""


@dataclass
class Limits:
    max_request_bytes: int = MAX_REQUEST_BYTES
    max_camera_pixels: int = MAX_CAMERA_PIXELS
    max_queue: int = MAX_QUEUE


class _Worker:
    def __init__(self, ctx, facility, threads):
        self.conn, child = ctx.Pipe()
        self.process = ctx.Process(target=worker_main, args=(child, facility, threads), daemon=True)
        # the spawned worker reads its thread budget from the environment it starts with: Dr.Jit
        # and OpenEXR (SKYNAV_THREADS) and OpenBLAS/OpenMP/MKL alike, so that N workers on N cores
        # do not each start a pool as wide as the machine
        with WorkerThreads(1, threads=threads):
            self.process.start()
        child.close()
        self.reader = self.writer = None

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
        """Open this worker's pipe as a stream of the running event loop (after :meth:`wait_ready`).

        The server then talks to the worker without a thread: the request is written, the answer
        read as its bytes come, in the loop that also serves HTTP. The worker side keeps its
        :class:`multiprocessing.connection.Connection`, whose framing (a 4-byte big-endian signed
        length, -1 then an 8-byte length past 2 GiB, then the pickle) :meth:`call` speaks.
        """
        sock = socket.socket(fileno=os.dup(self.conn.fileno()))
        self.reader, self.writer = await asyncio.open_unix_connection(sock=sock, limit=_STREAM_LIMIT)

    async def call(self, msg):
        """Send one request, return the worker's answer; EOFError/OSError when the worker died.

        An ``ok`` answer is two messages in one write (:class:`skynav.service.worker._AnswerPipe`),
        ``("ok", content type, warnings, seconds)`` and the body's raw bytes (not pickled: read
        once, handed to the response as they are); the answer returned is ``("ok", content type,
        warnings, seconds, body)``.
        """
        if self.writer is None:   # died before, and its replacement could not start: try again
            raise EOFError("the render worker is gone")
        data = pickle.dumps(msg, protocol=pickle.HIGHEST_PROTOCOL)
        self.writer.write(frame_head(len(data)) + data)
        await self.writer.drain()
        answer = pickle.loads(await self._message())
        if answer[0] == "ok":
            answer = (*answer, await self._message())
        return answer

    async def _message(self) -> bytes:
        (size,) = struct.unpack("!i", await self.reader.readexactly(4))
        if size == -1:
            (size,) = struct.unpack("!Q", await self.reader.readexactly(8))
        return await self.reader.readexactly(size)

    def detach(self) -> None:
        if self.writer is not None:
            self.writer.close()
            self.reader = self.writer = None

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
        self._exchanges: set = set()
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

    async def render(self, mapping: dict, outputs: tuple):
        if self.busy >= self.n and self.waiting >= self.limits.max_queue:
            raise _HTTPError(503, f"the server is busy ({self.busy} frames rendering, {self.waiting} waiting; "
                                  f"the queue holds {self.limits.max_queue}); try again")
        self.waiting += 1
        try:
            worker = await self._idle.get()
        finally:
            self.waiting -= 1
        self.busy += 1
        # the exchange with the worker runs to its end even if this request is cancelled (its
        # client went away): the worker goes back to the idle queue only once its answer has been
        # read, so that the next request never reads this one's frame
        task = asyncio.ensure_future(self._exchange(worker, (mapping, outputs, self.limits.max_camera_pixels)))
        self._exchanges.add(task)
        task.add_done_callback(self._exchange_done)
        return await asyncio.shield(task)

    def _exchange_done(self, task) -> None:
        self._exchanges.discard(task)
        if not task.cancelled():
            task.exception()   # retrieved: a cancelled request's error has no one to go to

    async def _exchange(self, worker: _Worker, msg):
        try:
            try:
                return await worker.call(msg)
            except (EOFError, OSError):
                # the process died (killed, out of memory): replace it, tell this client
                worker.detach()
                worker.stop(1)
                dead = worker
                worker = await asyncio.get_running_loop().run_in_executor(self._executor, self._respawn)
                await worker.attach()
                self.workers[self.workers.index(dead)] = worker
                raise _HTTPError(503, "the render worker died while rendering this frame (out of memory?); "
                                      "ask for a smaller camera or try again") from None
        finally:
            self.busy -= 1
            self._idle.put_nowait(worker)

    def _respawn(self) -> _Worker:
        w = _Worker(self._ctx, self.facility_arg, self.threads)
        w.wait_ready(600)
        return w

    def stop(self) -> None:
        for w in self.workers:
            w.stop()
        self._executor.shutdown(wait=False)


class _HTTPError(Exception):
    def __init__(self, status: int, message: str):
        super().__init__(message)
        self.status, self.message = status, " ".join(str(message).split())


def _error(status: int, message: str):
    return JSONResponse({"error": " ".join(str(message).split())}, status_code=status)


def parse_request(body: bytes, *, has_facility: bool, limits: Limits) -> tuple[dict, tuple]:
    """Parse a request body: ``(scene mapping, outputs)``; raises :class:`_HTTPError` (400) with one line."""
    def no_constant(name):
        raise ValueError(f"{name} is not a JSON number")

    try:
        doc = json.loads(body.decode("utf-8"), parse_constant=no_constant)
    except (UnicodeDecodeError, ValueError, RecursionError) as exc:
        raise _HTTPError(400, f"request body: not a JSON object ({str(exc).splitlines()[0][:120]})") from None
    if not isinstance(doc, dict):
        raise _HTTPError(400, "request body: expected a JSON object with the keys of a scene file ("
                              + ", ".join(SCENE_KEYS) + ") and outputs")
    mapping = dict(doc)
    outputs = mapping.pop("outputs", ["png", "truth"])
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
    # the scene itself is validated by the worker (the same validator as scene files): doing it
    # here as well cost ~1 ms of the ~9 ms a request adds to a frame
    return mapping, tuple(outputs)


def _short(value) -> str:
    text = json.dumps(value) if not isinstance(value, str) else repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def build_app(pool: WorkerPool, *, token: str | None = None, limits: Limits = Limits()):
    """The Starlette application of protocol v1 around a started :class:`WorkerPool`."""
    has_facility = pool.info.get("facility") is not None
    document = openapi_document()

    async def health(request):
        return JSONResponse({"status": "ok", "api": "v1", "workers": pool.n, "busy": pool.busy, "waiting": pool.waiting,
                             "outputs": [o for o in OUTPUTS if o != "screen_png" or has_facility],
                             "facility": pool.info.get("facility")})

    async def openapi(request):
        return JSONResponse(document)

    async def read_body(request) -> bytes:
        declared = request.headers.get("content-length")
        if declared is not None:
            try:
                n = int(declared)
            except ValueError:
                raise _HTTPError(400, f"Content-Length {declared!r}: not a number") from None
            if n > limits.max_request_bytes:
                raise _HTTPError(413, f"request body: {n} bytes; at most {limits.max_request_bytes} (--max-request-bytes)")
        chunks, size = [], 0
        async for chunk in request.stream():
            size += len(chunk)
            if size > limits.max_request_bytes:
                raise _HTTPError(413, f"request body: more than {limits.max_request_bytes} bytes (--max-request-bytes)")
            chunks.append(chunk)
        return b"".join(chunks)

    async def render(request):
        try:
            if token is not None:
                given = request.headers.get(AUTH_HEADER, "")
                scheme, _, value = given.partition(" ")
                if not (scheme.lower() == "bearer" and hmac.compare_digest(value.strip().encode(), token.encode())):
                    raise _HTTPError(401, "Authorization: expected 'Bearer TOKEN' with the server's --token")
            ctype = request.headers.get("content-type", "application/json").split(";")[0].strip().lower()
            if ctype not in ("application/json", "application/x-www-form-urlencoded", ""):
                raise _HTTPError(415, f"Content-Type {ctype!r}: send the scene mapping as application/json")
            body = await read_body(request)
            mapping, outputs = parse_request(body, has_facility=has_facility, limits=limits)
            answer = await pool.render(mapping, outputs)
        except _HTTPError as exc:
            return _error(exc.status, exc.message)
        except ClientDisconnect:
            return Response(status_code=400)
        kind = answer[0]
        if kind == "bad":
            return _error(400, answer[1])
        if kind != "ok":
            return _error(500, answer[1])
        _, ctype, lines, seconds, body = answer
        headers = {"Skynav-Render-Seconds": f"{seconds:.6f}", "content-type": ctype}
        if lines:
            headers["Skynav-Warnings"] = " | ".join(lines).encode("ascii", "replace").decode("ascii")[:4000]
        return Response(body, headers=headers)

    async def http_error(request, exc):
        return _error(exc.status_code, f"{request.method} {request.url.path}: {exc.detail}")

    async def internal_error(request, exc):
        print(f"skynav serve: internal error on {request.method} {request.url.path}: {exc.__class__.__name__}: {exc}",
              file=sys.stderr)
        return _error(500, "internal error; see the server's log")

    routes = [Route(f"{API_PREFIX}/health", health, methods=["GET"]),
              Route(f"{API_PREFIX}/openapi.json", openapi, methods=["GET"]),
              Route(f"{API_PREFIX}/render", render, methods=["POST"])]

    @asynccontextmanager
    async def lifespan(app):
        await pool.attach()
        yield
        pool.detach()

    return Starlette(routes=routes, lifespan=lifespan,
                     exception_handlers={HTTPException: http_error, Exception: internal_error})


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
        config = uvicorn.Config(app, log_level="warning", access_log=False, lifespan="on", proxy_headers=False,
                                timeout_graceful_shutdown=600, limit_concurrency=limits.max_queue * 4 + workers + 64)
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
