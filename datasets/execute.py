"""Rendering a run plan's frames: one per-frame function, one strategy per executor.

Driver module (the *execute* step of :func:`skynav.datasets.generate`). Frame k is made by
:func:`produce_frame` from the sampler plan and frame k's seed ``SeedSequence([master_seed, k])``
alone, so a frame's files are the same bytes whatever the executor, the number of workers, or the
order in which frames ran (docs/conventions.md "Randomness"). The executors differ only in where
:func:`produce_frame` runs:

- :func:`run_in_process` (``workers=1``): in this process, in order; frame k's files are written on
  a writer thread while frame k + 1 is rendered and encoded (:func:`make_frame`,
  :func:`commit_frame`).
- :func:`run_process_pool` (``workers=N``): this process and ``N - 1`` spawned helpers share the
  frames (:func:`skynav.infra.pool.share_jobs`: ``cores // N`` threads each; each process takes
  the next frame when it is ready for one), each making its frames as :func:`run_in_process`
  does; the helpers start only once the frames left are worth their start-up
  (:class:`HelpersPay`). The plan travels pickled once per helper.
- :func:`run_dask`: one Dask task per run of frames (``pure=False``); the workers must see the
  dataset folder on a shared file system.

Each executor hands every :class:`FrameResult` to an ``accept`` callback as it arrives (the
runner checkpoints the manifest from there, :mod:`skynav.datasets.finalise`).
"""

from __future__ import annotations

import dataclasses
import hashlib
import os
import pickle
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from skynav.infra.atomic_files import atomic_write_many
from skynav.infra.heap import LargeArraysOnHeap, WarmHeap
from skynav.infra.pool import share_jobs
from skynav.renderer.render import RenderOptions, render
from skynav.scenes.scene import build_scene

from . import layout
from .errors import DatasetMismatchError
from .frame_files import encode_frame
from .journal import write_record
from .plan import frame_seed

__all__ = ["FrameResult", "EncodedFrame", "produce_frame", "frame_scene", "dataset_truth", "render_request", "make_frame", "commit_frame", "run_in_process",
           "run_process_pool", "run_dask", "check_backends"]


@dataclass(frozen=True, kw_only=True)
class FrameResult:
    """What a worker reports for one frame.

    Attributes
    ----------
    frame : int
    files : dict
        ``{relpath: sha256}`` of the frame's files.
    index_row : dict
        The frame's ``index.csv`` row.
    draws : int or None
        Monte Carlo draws it took (None for the other kinds).
    timings_s : dict
        ``sample``, ``render``, ``write``, s.
    backends : dict
        What ran: ``sensor`` (``"llvm"``, ``"cuda"`` or ``"numpy"``) and ``mitsuba_variant`` (None when no
        body was ray-traced in this frame).
    record : dict
        ``{"frames/NNNNNN.sha256": sha256}``: the frame's checksum record
        (:mod:`skynav.datasets.journal`), written after its files.
    """

    frame: int
    files: dict
    index_row: dict
    draws: int | None
    timings_s: dict
    backends: dict = dataclasses.field(default_factory=dict)
    record: dict = dataclasses.field(default_factory=dict)


# ----------------------------------------------------------------------------- the per-frame function
_PLAN_CACHE: dict = {}


def _plan_from_bytes(blob: bytes):
    key = hash(blob)
    plan = _PLAN_CACHE.get(key)
    if plan is None:
        _PLAN_CACHE.clear()
        plan = _PLAN_CACHE[key] = pickle.loads(blob)
    return plan


def produce_frame(plan, k: int, out_dir, *, master_seed: int, formats, catalog_limiting_v_mag: float,
                  render_options=None) -> FrameResult:
    """Sample, render and write frame ``k``; returns its checksums and index row.

    The random stream is ``default_rng(SeedSequence([master_seed, k]))``: the sampler draws
    first (:mod:`skynav.datasets.samplers`), then the renderer. A frame request's own camera,
    visibility criteria, catalogue limit, resolved-body threshold or cosmic-ray rate (per-scene
    keys of a ``scenes`` recipe) replace the plan's for this frame; without one, the recipe's
    ``render.resolved_threshold_px`` (if set) replaces the scene model's default.

    The two halves, :func:`make_frame` (sample, render, encode) and :func:`commit_frame` (write
    the files, their checksums, the record), are what :func:`run_in_process` runs on two
    threads.

    Parameters
    ----------
    plan : SamplerPlan or bytes
        The sampler plan, or its pickle (cached per process).
    k : int
    out_dir : str or os.PathLike
        The dataset folder.
    master_seed : int
    formats : sequence of str
    catalog_limiting_v_mag : float
        The recipe's faintest catalog V.
    render_options : RenderOptions, optional
    """
    return commit_frame(make_frame(plan, k, out_dir, master_seed=master_seed, formats=formats,
                                   catalog_limiting_v_mag=catalog_limiting_v_mag, render_options=render_options))


@dataclass(frozen=True, kw_only=True)
class EncodedFrame:
    """Frame ``k`` sampled, rendered and encoded, not yet written (:func:`make_frame`)."""

    frame: int
    out_dir: Path
    blobs: dict  # {format: bytes}
    truth: dict
    draws: int | None
    backends: dict
    timings_s: dict  # sample, render, encode


def frame_scene(plan, k: int, *, master_seed: int, catalog_limiting_v_mag: float, render_options=None):
    """Sample frame ``k``: ``(scene, options, seed, rng, request)``, ``rng`` the frame's stream
    after the sampler's draws (the renderer draws next from it) and ``options`` with the frame's
    own render keys. Parameters as :func:`produce_frame`."""
    if isinstance(plan, (bytes, bytearray)):
        plan = _plan_from_bytes(bytes(plan))
    options = render_options or RenderOptions()
    ss = frame_seed(master_seed, k)
    rng = np.random.default_rng(ss)
    req = plan.frame_request(k, rng)
    threshold = req.resolved_threshold_px  # a scene's own, else the recipe's render.resolved_threshold_px
    if threshold is None:
        threshold = (getattr(plan, "recipe", None) or {}).get("render", {}).get("resolved_threshold_px")
    extra = {} if threshold is None else {"resolved_threshold_px": threshold}
    scene = build_scene(req.epoch_tdb_s, position_km=req.position_km, velocity_km_s=req.velocity_km_s,
                        R_cam_icrs=req.R_cam_icrs, camera=req.camera if req.camera is not None else plan.camera,
                        angular_velocity_rad_s=req.angular_velocity_rad_s,
                        catalog_limiting_v_mag=req.catalog_limiting_v_mag if req.catalog_limiting_v_mag is not None else catalog_limiting_v_mag,
                        visibility=req.visibility if req.visibility is not None else plan.visibility,
                        sky=req.sky, **extra)
    own = {k: getattr(req, k) for k in ("cosmic_rays_per_frame", "mitsuba_spp") if getattr(req, k) is not None}
    if own:  # a scene's own render keys (scenes recipes)
        options = dataclasses.replace(options, **own)
    return scene, options, ss, rng, req


def dataset_truth(truth: dict, req, master_seed: int) -> dict:
    """A rendered frame's truth with its ``dataset`` section (the sampler's record, the seed)."""
    out = dict(truth)
    meta = {k: v for k, v in req.meta.items() if k != "data_files"}
    if "data_files" in req.meta:  # the mission files the plan read (name as written, SHA-256)
        out["data_files"] = req.meta["data_files"]
    out["dataset"] = {**meta, "master_seed": int(master_seed),
                      "seed_scheme": "numpy SeedSequence([master_seed, frame]); sampler draws, then renderer"}
    return out


def render_request(plan, k: int, *, master_seed: int, catalog_limiting_v_mag: float, render_options=None,
                   before_render=None):
    """Sample and render frame ``k`` in memory: ``(frame, draws, timings_s)``, the frame's truth with
    its ``dataset`` section; what :func:`make_frame` encodes and :func:`skynav.datasets.stream`
    hands to a training loop (so a streamed frame is the dataset's frame of the same seed and index).
    Parameters as :func:`produce_frame`; ``before_render``: as :func:`make_frame`."""
    t0 = time.perf_counter()
    scene, options, ss, rng, req = frame_scene(plan, k, master_seed=master_seed,
                                               catalog_limiting_v_mag=catalog_limiting_v_mag, render_options=render_options)
    if before_render is not None:
        before_render()
    t1 = time.perf_counter()
    frame = render(scene, seed=ss, rng=rng, options=options)
    t2 = time.perf_counter()
    frame = dataclasses.replace(frame, truth=dataset_truth(frame.truth, req, master_seed))
    return frame, req.meta.get("draws"), {"sample": t1 - t0, "render": t2 - t1}


def make_frame(plan, k: int, out_dir, *, master_seed: int, formats, catalog_limiting_v_mag: float,
               render_options=None, before_render=None) -> EncodedFrame:
    """The first half of :func:`produce_frame` (same parameters): sample, render and encode
    frame ``k`` in memory. ``before_render``: called with no argument once the scene is built,
    right before the render (:func:`_made_and_written` starts writing the frame before there)."""
    frame, draws, timings = render_request(plan, k, master_seed=master_seed, catalog_limiting_v_mag=catalog_limiting_v_mag,
                                           render_options=render_options, before_render=before_render)
    t2 = time.perf_counter()
    blobs = encode_frame(frame, tuple(formats))
    t3 = time.perf_counter()
    ran = frame.truth["render"]  # what ran, as the renderer records it
    backends = {"sensor": ran["backend_used"] if ran["noise"] else None, "mitsuba_variant": ran["mitsuba_variant"]}
    return EncodedFrame(frame=int(k), out_dir=Path(out_dir), blobs=blobs, truth=frame.truth, draws=draws,
                        backends=backends, timings_s={**timings, "encode": t3 - t2})


def commit_frame(made: EncodedFrame) -> FrameResult:
    """The second half of :func:`produce_frame`: write the frame's files (each atomically),
    their SHA-256, then the frame's checksum record, its commit point."""
    t0 = time.perf_counter()
    k, formats = made.frame, tuple(made.blobs)
    rel = layout.frame_relpaths(k, formats)
    paths = {fmt: made.out_dir / rel[fmt] for fmt in formats}
    atomic_write_many((paths[fmt], made.blobs[fmt]) for fmt in formats)  # on this (writer) thread, one folder fsync
    files = {rel[fmt]: hashlib.sha256(made.blobs[fmt]).hexdigest() for fmt in formats}  # of the bytes written
    record = write_record(made.out_dir, k, files)  # the frame's commit point: written last, atomically
    t = made.timings_s
    return FrameResult(frame=k, files=files, index_row=layout.index_row(made.truth, k, files), draws=made.draws,
                       timings_s={"sample": t["sample"], "render": t["render"],
                                  "write": t["encode"] + time.perf_counter() - t0},
                       backends=made.backends, record=record)


def check_backends(res: FrameResult, recorded: dict) -> None:
    """Refuse a frame rendered on another backend than the dataset records (one line).

    Raises
    ------
    DatasetMismatchError
        E.g. a Dask worker whose LLVM backend does not work made a frame with numpy noise.
    """
    for key, ran in res.backends.items():
        want = recorded.get(key)
        if ran is not None and want is not None and ran != want:
            raise DatasetMismatchError(
                f"frame {res.frame} ran with {key} {ran!r} but this dataset records {want!r}; "
                f"the bits would differ: give every worker the same backend (render options backend='{want}')")


def _produce_dask(ks, *, blob, out_dir, master_seed, formats, mag, options) -> list:
    """A Dask task: the consecutive frames ``ks``, made and written as in :func:`run_in_process`."""
    # A Dask worker process owns `nthreads` cores (its nanny already sets OpenBLAS/OpenMP/MKL to
    # 1); size skynav's pools to that unless the cluster's environment says otherwise.
    if "SKYNAV_THREADS" not in os.environ:
        # dask.distributed (the optional 'dask' extra) only with a Dask scheduler
        from distributed import get_worker

        os.environ["SKYNAV_THREADS"] = str(max(1, int(get_worker().state.nthreads)))
    return _produce_chunk([(blob, k, out_dir, master_seed, formats, mag, options) for k in ks])


# ----------------------------------------------------------------------------- executors
def _jobs(plan):
    """One argument tuple per frame to make; the sampler plan travels pickled once."""
    blob = pickle.dumps(plan.sampler)
    return blob, [(blob, k, plan.root, plan.master_seed, list(plan.formats), plan.catalog_limiting_v_mag, plan.render_options)
                  for k in plan.todo]


def _make_job(job, before_render=None):
    blob, k, out_dir, master_seed, formats, mag, options = job
    return make_frame(blob, k, out_dir, master_seed=master_seed, formats=formats, catalog_limiting_v_mag=mag,
                      render_options=options, before_render=before_render)


def _made_and_written(jobs, accept) -> None:
    """Make the jobs' frames in order, frame k's files written (:func:`commit_frame`) on a writer
    thread while this thread makes frame k + 1; ``accept`` sees each frame in order, after its
    record is written. A failure in either half ends the loop once the frame being written is
    complete (a frame made before a failure is written). After the first frame the collector
    leaves the warm heap alone (:class:`WarmHeap`); the frames' images come from glibc's heap even
    in a Dask worker (:class:`LargeArraysOnHeap`).

    Frame k is handed to the writer when frame k + 1's render begins, not when frame k is made:
    the writer's own Python (paths, checksums, the record) then runs while the render's Dr.Jit
    kernels hold no GIL, instead of taking turns with the sampler's Python (less CPU and wall
    clock a frame; docs/performance.md)."""
    with LargeArraysOnHeap(), WarmHeap() as heap, ThreadPoolExecutor(1, thread_name_prefix="skynav-commit") as writer:
        pending = made = None

        def start_writing():
            nonlocal pending, made
            if made is not None:
                pending, made = writer.submit(commit_frame, made), None

        try:
            for j in jobs:
                nxt = _make_job(j, before_render=start_writing)
                heap.warm()
                start_writing()  # (make_frame called it before its render; a frame is never left unwritten)
                if pending is not None:
                    done, pending = pending, None
                    accept(done.result())
                made = nxt
        except BaseException:
            start_writing()  # the frame made before the failure is still written (the writer finishes it)
            raise
        start_writing()
        if pending is not None:
            accept(pending.result())


def _produce_chunk(jobs) -> list:
    """A process-pool job: several consecutive frames, made and written as in :func:`run_in_process`."""
    out = []
    _made_and_written(jobs, out.append)
    return out


#: Consecutive frames per Dask task (fewer when there are few frames for the
#: workers): within one the writes overlap the next frame's work, and its last write does not.
POOL_CHUNK = 8


def _chunks(items: list, n_workers: int) -> list:
    """``items`` in runs of up to :data:`POOL_CHUNK`, at least four runs per worker where possible."""
    size = max(1, min(POOL_CHUNK, len(items) // (4 * n_workers)))
    return [items[i:i + size] for i in range(0, len(items), size)]


def run_in_process(plan, accept) -> tuple:
    """Make the plan's frames here, in order. Returns ``(workers, executor name)``.

    Frame k's files are written (:func:`commit_frame`) on a writer thread while this thread
    renders and encodes frame k + 1 (:func:`_made_and_written`): the writes wait on the disk
    (fsync) with the GIL released, so the wait overlaps the next frame's work even on one core.
    ``accept`` still sees every frame in order, after its record is written.
    """
    _, jobs = _jobs(plan)
    _made_and_written(jobs, accept)
    return 1, "in-process"


def cpu_jiffies():
    """``(idle, total)`` CPU time of the whole machine so far, in clock ticks of all its cores
    (Linux's ``/proc/stat``; idle includes waiting for I/O); None where it cannot be read."""
    try:
        with open("/proc/stat", "rb") as f:
            fields = [int(x) for x in f.readline().split()[1:9]]
    except (OSError, ValueError):
        return None
    return (fields[3] + fields[4], sum(fields)) if len(fields) == 8 else None


class HelpersPay:
    """Whether starting the helpers of a dataset run pays, asked before each of this process's
    frames (the ``pays`` of :func:`skynav.infra.pool.share_jobs`).

    A helper pays its own start-up before it makes a frame: the imports, the catalogue, the
    radiometry tables and the first kernels, about what this process paid for its first frame
    (``first_s``, measured here) plus ``imports_s``. It pays once the frames left would keep this
    process busy for more than ``factor`` times that start-up at its own pace (the wall-clock time
    a frame has taken it since its first): then a helper that joins after its start-up still
    takes a good share of them (a helper gains half of what is left once it has joined, so it
    pays from ``factor`` = 1; the margin covers a start-up longer than this estimate). And only
    where a core is idle for it: on a machine whose cores are busy with other work, a helper's
    start-up and frames would be taken from this process's share of them. The idle cores are
    the machine's idle CPU time over at least ``window_s`` since the last look (``jiffies``,
    :func:`cpu_jiffies`; where it cannot be read, a core is taken to be idle). On a small
    dataset, or a busy machine, no helper is started and ``--workers N`` runs as ``--workers 1``.
    """

    def __init__(self, *, imports_s: float = 1.0, factor: float = 1.5, idle_cores: float = 0.5,
                 window_s: float = 0.5, jiffies=cpu_jiffies):
        self.imports_s, self.factor, self.idle_cores, self.window_s, self.jiffies = (
            imports_s, factor, idle_cores, window_s, jiffies)
        self.first_s = None
        self.mark = None  # (seconds, jiffies) where the machine was last looked at

    def __call__(self, made: int, left: int, seconds: float) -> bool:
        if made == 0:
            return False
        if self.first_s is None:
            self.first_s, self.mark = seconds, (seconds, self.jiffies())
        if made < 3:  # the pace of two frames after the first
            return False
        pace = (seconds - self.first_s) / (made - 1)
        if left * pace <= self.factor * (self.first_s + self.imports_s):
            return False
        return self.a_core_is_idle(seconds)

    def a_core_is_idle(self, seconds: float) -> bool:
        """Whether the machine had ``idle_cores`` idle since the last look (at least ``window_s``
        ago; sooner, not yet known: False)."""
        then_s, then = self.mark
        if then is None:
            return True
        if seconds - then_s < self.window_s:
            return False
        now = self.jiffies()
        self.mark = (seconds, now)
        if now is None or now[1] <= then[1]:
            return True
        return (now[0] - then[0]) / (now[1] - then[1]) * (os.cpu_count() or 1) >= self.idle_cores


def run_process_pool(plan, accept, n_workers: int) -> tuple:
    """Make the plan's frames in this process and up to ``n_workers - 1`` spawned helpers.
    Returns ``(workers, executor name)``.

    The processes share the frames (:func:`skynav.infra.pool.share_jobs`): each takes the next
    frame nobody has taken when it is ready for one and makes its frames with their writes
    overlapped, as :func:`run_in_process` does. This process starts at once; the helpers are
    started once the frames left are worth their start-up (:class:`HelpersPay`), each joins once
    it has imported the renderer and loaded its tables, and one that finds no frame left is
    stopped, so no number of workers makes a dataset slower than one worker. The plan travels
    pickled once per helper; ``accept`` sees each frame once its record is written."""
    _, jobs = _jobs(plan)
    share_jobs(_made_and_written, jobs, n_workers, accept, pays=HelpersPay())
    return n_workers, "processes (spawn)"


def run_dask(plan, accept, client) -> tuple:
    """Make the plan's frames as Dask tasks on ``client``, each up to :data:`POOL_CHUNK`
    consecutive frames with their writes overlapped (as :func:`run_process_pool`). Returns
    ``(workers, executor name)``."""
    # dask.distributed (the optional 'dask' extra) only with a Dask scheduler
    from distributed import as_completed

    n_workers = max(1, sum(w.get("nthreads", 1) for w in client.scheduler_info().get("workers", {}).values()))
    if plan.todo:
        blob = pickle.dumps(plan.sampler)
        blob_f = client.scatter(blob, broadcast=True)
        futs = client.map(_produce_dask, [tuple(c) for c in _chunks(list(plan.todo), n_workers)], blob=blob_f,
                          out_dir=plan.root, master_seed=plan.master_seed, formats=list(plan.formats),
                          mag=plan.catalog_limiting_v_mag, options=plan.render_options, pure=False)
        for fut in as_completed(futs):
            for res in fut.result():
                accept(res)
    return n_workers, "dask"
