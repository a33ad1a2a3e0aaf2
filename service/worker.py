"""The render side of the service: worker processes that keep everything warm and render on request.

Each worker is a process of its own (``spawn``: nothing of the server's memory is shared), so two
requests never touch the same frame buffers or random streams: frames of concurrent clients cannot
mix. A worker loads the catalogue, ephemeris, radiometry tables and Mitsuba/Dr.Jit kernels once,
by rendering the built-in scenes at start, then answers the requests on its pipe (a request's
JSON body, its outputs, the server's bounds) with the answer's HTTP body
(:func:`skynav.service.protocol.answer_chunks`: one output's bytes, or the multipart body of
several), which the server sends to the client.

The frame is rendered exactly as ``skynav render`` renders a scene file (same validator, same
options, same seed, same encoders: :func:`skynav.datasets.frame_files.frame_file_bytes`), so the
PNG, EXR and truth bytes are those of its files.
"""

from __future__ import annotations

import os
import resource
import signal
import sys
import time
import traceback
import warnings

from skynav.calibration.errors import CalibrationInputError
from skynav.calibration.facility_io import load_facility
from skynav.datasets.frame_files import frame_file_bytes
from skynav.datasets.hil_export import screen_frame_bytes
from skynav.infra.heap import WarmHeap
from skynav.renderer.render import RenderOptions, render
from skynav.scenes.config import scene_spec_from_mapping
from skynav.infra.errors import ConfigValueError, SkynavError
from skynav.scenes.presets import preset_mapping
from skynav.scenes.scene import build_from_spec

from .budget import Budget, check_budget
from .files import request_files
from .protocol import OUTPUTS, answer_chunks, read_json


def render_outputs(mapping: dict, outputs, *, facility=None, max_camera_pixels: int | None = None,
                   budget: Budget | None = None) -> tuple[dict, list]:
    """Render one scene mapping; ``({output: bytes}, [warning lines])``.

    Raises a :class:`~skynav.infra.errors.SkynavError` for a bad mapping (the scene-file words),
    and for a scene whose estimated cost is above ``budget`` (:func:`skynav.service.budget.check_budget`,
    before anything is drawn).
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
        # as skynav.cli.cmd_render: noise on, backend auto, the scene's cosmic rays and spp
        options = RenderOptions(noise=True, backend="auto", cosmic_rays_per_frame=spec.cosmic_rays_per_frame,
                                mitsuba_spp=spec.mitsuba_spp)
        if budget is not None:
            check_budget(scene, options, budget, mapping)
        if any(o in outputs for o in ("png", "exr", "truth")):
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


def answer(msg, facility) -> tuple:
    """The answer to one request ``(JSON body, outputs, bounds)`` (bounds:
    :meth:`skynav.service.pool.Limits.worker_bounds`): ``("ok", content type,
    warning lines, render seconds, HTTP body)``, or ``(kind, one line)`` with kind ``bad`` (the
    request's fault: a 400), ``cap`` (the worker reached its memory cap: it ends, the server
    replaces it and answers 503) or ``error`` (a bug: a 500, the traceback on this process's
    stderr)."""
    body, outputs, bounds = msg
    budget = bounds.get("budget")
    try:
        mapping = read_json(body)   # as the server read it (it checked the envelope)
        mapping.pop("outputs", None)
        t0 = time.perf_counter()
        with request_files(bounds["data_dirs"], bounds["max_data_file_bytes"],
                           None if budget is None else budget.max_file_bytes):
            parts, lines = render_outputs(mapping, tuple(o for o in outputs if o in OUTPUTS), facility=facility,
                                          max_camera_pixels=bounds["max_camera_pixels"], budget=budget)
        chunks, ctype = answer_chunks(parts)
        return "ok", ctype, lines, time.perf_counter() - t0, b"".join(chunks)
    except SkynavError as exc:
        return "bad", " ".join(str(exc).split())
    except MemoryError:
        return "cap", ("the render reached the worker's memory cap (skynav serve --worker-memory); the worker "
                       "was replaced; ask for a smaller frame, PSF or spp")
    except Exception as exc:  # noqa: BLE001 - a bug: logged here, one line to the client
        traceback.print_exc(file=sys.stderr)
        return "error", f"internal error while rendering ({exc.__class__.__name__}); see the server's log"


def cap_address_space(max_bytes: int | None) -> None:
    """This process's address space capped at ``max_bytes`` (``RLIMIT_AS``; None: no cap).

    An address-space cap rather than an RSS cap: the kernel enforces it at each allocation, so a
    request that would pass it gets a MemoryError (numpy) or dies (a native library) before it
    holds the memory, where a watched RSS is seen only after the fact. It counts what is reserved
    as well as what is touched: Dr.Jit and LLVM reserve address space for their JIT and thread
    pools, and a warm one-thread worker holds about 0.95 GB of it (``VmSize``, measured with
    ``python benchmarks/request_cost_bench.py``) for about 0.37 GB resident, which the cap leaves
    room for."""
    if max_bytes:
        resource.setrlimit(resource.RLIMIT_AS, (int(max_bytes), int(max_bytes)))


def worker_main(conn, facility_arg, threads, memory_cap=None) -> None:
    """Entry point of one worker process: warm up, say ready, then answer the requests on ``conn``
    (a :class:`multiprocessing.connection.Connection`) until it closes or brings None. The process
    runs under :func:`cap_address_space` (``memory_cap`` bytes); an answer of kind ``cap`` is its
    last."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)    # Ctrl-C reaches the whole group; the server decides
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    if threads:
        os.environ["SKYNAV_THREADS"] = str(threads)
    cap_address_space(memory_cap)

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
    with WarmHeap() as heap:
        heap.warm()  # warm_up made a frame: the collector leaves the warm heap alone from here
        conn.send(("ready", {"warm_s": seconds, "facility": None if facility is None else facility.name}))
        while True:
            try:
                msg = conn.recv()
            except (EOFError, OSError):
                return
            if msg is None:
                return
            reply = answer(msg, facility)
            conn.send(reply)
            if reply[0] == "cap":   # a MemoryError may leave a native library half-way: a fresh worker takes over
                return
