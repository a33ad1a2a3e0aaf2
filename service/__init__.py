"""The render service: frames for programs in a loop (flight software, benches, simulators).

Three halves (docs/service.md):

- :mod:`skynav.service.server`: ``skynav serve``, a long-running HTTP server on uvicorn whose
  worker processes keep the catalogue, ephemeris, radiometry tables and Mitsuba/Dr.Jit kernels
  warm and render a scene mapping on request (``POST /v1/render``);
- :mod:`skynav.service.client`: :class:`Client`, which a program imports to ask for frames. It
  loads no renderer, Mitsuba or Dr.Jit (only numpy and the frame-file readers);
- :mod:`skynav.service.loop`: the closed-loop driver of ``skynav bench loop``, where the flight
  software (``skynav.pipeline``) reaches the renderer only through the client.

``import skynav.service`` loads none of them; ``skynav.service.Client`` imports the client only.
"""

from __future__ import annotations

import importlib

__all__ = ["Client", "LocalServer", "RenderResult", "ServiceError"]

_LAZY = {"Client": "client", "LocalServer": "client", "RenderResult": "client", "ServiceError": "client"}


def __getattr__(name):
    if name in _LAZY:
        return getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
