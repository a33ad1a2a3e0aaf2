"""Dataset generation: frames spread over local processes or a Dask cluster; crash-safe, resumable.

Driver module. :func:`generate` is the one entry point (the ``skynav dataset generate``
sub-command calls it). Frame k is made by :func:`produce_frame` from the plan and frame k's
seed ``SeedSequence([master_seed, k])`` alone, so a frame's files are the same bytes whatever the
number of workers, the executor, or the order in which frames ran (CONVENTIONS.md "Randomness").

Executors
---------
- ``workers=1``: in this process.
- ``workers=N`` (default: all cores): :class:`concurrent.futures.ProcessPoolExecutor` with the
  **spawn** start method. Dr.Jit/LLVM (the sensor kernel, Mitsuba) start threads and JIT state in
  a process; a fork of a parent that already used them inherits locked mutexes and a half-copied
  JIT (the classic fork-after-threads hazard), so children are spawned fresh and import skynav
  themselves. The plan travels pickled. Each worker gets ``cores // N`` threads for the
  libraries that start thread pools (Dr.Jit and OpenEXR via ``SKYNAV_THREADS``, OpenBLAS/OpenMP/MKL via
  their ``*_NUM_THREADS``; a variable the user set is left alone): N processes each with a pool as
  wide as the machine spin against each other (measured: 2 workers on 2 cores went from 1.0x to
  1.6x the 1-worker rate with this alone; ``benchmarks/dataset_bench.py``).
- ``dask_scheduler="tcp://host:8786"`` or ``client=distributed.Client(...)``: one Dask task per
  frame (``pure=False``); the workers must see ``out_dir`` on a shared file system.

Crash safety
------------
Every file is written atomically (temp + fsync + rename, :mod:`skynav.datasets.frame_files`). The
manifest is written first with ``"complete": false``, rewritten every ``flush_every_s`` with the
checksums of the frames done, and says ``"complete": true`` only after every frame, the index and
the side files are written and checksummed. A re-run on the same folder (same recipe, seed and
package version; anything else is refused) renders only the frames that are missing: a frame is
present when all its files exist and, where the manifest recorded them, their SHA-256 match.
"""

from __future__ import annotations

import dataclasses
import math
import os
import pickle
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import layout
from .errors import DatasetError
from .recipes import recipe_camera, validate_recipe

__all__ = ["FrameResult", "GenerateSummary", "produce_frame", "generate", "regenerate_frame"]


@dataclass(frozen=True, kw_only=True)
class FrameResult:
    """What a worker reports for one frame."""

    frame: int
    files: dict                  # {relpath: sha256}
    index_row: dict
    draws: int | None
    timings_s: dict              # sample, render, write


@dataclass(frozen=True, kw_only=True)
class GenerateSummary:
    """Outcome of :func:`generate`."""

    path: str
    frames_total: int
    frames_rendered: int
    frames_reused: int
    draws: int | None
    elapsed_s: float
    frames_per_s: float
    workers: int
    executor: str
    mean_timings_s: dict = field(default_factory=dict)

    def lines(self) -> list:
        """Printable summary lines."""
        t = ", ".join(f"{k} {v * 1e3:.0f} ms" for k, v in self.mean_timings_s.items())
        out = [f"dataset {self.path}: {self.frames_total} frames complete "
               f"({self.frames_rendered} rendered, {self.frames_reused} already present)",
               f"{self.elapsed_s:.1f} s, {self.frames_per_s:.2f} frames/s on {self.workers} worker(s) ({self.executor})"]
        if t:
            out.append(f"mean per frame: {t}")
        if self.draws is not None:
            out.append(f"scenes drawn {self.draws}, kept {self.frames_total}")
        return out


# ----------------------------------------------------------------------------- worker side
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
    first (:mod:`skynav.datasets.samplers`), then the renderer.
    """
    from skynav.renderer.render import RenderOptions, render

    from .frame_files import sha256_file, write_frame
    from skynav.scenes.scene import build_scene

    from .samplers import frame_seed

    if isinstance(plan, (bytes, bytearray)):
        plan = _plan_from_bytes(bytes(plan))
    out = Path(out_dir)
    t0 = time.perf_counter()
    ss = frame_seed(master_seed, k)
    rng = np.random.default_rng(ss)
    req = plan.frame_request(k, rng)
    scene = build_scene(req.epoch_tdb_s, position_km=req.position_km, velocity_km_s=req.velocity_km_s,
                        R_cam_icrs=req.R_cam_icrs, camera=plan.camera,
                        angular_velocity_rad_s=req.angular_velocity_rad_s, catalog_limiting_v_mag=catalog_limiting_v_mag,
                        visibility=plan.visibility, sky=req.sky)
    t1 = time.perf_counter()
    frame = render(scene, seed=ss, rng=rng, options=render_options or RenderOptions())
    t2 = time.perf_counter()
    truth = dict(frame.truth)
    truth["dataset"] = {**req.meta, "master_seed": int(master_seed),
                        "seed_scheme": "numpy SeedSequence([master_seed, frame]); sampler draws, then renderer"}
    frame = dataclasses.replace(frame, truth=truth)
    stem = layout.frame_stem(k)
    paths = write_frame(frame, out / layout.FRAMES_DIR, stem, formats=tuple(formats))
    rel = layout.frame_relpaths(k, formats)
    files = {rel[fmt]: sha256_file(paths[fmt]) for fmt in formats}
    t3 = time.perf_counter()
    return FrameResult(frame=int(k), files=files, index_row=layout.index_row(truth, k, files),
                       draws=req.meta.get("draws"), timings_s={"sample": t1 - t0, "render": t2 - t1, "write": t3 - t2})


def _produce_job(job):
    blob, k, out_dir, master_seed, formats, mag, options = job
    return produce_frame(blob, k, out_dir, master_seed=master_seed, formats=formats, catalog_limiting_v_mag=mag,
                         render_options=options)


def _produce_dask(k, *, blob, out_dir, master_seed, formats, mag, options):
    # A Dask worker process owns `nthreads` cores (its nanny already sets OpenBLAS/OpenMP/MKL to
    # 1); size skynav's pools to that unless the cluster's environment says otherwise.
    if "SKYNAV_THREADS" not in os.environ:
        from distributed import get_worker

        os.environ["SKYNAV_THREADS"] = str(max(1, int(get_worker().state.nthreads)))
    return produce_frame(blob, k, out_dir, master_seed=master_seed, formats=formats, catalog_limiting_v_mag=mag,
                         render_options=options)


# ----------------------------------------------------------------------------- driver side
_THREAD_VARS = ("SKYNAV_THREADS", "OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


class _worker_threads:
    """Context: thread-count variables the spawned workers inherit (``cores // workers`` each).

    Spawned children read their environment when they start (inside the ``with`` block, when the
    pool submits); the parent's environment is restored on exit. Variables already set by the
    user are kept.
    """

    def __init__(self, n_workers: int):
        self.threads = max(1, (os.cpu_count() or 1) // max(1, n_workers))
        self.set_here: list = []

    def __enter__(self):
        self.set_here = [name for name in _THREAD_VARS if name not in os.environ]
        for name in self.set_here:
            os.environ[name] = str(self.threads)
        return self

    def __exit__(self, *exc):
        for name in self.set_here:
            os.environ.pop(name, None)
        return False


def _frame_present(root: Path, k: int, formats, recorded: dict):
    """``{relpath: sha}`` if frame k is fully present (and matches recorded checksums), else None."""
    from .frame_files import sha256_file

    files = {}
    for rel in layout.frame_relpaths(k, formats).values():
        p = root / rel
        if not p.is_file():
            return None
        sha = sha256_file(p)
        if rel in recorded and recorded[rel] != sha:
            return None
        files[rel] = sha
    return files


def _existing_row(root: Path, k: int, files: dict) -> tuple:
    from .truth_schema import read_truth_json

    truth = read_truth_json(root / layout.frame_relpaths(k, ["json"])["json"])
    return layout.index_row(truth, k, files), (truth.get("dataset") or {}).get("draws")


def _base_manifest(recipe: dict, plan, camera) -> dict:
    n = plan.n_frames
    return {
        "schema": layout.MANIFEST_SCHEMA,
        "complete": False,
        "package": "skynav",
        "version": layout.package_version(),
        "recipe": recipe,
        "master_seed": int(recipe["seed"]),
        "seed_scheme": "frame k: numpy.random.default_rng(SeedSequence([master_seed, k])); sampler draws, then renderer",
        "camera": camera.to_dict(),
        "formats": list(recipe["formats"]),
        "layout": {"frames": "frames/NNNNNN.{" + ",".join(recipe["formats"]) + "}", "index": layout.INDEX_NAME},
        "plan": plan.describe(),
        "counts": {"frames": n, "frames_done": 0},
        "files": {},
    }


def _make_progress(progress, total: int, initial: int):
    """(update(n), close()) for a tqdm bar, a callback ``progress(done, total)``, or nothing."""
    if progress is True:
        from tqdm.auto import tqdm

        bar = tqdm(total=total, initial=initial, unit="frame", desc="frames", smoothing=0.1)
        return bar.update, bar.close
    if callable(progress):
        state = {"done": initial}

        def update(n=1):
            state["done"] += n
            progress(state["done"], total)

        progress(initial, total)
        return update, lambda: None
    return (lambda n=1: None), (lambda: None)


def generate(recipe, out_dir, *, workers: int | None = None, dask_scheduler: str | None = None, client=None,
             progress=True, render_options=None, flush_every_s: float = 5.0, ephemeris=None,
             max_frames: int | None = None) -> GenerateSummary:
    """Generate (or resume) a dataset folder from a recipe.

    Parameters
    ----------
    recipe : dict
        A recipe mapping (validated here; see :mod:`skynav.datasets.recipes`).
    out_dir : str or os.PathLike
        Dataset folder (created; an existing folder of the same dataset is resumed).
    workers : int, optional
        Local worker processes (default ``os.cpu_count()``); 1 runs in this process.
    dask_scheduler : str, optional
        Address of a Dask scheduler; or pass ``client`` (a ``distributed.Client``).
    progress : bool or callable
        True: a tqdm bar with rate and ETA; a callable ``progress(done, total)``; False: silent.
    render_options : skynav.renderer.render.RenderOptions, optional
    flush_every_s : float
        Interval between manifest checkpoints while running.
    max_frames : int, optional
        Stop after rendering this many new frames (the manifest stays incomplete; for tests and
        for splitting a long campaign into sessions).

    Returns
    -------
    GenerateSummary

    Raises
    ------
    RecipeError, DatasetMismatchError, DatasetError
    """
    from .frame_files import atomic_write_bytes, sha256_file
    from .samplers import make_plan

    t_start = time.perf_counter()
    recipe = validate_recipe(recipe)
    root = Path(out_dir)
    try:
        (root / layout.FRAMES_DIR).mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise DatasetError(f"{root}: cannot create the dataset folder ({exc.strerror})") from None
    camera = recipe_camera(recipe)
    plan = make_plan(recipe, ephemeris=ephemeris)
    manifest = _base_manifest(recipe, plan, camera)
    recorded = {}
    if (root / layout.MANIFEST_NAME).exists():
        old = layout.read_manifest(root)
        layout.check_same_dataset(old, manifest, root)
        recorded = dict(old.get("files", {}))
    layout.clean_stale_temp_files(root)
    formats = list(recipe["formats"])
    n = plan.n_frames

    # side files (deterministic) first
    side = plan.side_files() if hasattr(plan, "side_files") else {}
    for name, data in side.items():
        atomic_write_bytes(root / name, data)

    # what is there already
    files: dict = {}
    rows: dict = {}
    draws: dict = {}
    todo = []
    for k in range(n):
        present = _frame_present(root, k, formats, recorded)
        if present is None:
            todo.append(k)
        else:
            files.update(present)
            rows[k], draws[k] = _existing_row(root, k, present)
    reused = n - len(todo)
    if max_frames is not None:
        todo = todo[:max_frames]
    manifest["counts"]["frames_done"] = len(rows)
    manifest["files"] = dict(files)
    layout.write_manifest(root, manifest)

    blob = pickle.dumps(plan)
    mag = float(recipe["catalog_limiting_v_mag"])
    seed = int(recipe["seed"])
    jobs = [(blob, k, str(root), seed, formats, mag, render_options) for k in todo]
    timings = {"sample": 0.0, "render": 0.0, "write": 0.0}
    update, close = _make_progress(progress, n, reused)
    last_flush = [time.perf_counter()]

    def accept(res: FrameResult):
        files.update(res.files)
        rows[res.frame] = res.index_row
        draws[res.frame] = res.draws
        for key, v in res.timings_s.items():
            timings[key] = timings.get(key, 0.0) + v
        update(1)
        if time.perf_counter() - last_flush[0] > flush_every_s:
            manifest["counts"]["frames_done"] = len(rows)
            manifest["files"] = dict(files)
            layout.write_manifest(root, manifest)
            last_flush[0] = time.perf_counter()

    n_workers = 1
    executor = "in-process"
    own_client = None
    try:
        if client is not None or dask_scheduler is not None:
            from distributed import Client, as_completed

            if client is None:
                client = own_client = Client(dask_scheduler)
            n_workers = max(1, sum(w.get("nthreads", 1) for w in client.scheduler_info().get("workers", {}).values()))
            executor = "dask"
            if jobs:
                blob_f = client.scatter(blob, broadcast=True)
                futs = client.map(_produce_dask, [j[1] for j in jobs], blob=blob_f, out_dir=str(root),
                                  master_seed=seed, formats=formats, mag=mag, options=render_options, pure=False)
                for fut in as_completed(futs):
                    accept(fut.result())
        else:
            n_workers = int(workers) if workers is not None else (os.cpu_count() or 1)
            if n_workers < 1:
                from .errors import RecipeError

                raise RecipeError("workers", workers, "an integer >= 1")
            if n_workers == 1 or len(jobs) <= 1:
                n_workers = 1
                for j in jobs:
                    accept(_produce_job(j))
            else:
                import multiprocessing
                from concurrent.futures import ProcessPoolExecutor, as_completed as cf_completed

                executor = "processes (spawn)"
                with _worker_threads(n_workers), \
                        ProcessPoolExecutor(max_workers=n_workers, mp_context=multiprocessing.get_context("spawn")) as ex:
                    futs = [ex.submit(_produce_job, j) for j in jobs]
                    try:
                        for fut in cf_completed(futs):
                            accept(fut.result())
                    except BaseException:
                        for f in futs:
                            f.cancel()
                        raise
    finally:
        close()
        if own_client is not None:
            own_client.close()
        manifest["counts"]["frames_done"] = len(rows)
        manifest["files"] = dict(files)
        if len(rows) < n:
            layout.write_manifest(root, manifest)

    rendered = len(jobs)
    if len(rows) == n:
        atomic_write_bytes(root / layout.INDEX_NAME, layout.index_csv_bytes(rows.values()))
        files[layout.INDEX_NAME] = sha256_file(root / layout.INDEX_NAME)
        for name in side:
            files[name] = sha256_file(root / name)
        counts = {"frames": n, "frames_done": n}
        if recipe["kind"] == "montecarlo":
            counts["scenes_drawn"] = int(sum(d for d in draws.values() if d))
            counts["scenes_kept"] = n
        manifest["counts"] = counts
        manifest["files"] = dict(files)
        manifest["complete"] = True
        layout.write_manifest(root, manifest)
    elapsed = time.perf_counter() - t_start
    mean = {k: v / rendered for k, v in timings.items()} if rendered else {}
    total_draws = int(sum(d for d in draws.values() if d)) if recipe["kind"] == "montecarlo" else None
    return GenerateSummary(path=str(root), frames_total=n, frames_rendered=rendered, frames_reused=reused,
                           draws=total_draws, elapsed_s=elapsed, frames_per_s=rendered / elapsed if elapsed > 0 else math.nan,
                           workers=n_workers, executor=executor, mean_timings_s=mean)


def regenerate_frame(path, k: int, out_dir, *, render_options=None):
    """Re-make frame ``k`` of an existing dataset alone into ``out_dir`` (for checks and repairs).

    Returns the :class:`FrameResult`; its checksums equal the manifest's when the package,
    recipe and seed are the same.
    """
    from .samplers import make_plan

    m = layout.read_manifest(path)
    recipe = m["recipe"]
    plan = make_plan(recipe)
    (Path(out_dir) / layout.FRAMES_DIR).mkdir(parents=True, exist_ok=True)
    return produce_frame(plan, k, out_dir, master_seed=int(recipe["seed"]), formats=recipe["formats"],
                         catalog_limiting_v_mag=float(recipe["catalog_limiting_v_mag"]), render_options=render_options)
