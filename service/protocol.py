"""The wire protocol of the render service, version 1: names, media types and bounds.

Shared by the server and the client; imports nothing of skynav (the client must stay light).
"""

from __future__ import annotations

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
