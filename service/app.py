"""The HTTP side of ``skynav serve``: the Starlette application of protocol v1.

``POST /v1/render`` checks a request's envelope (token, media type, size, JSON object, outputs)
and hands its JSON body to an idle worker (:class:`skynav.service.pool.WorkerPool`), which
validates the scene with the scene-file validator (so errors use the scene-file words: a ``bad``
answer becomes the 400's line) and renders it; the server renders nothing itself and writes no
file. ``GET /v1/health`` and ``GET /v1/openapi.json`` describe the server. Every error is a
4xx/5xx with a one-line JSON body ``{"error": "..."}``.

Each 200 answer carries a ``Server-Timing`` header (W3C Server Timing, milliseconds):
``queue`` (waiting for an idle worker), ``render`` (the worker's render and encoding of the
outputs) and ``service`` (the rest of the server's time on the request, from the endpoint's start
to the answer handed to uvicorn: the checks, the hand-over to the worker and back).
"""

from __future__ import annotations

import asyncio
import hmac
import json
import sys
import time
from contextlib import asynccontextmanager

from starlette.applications import Starlette
from starlette.exceptions import HTTPException
from starlette.middleware import Middleware
from starlette.middleware.cors import CORSMiddleware
from starlette.requests import ClientDisconnect
from starlette.responses import JSONResponse, Response
from starlette.routing import Route

from .browser import BrowserGuard
from .openapi import openapi_document
from .pool import ClientGone, Limits, ServiceBusy, WorkerDied, WorkerPool
from .protocol import API_PREFIX, OUTPUTS, SCENE_KEYS, read_json, server_timing, warnings_header


class _HTTPError(Exception):
    def __init__(self, status: int, message: str):
        super().__init__(message)
        self.status, self.message = status, " ".join(str(message).split())


def _error(status: int, message: str) -> JSONResponse:
    return JSONResponse({"error": " ".join(str(message).split())}, status_code=status)


def parse_request(body: bytes, *, has_facility: bool) -> tuple:
    """Check a request body's envelope (a JSON object; its outputs): the outputs asked for;
    raises :class:`_HTTPError` (400) with one line.

    The scene itself is validated by the worker, which reads it from the same bytes with the same
    reader (:func:`skynav.service.protocol.read_json`)."""
    try:
        doc = read_json(body)
    except (UnicodeDecodeError, ValueError, RecursionError) as exc:
        raise _HTTPError(400, f"request body: not a JSON object ({str(exc).splitlines()[0][:120]})") from None
    if not isinstance(doc, dict):
        raise _HTTPError(400, "request body: expected a JSON object with the keys of a scene file ("
                              + ", ".join(SCENE_KEYS) + ") and outputs")
    _check_numbers(doc)
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


#: Integers in a request are at most this in magnitude: every numeric field of a scene is a
#: 64-bit integer or a float, and a larger integer (JSON allows any number of digits) overflows
#: their conversions.
MAX_INTEGER = 2**63 - 1


def _check_numbers(doc) -> None:
    """A 400 naming the first integer of ``doc`` beyond :data:`MAX_INTEGER` in magnitude (its
    dotted key, as the scene-file errors write it), before any field's validator converts it."""
    stack = [("", doc)]
    while stack:
        path, node = stack.pop()
        if isinstance(node, dict):
            stack.extend((f"{path}.{k}" if path else str(k), v) for k, v in reversed(node.items()))
        elif isinstance(node, list):
            stack.extend((f"{path}[{i}]", v) for i, v in reversed(list(enumerate(node))))
        elif isinstance(node, int) and not isinstance(node, bool) and abs(node) > MAX_INTEGER:
            raise _HTTPError(400, f"{path or 'request body'} = an integer of {len(str(abs(node)))} digits is not "
                                  f"allowed; expected a number of magnitude at most {MAX_INTEGER}")


def _short(value) -> str:
    text = json.dumps(value) if not isinstance(value, str) else repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _check_token(request, token: bytes | None) -> None:
    if token is None:
        return
    scheme, _, value = request.headers.get("authorization", "").partition(" ")
    if not (scheme.lower() == "bearer" and hmac.compare_digest(value.strip().encode("latin-1"), token)):
        raise _HTTPError(401, "Authorization: expected 'Bearer TOKEN' with the server's --token")


def _check_media_type(request) -> None:
    kind = request.headers.get("content-type", "").split(";")[0].strip().lower()
    if kind != "application/json":   # a form or a bare text/plain is what a web page can send unasked
        raise _HTTPError(415, f"Content-Type {kind!r}: send the scene mapping as application/json")


async def _read_body(request, bound: int, timeout_s: float) -> bytes:
    """The request's body, at most ``bound`` bytes (413 beyond, before reading it where the
    Content-Length says so), all of it within ``timeout_s`` (408 after, and the connection is
    closed); ClientDisconnect when the client hangs up first."""
    try:
        if hasattr(asyncio, "timeout"):   # Python 3.11: a timer, no task of its own (as asyncio.wait_for makes)
            async with asyncio.timeout(timeout_s):
                return await _read_bounded(request, bound)
        return await asyncio.wait_for(_read_bounded(request, bound), timeout_s)
    except (TimeoutError, asyncio.TimeoutError):
        raise _HTTPError(408, f"request body: not received within {timeout_s:g} s (--body-timeout)") from None


async def _read_bounded(request, bound: int) -> bytes:
    declared = request.headers.get("content-length")
    if declared is not None:
        try:
            n = int(declared)
        except ValueError:
            raise _HTTPError(400, f"Content-Length {declared!r}: not a number") from None
        if n > bound:
            raise _HTTPError(413, f"request body: {n} bytes; at most {bound} (--max-request-bytes)")
    chunks, size = [], 0
    async for chunk in request.stream():
        size += len(chunk)
        if size > bound:
            raise _HTTPError(413, f"request body: more than {bound} bytes (--max-request-bytes)")
        chunks.append(chunk)
    return b"".join(chunks)


def render_endpoint(pool: WorkerPool, *, token: str | None, limits: Limits, has_facility: bool,
                    body_timeout_s: float = 10.0):
    """The endpoint of ``POST /v1/render``."""
    token_bytes = None if token is None else token.encode()

    async def render(request) -> Response:
        t0 = time.perf_counter()
        try:
            _check_token(request, token_bytes)
            _check_media_type(request)
            body = await _read_body(request, limits.max_request_bytes, body_timeout_s)
            outputs = parse_request(body, has_facility=has_facility)
            answer, queue_s = await pool.render(body, outputs, gone=request.is_disconnected)
        except _HTTPError as exc:
            answer = _error(exc.status, exc.message)
            if exc.status == 408:   # the rest of the body is not read: the connection ends
                answer.headers["connection"] = "close"
            return answer
        except (ServiceBusy, WorkerDied) as exc:
            return _error(503, str(exc))
        except (ClientDisconnect, ClientGone):
            return Response(status_code=400)   # no one reads it
        if answer[0] != "ok":
            return _error(400 if answer[0] == "bad" else 500, answer[1])
        _, ctype, lines, render_s, content = answer
        own_s = time.perf_counter() - t0 - queue_s - render_s
        headers = {"server-timing": server_timing(queue=queue_s, render=render_s, service=own_s)}
        if lines:
            headers["skynav-warnings"] = warnings_header(lines)
        return Response(content, media_type=ctype, headers=headers)

    return render


def build_app(pool: WorkerPool, *, token: str | None = None, limits: Limits = Limits(), on_ready=None,
              host: str = "127.0.0.1", allow_origins=(), body_timeout_s: float = 10.0) -> Starlette:
    """The ASGI application of protocol v1 around a started :class:`WorkerPool`; ``on_ready()``
    is called once it has started (its lifespan's startup). Requests from web pages are refused
    unless their origin is in ``allow_origins``, other ``Host`` names than ``host``'s too
    (:mod:`skynav.service.browser`)."""
    has_facility = pool.info.get("facility") is not None
    document = openapi_document()

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
              Route(f"{API_PREFIX}/render", render_endpoint(pool, token=token, limits=limits, has_facility=has_facility,
                                                            body_timeout_s=body_timeout_s), methods=["POST"])]

    @asynccontextmanager
    async def lifespan(app):
        await pool.attach()
        if on_ready is not None:
            on_ready()
        yield
        pool.detach()

    middleware = [Middleware(BrowserGuard, host=host, allow_origins=tuple(allow_origins))]
    if allow_origins:
        middleware.append(Middleware(CORSMiddleware, allow_origins=list(allow_origins), allow_methods=["GET", "POST"],
                                     allow_headers=["authorization", "content-type"]))
    return Starlette(routes=routes, lifespan=lifespan, middleware=middleware,
                     exception_handlers={HTTPException: http_error, Exception: internal_error})
