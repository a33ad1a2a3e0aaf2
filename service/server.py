"""``skynav serve``: the HTTP server (Starlette on uvicorn) in front of warm render workers.

:func:`serve` binds the address, starts the workers (:class:`skynav.service.pool.WorkerPool`),
and runs the application of :mod:`skynav.service.app` on uvicorn, through its public API
(:class:`uvicorn.Config`, :class:`uvicorn.Server`), until SIGINT or SIGTERM: uvicorn then stops
accepting, lets the running renders finish and answer, and the workers are stopped.
"""

from __future__ import annotations

import contextlib
import ipaddress
import signal
import socket
import threading

import uvicorn

from .app import build_app
from .guard import ConnectionLimits, Registry, RequestTracker, guarded_protocol
from .pool import Limits, ServiceStartError, WorkerPool


def is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def _listen(host: str, port: int) -> socket.socket:
    """A socket listening on ``host:port``; ServiceStartError (one line) where it cannot."""
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    sock = socket.socket(family, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        sock.bind((host, port))
    except OSError as exc:
        sock.close()
        raise ServiceStartError(f"--host {host} --port {port}: cannot listen there ({exc.strerror or exc})") from None
    sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)   # small answers on kept-alive connections
    sock.listen(128)
    return sock


@contextlib.contextmanager
def _stop_signals_noted():
    """SIGINT and SIGTERM only noted while uvicorn serves.

    uvicorn handles both while it serves (a graceful shutdown), then restores the handlers it
    found and raises the signal again for them: these, which let :func:`serve` go on to stop the
    workers and return. Outside the main thread (where no handler can be set) nothing changes."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    signals = (signal.SIGINT, signal.SIGTERM)
    previous = {sig: signal.signal(sig, lambda signum, frame: None) for sig in signals}
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


def uvicorn_config(app, connections: ConnectionLimits) -> uvicorn.Config:
    """uvicorn's configuration of the server: its h11 protocol, whose request header is bounded
    (``h11_max_incomplete_event_size``), under the guard of :mod:`skynav.service.guard`.

    ``Config.load()`` resolves ``http="h11"`` to uvicorn's protocol class (``http_protocol_class``,
    from which uvicorn makes each connection's protocol); the guard's class, which makes one of
    those per connection and hands it every :class:`asyncio.Protocol` call, takes its place.
    The connections are bounded by the guard (``limit_concurrency`` would refuse newcomers while
    idle connections stay)."""
    registry = Registry(connections)
    # proxy_headers off: the server is not behind a proxy (a client's X-Forwarded-For means nothing
    # here; scope["client"] is the connection's own address, by which the guard knows it)
    config = uvicorn.Config(RequestTracker(app, registry), log_level="warning", access_log=False, lifespan="on",
                            proxy_headers=False, timeout_graceful_shutdown=600, limit_concurrency=None, http="h11",
                            h11_max_incomplete_event_size=connections.max_header_bytes)
    config.load()
    config.http_protocol_class = guarded_protocol(config.http_protocol_class, registry)
    return config


def serve(*, host: str = "127.0.0.1", port: int = 8765, workers: int = 1, facility=None, token: str | None = None,
          limits: Limits = Limits(), threads=None, ready=print, allow_origins=(),
          connections: ConnectionLimits = ConnectionLimits()) -> None:
    """Bind, warm the workers, print the ready line through ``ready``, serve until SIGINT/SIGTERM.

    On a signal uvicorn stops accepting, lets the running renders finish and answer, then the
    workers are stopped.
    """
    sock = _listen(host, port)
    pool = WorkerPool(workers, facility=facility, threads=threads, limits=limits)
    try:
        warm_s = pool.start()
    except BaseException:
        sock.close()
        raise
    shown = f"[{host}]" if sock.family == socket.AF_INET6 else host
    line = (f"skynav serve: ready at http://{shown}:{sock.getsockname()[1]} ({workers} worker{'s' if workers != 1 else ''}"
            f"{', facility ' + str(pool.info['facility']) if pool.info.get('facility') else ''}; warm in {warm_s:.1f} s)")
    try:
        app = build_app(pool, token=token, limits=limits, on_ready=lambda: ready(line), host=host,
                        allow_origins=allow_origins, body_timeout_s=connections.body_timeout_s)
        with _stop_signals_noted():
            uvicorn.Server(uvicorn_config(app, connections)).run(sockets=[sock])
    finally:
        pool.stop()
        sock.close()
