"""Slow and idle clients: the bounds per connection that uvicorn's settings do not give.

uvicorn's public settings bound a request's header (its h11 parser refuses a request line and
header past ``h11_max_incomplete_event_size``; its httptools parser has no such bound, so the
server runs h11) and close a kept-alive connection ``timeout_keep_alive`` seconds after its last
answer. They set no deadline for a request's header (a connection that sends nothing, or one
byte a second, is kept for ever), no cap per client, and past ``limit_concurrency`` they refuse
the newcomer, so that idle connections deny everyone else. This module adds those bounds around
uvicorn's own HTTP protocol, through two interfaces only: the :class:`asyncio.Protocol` methods
that the event loop calls (the guard is the protocol of each connection and hands every call on
to uvicorn's), and the ASGI ``scope["client"]`` of each request (the connection's remote address
and port), by which :class:`RequestTracker` tells the guard when a request of its connection is
in the application.

- **Header deadline**: from its opening, and again from the end of each answer, a connection
  has ``header_timeout_s`` to deliver its next request's header; then it is closed (with a
  ``408`` line when part of a header came).
- **Write stall**: an answer whose client reads nothing for ``write_timeout_s`` (the socket's
  buffers full) loses the connection.
- **Connections**: at most ``max_connections`` in all and ``max_connections_per_client`` from
  one address. A new connection over either cap first displaces the oldest idle one (no request
  in the application: waiting for a header, or kept alive) of the same scope; only when every
  such connection has a request in progress is the newcomer refused with a ``503`` line. Idle
  and dripping connections so never keep another client out.

The request body's deadline is the application's (:mod:`skynav.service.app` reads it with a
deadline).
"""

from __future__ import annotations

import asyncio
import json
from collections import Counter, OrderedDict
from dataclasses import dataclass


@dataclass(frozen=True)
class ConnectionLimits:
    """The bounds of :mod:`skynav.service.guard` and the request body's deadline (``skynav serve`` options)."""
    header_timeout_s: float = 10.0          # --header-timeout
    body_timeout_s: float = 10.0            # --body-timeout
    write_timeout_s: float = 60.0           # --write-timeout
    max_header_bytes: int = 16384           # --max-header-bytes: request line and header
    max_connections: int = 512              # --max-connections
    max_connections_per_client: int = 64    # --max-connections-per-client


def _answer(status: str, line: str) -> bytes:
    """A whole HTTP answer that closes its connection: ``status`` and a one-line JSON error."""
    body = json.dumps({"error": line}, separators=(",", ":")).encode()   # as the application writes it
    return (f"HTTP/1.1 {status}\r\ncontent-type: application/json\r\ncontent-length: {len(body)}\r\n"
            "connection: close\r\n\r\n").encode("latin-1") + body


class Registry:
    """The connections of one server: counts per address, the idle ones oldest first, and each
    one's guard by its remote ``(host, port)``."""

    def __init__(self, limits: ConnectionLimits):
        self.limits = limits
        self.by_peer: dict = {}
        self.per_host: Counter = Counter()
        self.idle: OrderedDict = OrderedDict()   # guard -> None, in the order they became idle

    def admit(self, guard) -> bool:
        """Count ``guard``'s connection in, displacing the oldest idle one where a cap is
        reached; False when it must be refused (every connection in its scope is busy)."""
        lim = self.limits
        if self.per_host[guard.host] >= lim.max_connections_per_client:
            victim = next((g for g in self.idle if g.host == guard.host), None)
            if victim is None:
                return False
            victim.shed()
        if len(self.by_peer) >= lim.max_connections:
            victim = next(iter(self.idle), None)
            if victim is None:
                return False
            victim.shed()
        self.by_peer[guard.peer] = guard
        self.per_host[guard.host] += 1
        return True

    def forget(self, guard) -> None:
        if self.by_peer.get(guard.peer) is guard:
            del self.by_peer[guard.peer]
            self.per_host[guard.host] -= 1
            if not self.per_host[guard.host]:
                del self.per_host[guard.host]
        self.idle.pop(guard, None)

    def started(self, peer) -> None:
        guard = self.by_peer.get(peer)
        if guard is not None:
            guard.request_started()

    def finished(self, peer) -> None:
        guard = self.by_peer.get(peer)
        if guard is not None:
            guard.request_finished()


class RequestTracker:
    """ASGI middleware: tells the :class:`Registry` when a request of a connection enters and
    leaves the application (by ``scope["client"]``, the connection's remote address and port)."""

    def __init__(self, app, registry: Registry):
        self.app, self.registry = app, registry

    async def __call__(self, scope, receive, send):
        client = scope.get("client") if scope["type"] == "http" else None
        if client is None:
            await self.app(scope, receive, send)
            return
        peer = (client[0], client[1])
        self.registry.started(peer)
        try:
            await self.app(scope, receive, send)
        finally:
            self.registry.finished(peer)


class GuardedProtocol(asyncio.Protocol):
    """A connection of :attr:`inner_class` (made with the same arguments) under the bounds of
    :attr:`registry`; :func:`guarded_protocol` makes the class for a pair."""

    inner_class: type = None
    registry: Registry = None

    def __init__(self, *args, **kwargs):
        self.inner = self.inner_class(*args, **kwargs)
        self.limits = self.registry.limits
        self.transport = None
        self.admitted = False
        self.in_flight = 0
        self.partial = False     # bytes came since the header deadline was set
        self.timer = None
        self.stall = None

    # ---------------------------------------------------------------- the event loop's calls
    def connection_made(self, transport):
        self.transport = transport
        peer = transport.get_extra_info("peername")
        self.peer = (str(peer[0]), int(peer[1])) if isinstance(peer, (tuple, list)) else (str(peer), id(self))
        self.host = self.peer[0]
        if not self.registry.admit(self):
            transport.write(_answer("503 Service Unavailable", (
                f"too many connections ({self.limits.max_connections} in all, "
                f"{self.limits.max_connections_per_client} per client), each with a request in progress; try again")))
            transport.close()
            return
        self.admitted = True
        self.inner.connection_made(transport)
        self._idle()

    def data_received(self, data):
        if not self.in_flight:
            self.partial = True
        self.inner.data_received(data)

    def eof_received(self):
        return self.inner.eof_received() if self.admitted else None

    def connection_lost(self, exc):
        self._cancel()
        self._unstall()
        if self.admitted:
            self.registry.forget(self)
            self.inner.connection_lost(exc)

    def pause_writing(self):
        self._unstall()
        self.stall = asyncio.get_running_loop().call_later(self.limits.write_timeout_s, self._stalled)
        self.inner.pause_writing()

    def resume_writing(self):
        self._unstall()
        self.inner.resume_writing()

    # ---------------------------------------------------------------- the guard's own
    def request_started(self):
        self.in_flight += 1
        self._cancel()
        self.registry.idle.pop(self, None)

    def request_finished(self):
        self.in_flight -= 1
        if not self.in_flight and not self.transport.is_closing():
            self._idle()

    def shed(self):
        """Closed to make room for a new connection (this one is idle)."""
        self.registry.forget(self)
        self.transport.close()

    def _idle(self):
        self.partial = False
        self.registry.idle[self] = None
        self.registry.idle.move_to_end(self)
        self._cancel()
        self.timer = asyncio.get_running_loop().call_later(self.limits.header_timeout_s, self._header_late)

    def _cancel(self):
        if self.timer is not None:
            self.timer.cancel()
            self.timer = None

    def _header_late(self):
        self.timer = None
        if self.in_flight or self.transport.is_closing():
            return
        if self.partial:
            self.transport.write(_answer("408 Request Timeout", (
                f"request header: not received within {self.limits.header_timeout_s:g} s (--header-timeout)")))
        self.transport.close()

    def _unstall(self):
        if self.stall is not None:
            self.stall.cancel()
            self.stall = None

    def _stalled(self):
        self.stall = None
        self.transport.abort()   # the answer's bytes cannot be delivered: no graceful close


def guarded_protocol(inner_class: type, registry: Registry) -> type:
    """An :class:`asyncio.Protocol` class whose connections are those of ``inner_class`` (made with
    the same arguments) under the bounds of ``registry``."""
    return type("GuardedProtocol", (GuardedProtocol,), {"inner_class": inner_class, "registry": registry})
