"""The render side of the service: worker processes that keep everything warm and render on request.

Each worker is a process of its own (``spawn``: nothing of the server's memory is shared), so two
requests never touch the same frame buffers or random streams: frames of concurrent clients cannot
mix. A worker loads the catalogue, ephemeris, radiometry tables and Mitsuba/Dr.Jit kernels once,
by rendering the built-in scenes at start, then answers the requests on its pipe (a request's
JSON body, its outputs, the pixel bound) with the answer's HTTP body
(:func:`skynav.service.protocol.answer_chunks`: one output's bytes, or the multipart body of
several). A 200 answer it writes, head and body, to the client's socket itself when the server
hands that over with the request (``SCM_RIGHTS``; the worker holds it only for that answer, and
writes nothing else to it), else to the server, which frames it.

The frame is rendered exactly as ``skynav render`` renders a scene file (same validator, same
options, same seed, same encoders: :func:`skynav.datasets.frame_files.frame_file_bytes`), so the
PNG, EXR and truth bytes are those of its files.
"""

from __future__ import annotations

import array
import contextlib
import os
import pickle
import signal
import socket
import struct
import sys
import time
import traceback
import warnings

try:  # Unix only: settle_heap counts page faults with it
    import resource
except ImportError:
    resource = None

from skynav.calibration.errors import CalibrationInputError
from skynav.calibration.facility_io import load_facility
from skynav.datasets.frame_files import frame_file_bytes
from skynav.datasets.hil_export import screen_frame_bytes
from skynav.infra.errors import ConfigValueError, SkynavError
from skynav.infra.heap import WarmHeap
from skynav.renderer.render import RenderOptions, render
from skynav.scenes.config import scene_spec_from_mapping
from skynav.scenes.presets import preset_mapping
from skynav.scenes.scene import build_from_spec

from .protocol import OUTPUTS, answer_chunks, answer_head, answer_headers, read_json, uvicorn_takes


def render_outputs(mapping: dict, outputs, *, facility=None, max_camera_pixels: int | None = None) -> tuple[dict, list]:
    """Render one scene mapping; ``({output: bytes}, [warning lines])``.

    Raises a :class:`~skynav.infra.errors.SkynavError` for a bad mapping (the scene-file words).
    """
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        spec = scene_spec_from_mapping(mapping)
        px = spec.camera.width * spec.camera.height
        if max_camera_pixels is not None and px > max_camera_pixels:
            raise ConfigValueError("camera", f"{spec.camera.width}x{spec.camera.height}",
                                   f"at most {max_camera_pixels} pixels a frame on this server (--max-camera-pixels)")
        scene = build_from_spec(spec)
        seed = spec.seed
        parts = {}
        if any(o in outputs for o in ("png", "exr", "truth")):
            # as skynav.cli.cmd_render: noise on, backend auto, the scene's cosmic rays and spp
            options = RenderOptions(noise=True, backend="auto", cosmic_rays_per_frame=spec.cosmic_rays_per_frame,
                                    mitsuba_spp=spec.mitsuba_spp)
            frame = render(scene, seed=seed, options=options)
            files = {"png": "png", "exr": "exr", "truth": "json"}
            for o in outputs:
                if o in files:
                    parts[o] = frame_file_bytes(frame, files[o])
        if "screen_png" in outputs:
            if facility is None:
                raise ConfigValueError("outputs", "screen_png", "png, exr or truth (this server has no facility)")
            if scene.camera != facility.camera:
                raise CalibrationInputError(
                    f"camera: the scene's camera ({scene.camera.width}x{scene.camera.height}, f "
                    f"{scene.camera.focal_length_mm:g} mm) is not the facility's ({facility.camera.width}x"
                    f"{facility.camera.height}, f {facility.camera.focal_length_mm:g} mm)")
            facility.check_coverage()
            parts["screen_png"] = screen_frame_bytes(facility, scene, source={"scene": "service", "seed": seed}, seed=seed)[0]
    lines = [" ".join(str(w.message).split()) for w in caught]
    return {o: parts[o] for o in outputs}, lines


def warm_up(facility=None) -> float:
    """Render the built-in scenes once (catalogue, ephemeris, radiometry, Mitsuba kernels); seconds."""
    t0 = time.perf_counter()
    render_outputs(preset_mapping("default"), ("png", "exr", "truth"))
    small = preset_mapping("earth_departure")   # resolved Earth and Moon: Mitsuba's scenes and kernels
    small["camera"].update({"width": 128, "height": 128})
    render_outputs(small, ("png",))
    return time.perf_counter() - t0


def settle_heap(max_frames: int = 12, pages: int = 64) -> int:
    """Render the default frame (PNG and truth) until one takes fewer than ``pages`` new memory
    pages (minor page faults), at most ``max_frames`` times; how many it rendered. Call it inside
    the :class:`~skynav.infra.heap.WarmHeap` of the request loop, once warm.

    With the young generation collected every 20,000 containers instead of 700, the process's
    heap grows for its first frames before it reuses its memory: the first six frames after the
    freeze each took ~2,000 fresh pages (8 MB), zeroed by the kernel, and 13-19 ms instead of
    10-11 ms (measured with ``ru_minflt``), the first requests' frames, not the warm-up's.
    """
    if resource is None:   # not Unix: no page-fault count; one frame
        max_frames = 1
    scene = preset_mapping("default")
    for k in range(1, max_frames + 1):
        before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt if max_frames > 1 else 0
        render_outputs(scene, ("png", "truth"))
        if max_frames == 1 or resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before < pages:
            return k
    return max_frames


def frame_head(n: int) -> bytes:
    """The head of one message of ``n`` bytes on the pipe between server and worker: the framing
    of :class:`multiprocessing.connection.Connection` (4-byte big-endian signed length; -1 then an
    8-byte length from 2 GiB), which the worker's ``conn.recv``/``conn.send`` speak too."""
    return struct.pack("!i", n) if n <= 0x7FFFFFFF else struct.pack("!iQ", -1, n)


def _advance(views: list, sent: int) -> None:
    """Drop from the gathered write ``views`` the ``sent`` bytes a ``sendmsg`` took (in place)."""
    while views and sent >= len(views[0]):
        sent -= len(views.pop(0))
    if views and sent:
        views[0] = views[0][sent:]


class _Pipe:
    """The worker's end of the pipe as a socket: requests (with the client's connection, when
    the server hands it over) in, answers out.

    A request is one message (:func:`frame_head` and a pickle), ``(JSON body, outputs, max
    pixels, direct)``; with ``direct`` (uvicorn's default header lines, whether the connection is
    kept alive, the request's serial) comes the client's socket, passed as ``SCM_RIGHTS``: the
    worker writes a 200 answer to the client itself (:meth:`send_direct`), then tells the server.
    The send buffer is widened to hold a whole answer (the default 1024^2 frame's PNG and truth
    are ~250 KB; Linux's default buffer is 208 KiB, its ceiling ``net.core.wmem_max``; best
    effort), and :meth:`send_ok` writes an answer's two messages, ``("ok", content type,
    warnings, seconds)`` and the body, in one gathered write: the server wakes once and reads it
    all.
    """

    def __init__(self, conn, sndbuf: int = 4 * 1024 * 1024):
        self.sock = socket.socket(fileno=os.dup(conn.fileno()))
        with contextlib.suppress(OSError):
            self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, sndbuf)
        self._fd_space = socket.CMSG_SPACE(4 * struct.calcsize("i"))

    def recv(self):
        """``(message, [file descriptors])``; EOFError when the server is gone."""
        fds = []
        (n,) = struct.unpack("!i", self._recv_exact(4, fds))
        if n == -1:
            (n,) = struct.unpack("!Q", self._recv_exact(8, fds))
        return pickle.loads(self._recv_exact(n, fds)), fds

    def _recv_exact(self, n: int, fds: list) -> bytearray:
        buf = bytearray(n)
        view, got = memoryview(buf), 0
        while got < n:
            k, ancillary, _, _ = self.sock.recvmsg_into([view[got:]], self._fd_space)
            for level, kind, data in ancillary:
                if level == socket.SOL_SOCKET and kind == socket.SCM_RIGHTS:
                    fds.extend(array.array("i", data[:len(data) - len(data) % 4]))
            if not k:
                raise EOFError
            got += k
        return buf

    def send_ok(self, header: tuple, chunks: list) -> None:
        head = pickle.dumps(header, protocol=pickle.HIGHEST_PROTOCOL)
        views = [memoryview(b) for b in
                 (frame_head(len(head)), head, frame_head(sum(len(c) for c in chunks)), *chunks) if len(b)]
        while views:
            _advance(views, self.sock.sendmsg(views))

    def send_direct(self, client: socket.socket, head: bytes, chunks: list) -> None:
        """Write an answer's HTTP head and body to the client's socket, at once and without
        waiting (the socket is the server's, non-blocking), then tell the server: ``("sent",
        True)`` and what the socket did not take (nothing, unless the client reads slowly), which
        the server writes after it; ``("sent", False)`` when the client is gone."""
        views = [memoryview(b) for b in (head, *chunks) if len(b)]
        ok = True
        try:
            sent = client.sendmsg(views, (), socket.MSG_DONTWAIT | socket.MSG_NOSIGNAL)
        except BlockingIOError:
            sent = 0
        except OSError:
            sent, ok = 0, False
        client.close()
        _advance(views, sent)
        self.send_ok(("sent", ok), views if ok else [])


def idle_pool_threads() -> int:
    """Put Dr.Jit's pool threads (nanothread's, named ``nt [i]``) of this process under
    ``SCHED_IDLE``; how many. Linux only (elsewhere, or where refused, nothing changes).

    After each kernel a pool thread spins for ~20 ms before it sleeps. In a worker that is just
    when the frame's answer is on its way: on two cores the spinning thread holds one, the
    worker's main thread, the server and the client share the other, and a waking client or
    server waited behind it up to a scheduler slice (own times of 2.4-4.7 ms in ~10 % of the
    frames). Under ``SCHED_IDLE`` the thread runs only where no other thread wants the core, and
    gives way at once to one that wakes: the render itself, with nothing else to run, keeps both
    cores. It is never set back (an unprivileged process may not raise a thread's priority).
    """
    if not hasattr(os, "sched_setscheduler") or not os.path.isdir("/proc/self/task"):
        return 0
    done = 0
    for tid in os.listdir("/proc/self/task"):
        try:
            with open(f"/proc/self/task/{tid}/comm") as f:
                if not f.read().startswith("nt ["):
                    continue
            os.sched_setscheduler(int(tid), os.SCHED_IDLE, os.sched_param(0))
            done += 1
        except (OSError, ValueError):
            continue
    return done


def worker_main(conn, facility_arg, threads, writing=None) -> None:
    """Entry point of one worker process: warm up, say ready, then answer requests until told to stop."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)    # Ctrl-C reaches the whole group; the server decides
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    if threads:
        os.environ["SKYNAV_THREADS"] = str(threads)

    try:
        facility = None
        if facility_arg is not None:
            facility = load_facility(facility_arg)
            facility.check_coverage()
        seconds = warm_up(facility)
    except SkynavError as exc:
        conn.send(("failed", " ".join(str(exc).split())))
        return
    except Exception as exc:  # noqa: BLE001 - reported to the server as one line, traceback on stderr
        traceback.print_exc(file=sys.stderr)
        conn.send(("failed", f"the render worker could not start: {exc.__class__.__name__}: {exc}"))
        return
    pipe = _Pipe(conn)
    idle_pool_threads()   # warm_up started the pool
    with WarmHeap() as heap:
        heap.warm()  # warm_up made a frame: the collector leaves the warm heap alone from here
        t0 = time.perf_counter()
        settle_heap()
        seconds += time.perf_counter() - t0
        conn.send(("ready", {"warm_s": seconds, "facility": None if facility is None else facility.name}))
        while True:
            try:
                msg, fds = pipe.recv()
            except (EOFError, OSError):
                return
            client = socket.socket(fileno=fds.pop(0)) if fds else None
            for fd in fds:
                os.close(fd)
            if msg is None:
                return
            body, outputs, max_pixels, direct = msg
            try:
                mapping = read_json(body)   # as the server read it (it checked the envelope)
                mapping.pop("outputs", None)
                t0 = time.perf_counter()
                parts, lines = render_outputs(mapping, tuple(o for o in outputs if o in OUTPUTS), facility=facility,
                                              max_camera_pixels=max_pixels)
                chunks, ctype = answer_chunks(parts)
                seconds = time.perf_counter() - t0
                headers = None if client is None or direct is None else answer_headers(ctype, seconds, lines)
                if headers is None or not uvicorn_takes(headers):
                    pipe.send_ok(("ok", ctype, lines, seconds), chunks)
                else:
                    defaults, keep_alive, serial = direct
                    head = answer_head(defaults, headers, sum(len(c) for c in chunks), keep_alive)
                    if writing is not None:
                        writing.value = serial   # from here a part of this answer may be with the client
                    pipe.send_direct(client, head, chunks)
            except SkynavError as exc:
                conn.send(("bad", " ".join(str(exc).split())))
            except MemoryError:
                conn.send(("bad", "camera: the frame does not fit in the server's memory; ask for fewer pixels"))
            except Exception as exc:  # noqa: BLE001 - a bug: logged here, one line to the client
                traceback.print_exc(file=sys.stderr)
                conn.send(("error", f"internal error while rendering ({exc.__class__.__name__}); see the server's log"))
            finally:
                if client is not None:
                    client.close()
