"""``skynav serve``: the render service (docs/service.md)."""

from __future__ import annotations

import os
import sys
import threading

from skynav.calibration.facility_io import load_facility
from skynav.scenes.constants import SECONDS_PER_DAY
from skynav.service.budget import MAX_REQUEST_MEMORY, MAX_REQUEST_SECONDS
from skynav.service.files import MAX_DATA_FILE_BYTES
from skynav.service.pool import REQUEST_DEADLINE_S, WORKER_MEMORY
from skynav.service.protocol import MAX_CAMERA_PIXELS, MAX_QUEUE, MAX_REQUEST_BYTES
from skynav.service.guard import ConnectionLimits
from skynav.service.server import Limits, ServiceStartError, is_loopback, serve

from .cli_args import (MAX_WORKERS, add_facility_arg, add_set_arg, add_workers_arg, float_in, int_in, non_negative_int,
                       positive_int)
from .cli_common import COMMAND_HELP, fail


def _vizard_endpoint(args):
    """``(the endpoint of --vizard's options, None)``, or ``(None, exit code)`` after one line."""
    # lazy: the endpoint loads zmq, protobuf and the renderer; skynav --help loads none of them
    from skynav.scenes.overrides import apply_overrides
    from skynav.scenes.scene_files import load_scene_mapping
    from skynav.service.vizard import BASE_SECTIONS, VizardEndpoint

    if not is_loopback(args.host) and not args.insecure:
        return None, fail(f"--host {args.host}: the Vizard endpoint has no token; binding an address other than "
                          "loopback needs --insecure (anyone who reaches it may make it render)")
    base = {}
    if args.camera is not None:
        section = load_scene_mapping(args.camera)
        base["camera"] = section["camera"] if isinstance(section.get("camera"), dict) else section
    if args.overrides:
        base = apply_overrides(base, args.overrides)
    unknown = sorted(set(base) - set(BASE_SECTIONS))
    if unknown:
        return None, fail(f"--set {unknown[0]}.*: the endpoint takes {', '.join(BASE_SECTIONS)} "
                          "(the rest of the scene comes from Basilisk)")
    if args.truth_dir is not None:
        try:
            os.makedirs(args.truth_dir, exist_ok=True)
        except OSError as exc:
            return None, fail(f"--truth-dir {args.truth_dir}: cannot make the folder ({exc.strerror or exc})")
    return VizardEndpoint(base, truth_dir=args.truth_dir), None


def cmd_serve_vizard(args) -> int:
    """``skynav serve --vizard``: the Vizard-compatible image endpoint (skynav.service.vizard) alone."""
    # lazy: the endpoint loads zmq, protobuf and the renderer; skynav --help loads none of them
    from skynav.service.vizard import VizardStartError, serve_vizard

    endpoint, rc = _vizard_endpoint(args)
    if endpoint is None:
        return rc
    try:
        serve_vizard(endpoint, host=args.host, port=args.vizard_port, ready=lambda line: print(line, flush=True))
    except VizardStartError as exc:
        return fail(str(exc))
    print(f"skynav serve: stopped ({endpoint.frames} frames)", file=sys.stderr)
    return 0


def _vizard_beside(args):
    """``--vizard --http``: the endpoint in a thread of its own; ``(thread, stop event, None)`` once it
    is ready, or ``(None, None, exit code)`` after one line. The HTTP server, in the main thread, takes
    the signals; setting the event stops the endpoint."""
    # lazy: the endpoint loads zmq, protobuf and the renderer; skynav --help loads none of them
    from skynav.service.vizard import VizardStartError, serve_vizard

    endpoint, rc = _vizard_endpoint(args)
    if endpoint is None:
        return None, None, rc
    stop, started, errors = threading.Event(), threading.Event(), []

    def run():
        try:
            serve_vizard(endpoint, host=args.host, port=args.vizard_port, stop=stop,
                         ready=lambda line: (print(line, flush=True), started.set()))
        except VizardStartError as exc:
            errors.append(str(exc))
        finally:
            started.set()

    thread = threading.Thread(target=run, name="skynav-vizard", daemon=True)
    thread.start()
    started.wait()
    if errors:
        return None, None, fail(errors[0])
    return thread, stop, None


def cmd_serve(args) -> int:
    if args.http and not args.vizard:
        return fail("--http: serves HTTP beside the Vizard endpoint; give it with --vizard (HTTP alone is the default)")
    if args.vizard and not args.http:
        return cmd_serve_vizard(args)
    beside = stop = None
    if args.vizard:
        beside, stop, rc = _vizard_beside(args)
        if beside is None:
            return rc
    try:
        return _serve_http(args)
    finally:
        if beside is not None:
            stop.set()
            beside.join()


def _serve_http(args) -> int:
    if args.port < 0 or args.port > 65535:
        return fail(f"--port {args.port}: expected 0..65535 (0: any free port)")
    token = args.token
    if token is None and args.token_env:
        token = os.environ.get(args.token_env) or None
        if token is None:
            return fail(f"--token-env {args.token_env}: the variable is not set or empty")
    if token is not None and len(token) < 16:
        return fail("--token: at least 16 characters (e.g. python -c 'import secrets; print(secrets.token_hex(16))')")
    if not is_loopback(args.host) and token is None and not args.insecure:
        return fail(f"--host {args.host}: binding an address other than loopback needs --token (or --insecure: "
                    "anyone who reaches it may make the server render)")
    if args.facility is not None:   # a bad facility is one line here, not a worker's failure

        load_facility(args.facility).check_coverage()
    for folder in args.data_dir:
        if not os.path.isdir(folder):
            return fail(f"--data-dir {folder}: not a folder")
    limits = Limits(max_request_bytes=args.max_request_bytes, max_camera_pixels=args.max_camera_pixels,
                    max_queue=args.max_queue, data_dirs=tuple(os.path.realpath(d) for d in args.data_dir),
                    max_data_file_bytes=args.max_data_file_bytes, max_request_memory=args.max_request_memory,
                    max_request_seconds=args.max_request_seconds, worker_memory=args.worker_memory or None,
                    request_deadline=args.request_deadline)
    threads = args.threads or max(1, (os.cpu_count() or 1) // args.workers)

    def ready(line):
        print(line, flush=True)

    try:
        serve(host=args.host, port=args.port, workers=args.workers, facility=args.facility, token=token,
              limits=limits, threads=threads, ready=ready, allow_origins=tuple(args.allow_origin),
              connections=_connection_limits(args))
    except ServiceStartError as exc:
        return fail(str(exc))
    except KeyboardInterrupt:
        pass
    print("skynav serve: stopped", file=sys.stderr)
    return 0


def _connection_limits(args) -> ConnectionLimits:
    return ConnectionLimits(header_timeout_s=args.header_timeout, body_timeout_s=args.body_timeout,
                            write_timeout_s=args.write_timeout, max_header_bytes=args.max_header_bytes,
                            max_connections=args.max_connections,
                            max_connections_per_client=args.max_connections_per_client)


def _add_connection_args(s) -> None:
    c, d = s.add_argument_group("Slow clients", "bounds per connection (docs/service.md, "
                                "'Running the service safely')"), ConnectionLimits()
    seconds = float_in(0, 3600, low_open=True, unit="s")
    c.add_argument("--header-timeout", type=seconds, default=d.header_timeout_s, metavar="S", help="a request's "
                   f"header must arrive within S of the connection's opening or the last answer (default {d.header_timeout_s:g})")
    c.add_argument("--body-timeout", type=seconds, default=d.body_timeout_s, metavar="S",
                   help=f"a request's body must arrive within S of its header (default {d.body_timeout_s:g})")
    c.add_argument("--write-timeout", type=seconds, default=d.write_timeout_s, metavar="S", help="a client that "
                   f"reads nothing of its answer for S loses the connection (default {d.write_timeout_s:g})")
    c.add_argument("--max-header-bytes", type=int_in(1024, 1 << 20), default=d.max_header_bytes, metavar="N",
                   help=f"largest request line and header (default {d.max_header_bytes})")
    c.add_argument("--max-connections", type=int_in(8, 100000), default=d.max_connections, metavar="N",
                   help=f"open connections in all; past it the oldest idle one is closed (default {d.max_connections})")
    c.add_argument("--max-connections-per-client", type=int_in(1, 100000), default=d.max_connections_per_client,
                   metavar="N", help="open connections from one address; past it its oldest idle one is closed "
                   f"(default {d.max_connections_per_client})")


def add_parser(sub) -> None:
    s = sub.add_parser(
        "serve", help=COMMAND_HELP["serve"],
        description="Start the render service (docs/service.md): worker processes keep the catalogue, ephemeris, "
        "radiometry tables and Mitsuba kernels warm; POST /v1/render takes a scene mapping (the keys of a scene "
        "file plus outputs) and returns PNG/EXR/truth bytes identical to 'skynav render'. Prints one line "
        "'skynav serve: ready at URL' when ready; SIGINT/SIGTERM finish the running renders and stop. Binds "
        "127.0.0.1 unless told otherwise; another address needs --token or --insecure. Bounds: request "
        f"body --max-request-bytes (default {MAX_REQUEST_BYTES}), camera --max-camera-pixels (default "
        f"{MAX_CAMERA_PIXELS}), outputs png, exr, truth (screen_png with --facility), --workers frames render at "
        f"once and --max-queue (default {MAX_QUEUE}) more wait; the next request gets 503.")
    s.add_argument("--host", default="127.0.0.1", help="address to bind (default 127.0.0.1, loopback only)")
    s.add_argument("--port", type=int, default=8765, help="TCP port (default 8765; 0: any free port, printed)")
    add_workers_arg(s, default=1, help=f"render processes, frames at once, 1..{MAX_WORKERS} (default 1)")
    add_facility_arg(s, required=False, help="facility YAML file or preset (screen, screen_small): enables screen_png")
    s.add_argument("--token", default=None, help="require 'Authorization: Bearer TOKEN' on /v1/render "
                   "(compared in constant time; at least 16 characters)")
    s.add_argument("--token-env", default=None, metavar="VAR", help="read the token from this environment variable "
                   "(keeps it out of the process list)")
    s.add_argument("--insecure", action="store_true", help="allow a non-loopback --host without a token")
    s.add_argument("--max-request-bytes", type=positive_int, default=MAX_REQUEST_BYTES, help="largest request body")
    s.add_argument("--max-camera-pixels", type=positive_int, default=MAX_CAMERA_PIXELS, help="largest frame, width x height")
    s.add_argument("--max-queue", type=positive_int, default=MAX_QUEUE, help="requests that may wait for a worker")
    s.add_argument("--data-dir", action="append", default=[], metavar="DIR", help="a folder whose files "
                   "(PSF images) requests may name, relative to it; repeatable (default: none, requests name no file)")
    s.add_argument("--max-data-file-bytes", type=positive_int, default=MAX_DATA_FILE_BYTES, metavar="N",
                   help=f"largest file a request may name (default {MAX_DATA_FILE_BYTES})")
    s.add_argument("--max-request-memory", type=positive_int, default=MAX_REQUEST_MEMORY, metavar="BYTES",
                   help="a request whose estimated memory (beyond the warm worker's) is larger gets 400 naming the key "
                        f"behind it (default {MAX_REQUEST_MEMORY})")
    s.add_argument("--max-request-seconds", type=float_in(0.0, SECONDS_PER_DAY, low_open=True, unit="s"),
                   default=MAX_REQUEST_SECONDS, metavar="S", help="a request whose estimated render time (one core) "
                   f"is longer gets 400 naming the key behind it (default {MAX_REQUEST_SECONDS:g})")
    s.add_argument("--worker-memory", type=non_negative_int, default=WORKER_MEMORY, metavar="BYTES",
                   help="each worker's address-space cap (RLIMIT_AS); a request that reaches it gets 503 and the "
                        f"worker is replaced (default {WORKER_MEMORY}; 0: none)")
    s.add_argument("--request-deadline", type=float_in(0.0, SECONDS_PER_DAY, low_open=True, unit="s"),
                   default=REQUEST_DEADLINE_S, metavar="S", help="wall seconds a worker may spend on one request; "
                   f"beyond, it is killed and replaced, and the request gets 503 (default {REQUEST_DEADLINE_S:g})")
    s.add_argument("--allow-origin", action="append", default=[], metavar="ORIGIN", help="a web origin "
                   "(e.g. https://lab.example) whose pages may call the server (CORS); repeatable (default: none)")
    s.add_argument("--threads", type=positive_int, default=None, help="threads per worker (default cores / workers)")
    _add_connection_args(s)
    v = s.add_argument_group("Vizard endpoint", "Basilisk's vizInterface (noDisplay) gets skynav frames "
                             "(docs/service.md); instead of HTTP, or beside it with --http")
    v.add_argument("--vizard", action="store_true", help="serve Basilisk's vizInterface as Vizard would: a "
                   "ZeroMQ REP socket on --host:--vizard-port answering PING, SIM_UPDATE and REQUEST_IMAGE_<id>")
    v.add_argument("--http", action="store_true", help="with --vizard: serve HTTP on --port as well (the "
                   "endpoint then renders in the server's process, beside the HTTP workers)")
    v.add_argument("--vizard-port", type=int_in(0, 65535, "0: any free port"), default=5556, metavar="PORT",
                   help="the endpoint's TCP port (default 5556, vizInterface's reqPortNumber; 0: any free port)")
    v.add_argument("--camera", default=None, metavar="FILE", help="camera YAML (a scene file's camera: section): "
                   "optics and sensor; its width, height and fov_deg, if given, must be Basilisk's")
    add_set_arg(v, "the endpoint's camera.*, render.*, visibility.* (e.g. --set camera.exposure_s=0.001)")
    v.add_argument("--truth-dir", default=None, metavar="DIR", help="keep each frame's PNG, truth JSON and "
                   "scene file here (NNNNNN.png, .json, .scene.yaml)")
    s.set_defaults(func=cmd_serve)
