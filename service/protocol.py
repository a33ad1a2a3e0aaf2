"""The wire protocol of the render service, version 1: names, media types and bounds.

Shared by the server and the client; imports nothing of skynav (the client must stay light).
"""

from __future__ import annotations

import json
import re
import secrets

import orjson

#: URL prefix of this protocol version.
API_PREFIX = "/v1"

#: The keys of a scene file (skynav.scenes.config): a request holds these plus ``outputs``.
SCENE_KEYS = ("epoch", "observer", "attitude", "camera", "visibility", "render")

#: Output name -> media type of its part. ``screen_png`` only when the server has a facility.
MEDIA_TYPES = {
    "png": "image/png",
    "exr": "image/x-exr",
    "truth": "application/json",
    "screen_png": "image/png",
}
OUTPUTS = tuple(MEDIA_TYPES)

#: Media type of an answer with several outputs: one part per output, in the order asked.
MULTIPART = "multipart/mixed"

# Default bounds (``skynav serve --help`` prints them; each has its option).
MAX_REQUEST_BYTES = 64 * 1024          # a scene mapping is ~1 KiB
MAX_CAMERA_PIXELS = 4096 * 4096        # width x height of one frame
MAX_QUEUE = 16                         # requests waiting for a worker beyond those rendering

#: HTTP header that carries the token (``Authorization: Bearer TOKEN``).
AUTH_HEADER = "authorization"


#: The multipart boundary of every answer whose parts do not contain it (practically all: a random
#: 128-bit string). One fixed string rather than a fresh one per answer because Python's
#: ``http.client`` (under urllib and requests) parses an answer's header with the e-mail parser,
#: which compiles a regular expression per new boundary, on every frame of such a client.
BOUNDARY = "skynav-3d1f0c9b2a8e47c6b5d4e3f2a1b0c9d8"


def answer_chunks(parts: dict) -> tuple[list, str]:
    """``(chunks, content type)`` of the answer to a render request: one output as its bytes with
    its media type; several as a multipart/mixed body, a part per output in the order given, each
    with its Content-Length. The body is the chunks one after the other: the worker writes them to
    the server in one gathered write (no joined copy), the server reads them as one message and
    hands it to the HTTP response as it is.

    The fixed boundary is used unless a part holds it. A JSON part (the truth) cannot hold a
    delimiter line (``--`` and the boundary at the start of a line: a JSON text's line breaks are
    whitespace between tokens, and no token starts with ``--``; nor does the text start with
    one), so only the images are searched, not the truth's ~235 KB."""
    if len(parts) == 1:
        (name, data), = parts.items()
        return [data], MEDIA_TYPES[name]
    boundary = BOUNDARY
    if any(MEDIA_TYPES[name] != "application/json" and boundary.encode("ascii") in data
           for name, data in parts.items()):
        boundary = "skynav-" + secrets.token_hex(16)
    chunks = []
    for name, data in parts.items():
        chunks.append(f"--{boundary}\r\nContent-Type: {MEDIA_TYPES[name]}\r\nContent-Disposition: inline; "
                      f"name=\"{name}\"\r\nContent-Length: {len(data)}\r\n\r\n".encode("ascii"))
        chunks.append(data)
        chunks.append(b"\r\n")
    chunks.append(f"--{boundary}--\r\n".encode("ascii"))
    return chunks, f'{MULTIPART}; boundary="{boundary}"'


#: A run of 19 digits: an integer that may not fit in 64 bits, which orjson reads as a float.
_LONG_DIGITS = re.compile(rb"[0-9]{19}")


def _no_constant(name):
    raise ValueError(f"{name} is not a JSON number")


def read_json(body: bytes):
    """The JSON value of a request body, as the standard library reads it (with NaN and the
    infinities refused); ValueError, UnicodeDecodeError or RecursionError where it cannot. The
    server reads a request with it to check its envelope, the worker reads the same bytes again
    for the scene (a request goes to the worker as its body, not as a pickled mapping).

    orjson reads it where the two agree (the faster reader with the caches cold, as they are
    after a frame's render): not a body orjson refuses (the errors then
    come in the standard library's words; orjson refuses all it does, NaN included, and a lone
    surrogate too), nor one with a run of 19 digits (an integer past 64 bits: the standard
    library's is an int, orjson's a float). Else the two read the same values (the same ints,
    correctly rounded floats, the last of duplicate keys)."""
    if not _LONG_DIGITS.search(body):
        try:
            return orjson.loads(body)
        except orjson.JSONDecodeError:
            pass
    return json.loads(body.decode("utf-8"), parse_constant=_no_constant)


#: A control character, which no header value may hold (RFC 9110, 5.5).
_CONTROL = re.compile("[\x00-\x1f\x7f]")


def warnings_header(lines: list) -> str:
    """The ``skynav-warnings`` header value of an answer: the scene's warnings, ``" | "``-separated,
    in ASCII without control characters, at most 4000 characters."""
    return _CONTROL.sub(" ", " | ".join(lines)).encode("ascii", "replace").decode("ascii")[:4000]


def server_timing(**seconds: float) -> str:
    """A ``Server-Timing`` header value (W3C Server Timing: ``name;dur=MILLISECONDS``, comma
    separated) of the durations given in seconds, in the order given.

    >>> server_timing(queue=0.0, render=0.0105, service=0.0004)
    'queue;dur=0.000, render;dur=10.500, service;dur=0.400'
    """
    return ", ".join(f"{name};dur={1e3 * s:.3f}" for name, s in seconds.items())


def parse_server_timing(value: str) -> dict:
    """``{name: seconds}`` of a ``Server-Timing`` header value (metrics without a ``dur`` left out)."""
    out = {}
    for metric in value.split(","):
        name, *params = (p.strip() for p in metric.split(";"))
        for p in params:
            key, _, number = p.partition("=")
            if key.strip().lower() == "dur":
                try:
                    out[name] = float(number.strip().strip('"')) / 1e3
                except ValueError:
                    pass
    return out
