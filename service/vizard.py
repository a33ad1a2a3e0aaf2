"""``skynav serve --vizard``: a Vizard-compatible image endpoint for Basilisk's ``vizInterface``.

Basilisk's ``vizInterface`` (headless, ``noDisplay = True``) connects a ZeroMQ REQ socket to an
image endpoint and, on the steps where a camera wants a picture, sends the simulation's state and
asks for the picture. This endpoint binds the REP socket and answers as Vizard would, with
skynav's frames:

- ``PING`` (the handshake, and the request left outstanding between steps) -> ``PONG``;
- ``[SIM_UPDATE | | | VizMessage]`` -> ``OK``: the message (:mod:`skynav.service.vizard_schema`) is
  kept: its cameras by id, its spacecraft by name, its celestial bodies, and the scenario's epoch
  from the message that carries it (the first);
- ``REQUEST_IMAGE_<id>`` -> ``[4-byte big-endian length | PNG]``: the frame of camera ``<id>`` at the
  last message's state, rendered from the scene :func:`skynav.service.vizard_scene.scene_mapping`
  derives, exactly as ``skynav render`` renders that scene as a file
  (:func:`skynav.service.worker.render_outputs`: same validator, options, seed and encoders).

Anything else, or a message that does not parse, is one line in the log and an ``ERROR ...``
reply; a frame that cannot be rendered (no such camera, a bad configuration) is one line and an
empty image (length 0), which Basilisk passes on as an image with ``valid = 0``. The endpoint keeps
serving either way. A REQ client that goes away mid-request loses its reply and nothing else.
With ``truth_dir`` every frame's PNG, truth JSON and derived scene file are kept there
(``NNNNNN.png``, ``NNNNNN.json``, ``NNNNNN.scene.yaml``) so Basilisk's estimates can be scored.
"""

from __future__ import annotations

import io
import os
import signal
import struct
import sys
import threading
import traceback
from pathlib import Path

import numpy as np
import orjson
import yaml
import zmq
from google.protobuf.message import DecodeError
from PIL import Image

from skynav.infra.errors import ConfigValueError, SkynavError
from skynav.infra.heap import WarmHeap

from .vizard_scene import check_base, epoch_utc_iso, origin_body, scene_mapping
from .vizard_schema import VizMessage
from .worker import render_outputs

#: Basilisk's default request port (``vizInterface.reqPortNumber``)
DEFAULT_PORT = 5556

#: full-scale pixels that make a saturated disc (a saturated star or cosmic ray is a handful)
SATURATED_DISC_PX = 50

#: the scene sections a user may give the endpoint (the rest comes from Basilisk's messages)
BASE_SECTIONS = ("camera", "visibility", "render")


class VizardStartError(SkynavError):
    """The endpoint could not start (the address is taken, a bad truth folder); one line."""


class VizardRequestError(SkynavError):
    """A request the endpoint cannot answer with a frame (no such camera, no state yet); one line."""


def _one_line(text) -> str:
    return " ".join(str(text).split())


class VizardEndpoint:
    """The state of one endpoint and its answers; :meth:`answer` maps request frames to reply frames.

    Parameters
    ----------
    base : dict
        The scene's ``camera``, ``visibility`` and ``render`` sections (the user's; the camera's
        geometry is replaced by Basilisk's).
    truth_dir : path or None
        Where each frame's PNG, truth JSON and scene file are kept.
    log : callable
        Takes one line (default: print to stderr).
    """

    def __init__(self, base: dict | None = None, *, truth_dir=None, log=None):
        base = dict(base or {})
        unknown = sorted(set(base) - set(BASE_SECTIONS))
        if unknown:
            raise ConfigValueError(unknown[0], base[unknown[0]], "one of the sections " + ", ".join(BASE_SECTIONS)
                                   + " (the rest of the scene comes from Basilisk)")
        check_base(base)     # a bad key or value is one line now, not on every image
        self.base = base
        self.truth_dir = Path(truth_dir) if truth_dir is not None else None
        self.log = log or (lambda line: print(f"skynav serve --vizard: {line}", file=sys.stderr, flush=True))
        self.epoch_utc: str | None = None
        self.message = None
        self.cameras: dict = {}
        self.spacecraft: dict = {}
        self.origin: str | None = None
        self.frames = 0
        self.last_scene: dict | None = None
        self._said: set = set()

    # ------------------------------------------------------------------ the protocol
    def answer(self, frames: list) -> list:
        """The reply frames to one request's frames."""
        first = bytes(frames[0]) if frames else b""
        if len(frames) == 1 and first == b"PING":
            return [b"PONG"]
        if first == b"SIM_UPDATE" and len(frames) == 4:
            return self._sim_update(bytes(frames[3]))
        if len(frames) == 1 and first.startswith(b"REQUEST_IMAGE_"):
            return self._image(first[len(b"REQUEST_IMAGE_"):])
        shown = first[:40].decode("ascii", "replace")
        self.log(f"unknown request ({len(frames)} frame{'s' if len(frames) != 1 else ''}, first {shown!r}): "
                 "expected PING, [SIM_UPDATE | | | VizMessage] or REQUEST_IMAGE_<id>")
        return [b"ERROR unknown request"]

    def _sim_update(self, payload: bytes) -> list:
        try:
            msg = VizMessage.FromString(payload)
        except DecodeError:
            self.log(f"a SIM_UPDATE whose VizMessage does not parse ({len(payload)} bytes); kept the last state")
            return [b"ERROR VizMessage does not parse"]
        if msg.HasField("epoch"):
            try:
                self.epoch_utc = epoch_utc_iso(msg.epoch)
            except SkynavError as exc:
                self.log(_one_line(exc))
                return [b"ERROR bad epoch"]
        for config in msg.cameras:
            self.cameras[int(config.cameraID)] = config
            if config.renderRate == 0:
                self._once(f"rate{config.cameraID}", f"camera {config.cameraID}: renderRate 0 ns; Basilisk asks "
                           "for no image of it (give the camera a render rate in ns)")
        for sc in msg.spacecraft:
            self.spacecraft[sc.spacecraftName] = sc
        if msg.celestialBodies:
            self.origin, note = origin_body(msg.celestialBodies)
            if note:
                self._once("origin" + note, note)
        self.message = msg
        return [b"OK"]

    def _image(self, id_text: bytes) -> list:
        try:
            mapping = self._scene_for(id_text)
            png = self._render(mapping)
        except SkynavError as exc:
            self.log(f"REQUEST_IMAGE_{id_text[:20].decode('ascii', 'replace')}: {_one_line(exc)}; sent an empty image")
            return [struct.pack(">i", 0), b""]
        return [struct.pack(">i", len(png)), png]

    def _scene_for(self, id_text: bytes) -> dict:
        try:
            camera_id = int(id_text.decode("ascii"))
        except (UnicodeDecodeError, ValueError):
            raise VizardRequestError("the camera id is not a decimal integer") from None
        if self.message is None:
            raise VizardRequestError("no SIM_UPDATE came before the image request")
        if self.epoch_utc is None:
            raise VizardRequestError("no SIM_UPDATE carried the scenario's epoch (vizInterface sends it first)")
        config = self.cameras.get(camera_id)
        if config is None:
            raise VizardRequestError(f"no camera {camera_id} was configured in a SIM_UPDATE (configured: "
                                     + (", ".join(str(k) for k in sorted(self.cameras)) or "none") + ")")
        spacecraft = self.spacecraft.get(config.parentName)
        if spacecraft is None:
            if len(self.spacecraft) != 1:
                raise VizardRequestError(f"camera {camera_id}'s parent {config.parentName!r} is none of the "
                                         "spacecraft (" + ", ".join(self.spacecraft) + ")")
            spacecraft = next(iter(self.spacecraft.values()))
        return scene_mapping(self.message, config, spacecraft, epoch_utc=self.epoch_utc, base=self.base,
                             origin=self.origin)

    def _render(self, mapping: dict) -> bytes:
        # the truth only where it is kept: decoding it to look for a saturated disc would cost a
        # tenth of a second a frame (its stars); the PNG says whether anything saturates
        outputs = ("png", "truth") if self.truth_dir is not None else ("png",)
        parts, lines = render_outputs(mapping, outputs)
        for line in lines:
            self._once(line, line)
        self.last_scene = mapping
        self._check_saturation(parts, mapping)
        if self.truth_dir is not None:
            self._keep(parts, mapping)
        self.frames += 1
        return parts["png"]

    # ------------------------------------------------------------------ reports and files
    def _once(self, key: str, line: str) -> None:
        if key not in self._said:
            self._said.add(key)
            self.log(line)

    def _check_saturation(self, parts: dict, mapping: dict) -> None:
        """One line (once) when a disc saturates the sensor: Hough and limb finders lose accuracy.

        A disc's worth of pixels at full scale (at least :data:`SATURATED_DISC_PX`; a star or a
        cosmic ray saturates a handful) is a saturated body; the truth, where it is kept, names it.
        """
        if "saturation" in self._said:
            return
        dn = np.asarray(Image.open(io.BytesIO(parts["png"])))
        n = int(np.count_nonzero(dn == np.iinfo(dn.dtype).max))
        if n < SATURATED_DISC_PX:
            return
        name = "a body"
        if "truth" in parts:
            bodies = orjson.loads(parts["truth"]).get("bodies", ())
            discs = [b["name"] for b in bodies if b.get("resolved") and b.get("in_fov")]
            name = discs[0] if discs else name
        self._once("saturation", f"{name}'s disc saturates the sensor ({n} pixels at full scale, exposure "
                   f"{mapping['camera'].get('exposure_s', 'the preset')} s): Basilisk's Hough and limb finders "
                   "lose accuracy; shorten camera.exposure_s (--set)")

    def _keep(self, parts: dict, mapping: dict) -> None:
        stem = self.truth_dir / f"{self.frames:06d}"
        files = {".png": parts["png"], ".json": parts["truth"],
                 ".scene.yaml": yaml.safe_dump(mapping, sort_keys=False).encode()}
        for suffix, data in files.items():
            tmp = stem.with_name(stem.name + suffix + ".part")
            tmp.write_bytes(data)
            os.replace(tmp, stem.with_name(stem.name + suffix))


def bind_rep(host: str, port: int):
    """A ZeroMQ REP socket bound to ``tcp://host:port`` (``port`` 0: any free one); ``(context, socket, port)``."""
    ctx = zmq.Context()
    sock = ctx.socket(zmq.REP)
    sock.setsockopt(zmq.LINGER, 0)
    try:
        if port == 0:
            port = sock.bind_to_random_port(f"tcp://{host}")
        else:
            sock.bind(f"tcp://{host}:{port}")
    except zmq.ZMQError as exc:
        sock.close()
        ctx.term()
        raise VizardStartError(f"--host {host} --vizard-port {port}: cannot listen there ({exc})") from None
    return ctx, sock, port


def serve_vizard(endpoint: VizardEndpoint, *, host: str = "127.0.0.1", port: int = DEFAULT_PORT, ready=print,
                 stop: threading.Event | None = None, poll_ms: int = 100) -> None:
    """Bind, print the ready line through ``ready``, answer requests until SIGINT/SIGTERM (or ``stop``).

    A signal lets the request being answered finish, then the socket closes.
    """
    ctx, sock, port = bind_rep(host, port)
    stop = stop or threading.Event()
    previous = {}
    if threading.current_thread() is threading.main_thread():
        for sig in (signal.SIGINT, signal.SIGTERM):
            previous[sig] = signal.signal(sig, lambda signum, frame: stop.set())
    try:
        ready(f"skynav serve: Vizard endpoint ready at tcp://{host}:{port}")
        _answer_until(endpoint, sock, stop, poll_ms)
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        sock.close(0)
        ctx.term()


def _answer_until(endpoint: VizardEndpoint, sock, stop: threading.Event, poll_ms: int) -> None:
    """Answer each request on ``sock`` until ``stop`` is set (checked every ``poll_ms``)."""
    with WarmHeap() as heap:
        warm = False
        while not stop.is_set():
            if not sock.poll(poll_ms, zmq.POLLIN):
                continue
            frames = sock.recv_multipart(copy=True)
            try:
                reply = endpoint.answer(frames)
            except Exception as exc:  # noqa: BLE001 - a bug: one line, the endpoint keeps serving
                traceback.print_exc(file=sys.stderr)
                endpoint.log(f"internal error on a request ({exc.__class__.__name__}); see above")
                reply = [b"ERROR internal error"]
            sock.send_multipart(reply)
            if endpoint.frames and not warm:
                heap.warm()   # the first frame is made: the collector leaves the warm objects alone from here
                warm = True
