"""What a web browser may do with ``skynav serve``: nothing, unless the operator allows an origin.

A page the user visits can make the browser send requests to a server on loopback (a "simple"
cross-origin POST needs no preflight), and a page whose name is rebound to 127.0.0.1 (DNS
rebinding) can read the answers. :class:`BrowserGuard` refuses both before any endpoint runs:
a ``Host`` header that is not a name the server listens on (127.0.0.1, localhost, [::1], the
bound host; with or without the port) gets a 400, a request with an ``Origin`` header that is
not one of the operator's ``--allow-origin`` values a 403. A server bound to every address
(0.0.0.0, ::) cannot know its names and leaves ``Host`` unchecked (it needs a token anyway).
CORS answers are given only for the allowed origins (Starlette's ``CORSMiddleware``).
"""

from __future__ import annotations

import ipaddress

from starlette.responses import JSONResponse

LOOPBACK_NAMES = ("127.0.0.1", "localhost", "[::1]")


def host_names(host: str) -> frozenset | None:
    """The ``Host`` header values (lower case) a server bound to ``host`` answers; None for a
    wildcard bind (every value)."""
    try:
        if ipaddress.ip_address(host).is_unspecified:
            return None
    except ValueError:
        pass
    shown = f"[{host}]" if ":" in host else host
    return frozenset(n.lower() for n in (*LOOPBACK_NAMES, shown))


class BrowserGuard:
    """ASGI middleware: the ``Host`` and ``Origin`` checks of the module, on every HTTP request."""

    def __init__(self, app, *, host: str, allow_origins=()):
        self.app, self.names, self.origins = app, host_names(host), frozenset(allow_origins)

    def _refusal(self, headers: dict):
        host = headers.get(b"host", b"").decode("latin-1").strip().lower()
        name = host.rsplit(":", 1)[0] if host.rsplit(":", 1)[-1].isdigit() and not host.endswith("]") else host
        if self.names is not None and name not in self.names:
            return 400, (f"Host {host[:80]!r}: not a name this server listens on ({', '.join(sorted(self.names))}); "
                         "a page rebound to this address is not served")
        origin = headers.get(b"origin")
        if origin is not None and origin.decode("latin-1") not in self.origins:
            return 403, (f"Origin {origin.decode('latin-1')[:80]!r}: requests from web pages are refused "
                         "(the server's operator allows an origin with --allow-origin)")
        return None

    async def __call__(self, scope, receive, send):
        if scope["type"] == "http":
            refusal = self._refusal(dict(scope["headers"]))
            if refusal is not None:
                status, line = refusal
                await JSONResponse({"error": " ".join(line.split())}, status_code=status)(scope, receive, send)
                return
        await self.app(scope, receive, send)
