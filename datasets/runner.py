"""Dataset generation: plan, execute, finalise; crash-safe, resumable, any executor.

Driver module. :func:`generate` is the one entry point (the ``skynav dataset generate``
sub-command calls it). It runs three steps:

1. **plan** (:func:`plan_run`, here): validate the recipe, build the recipe kind's sampler plan
   and camera, resolve the render options and the backends that will run, refuse a folder that
   holds another dataset (recipe, seed, version, render options or backends differ), and find
   the frames already complete; the result is a :class:`~skynav.datasets.plan.RunPlan`.
2. **execute** (:mod:`skynav.datasets.execute`): the same per-frame function
   (:func:`~skynav.datasets.execute.produce_frame`) in this process, in a local spawned process
   pool, or as Dask tasks. Frame k depends on the plan and ``SeedSequence([master_seed, k])``
   alone, so the bytes are the same whatever the executor (docs/conventions.md "Randomness").
3. **finalise** (:mod:`skynav.datasets.finalise`): ``index.csv``, checksums, and the manifest
   marked complete.

Crash safety
------------
Every file is written atomically (temp + fsync + rename, :mod:`skynav.datasets.frame_files`). The
manifest is written first with ``"complete": false``, rewritten every ``flush_every_s`` with the
checksums of the frames done, and says ``"complete": true`` only after every frame, the index and
the side files are written and checksummed. A re-run on the same folder (same recipe, seed,
package version, render options and resolved backends; anything else is refused) renders only the
frames that are missing. Each frame's checksums are recorded with the frame: a worker writes
``frames/NNNNNN.sha256`` after the frame's files (:mod:`skynav.datasets.journal`). A resume keeps
a frame only when that record exists, every file's SHA-256 matches it (and the manifest, where it
recorded the file) and every file decodes (PNG, EXR, JSON); any other frame is made again, so a
truncated or corrupted file is never kept.
"""

from __future__ import annotations

import dataclasses
import math
import os
import time
from dataclasses import dataclass, field
from pathlib import Path

from tqdm.auto import tqdm

from skynav.infra.atomic_files import atomic_write_bytes
from skynav.renderer import jit_backend
from skynav.renderer.render import RenderOptions, sensor_backend

from . import execute, layout
from .errors import DatasetError, RecipeError
from .execute import FrameResult, check_backends, produce_frame
from .finalise import Progress, base_manifest, finalise, write_checkpoint
from .frame_files import check_output_dir
from .journal import frame_problem
from .lock import dataset_lock
from .plan import RunPlan
from .recipe_checks import RECIPE_RENDER_OPTIONS, validate_recipe
from .recipes import recipe_camera
from .samplers import make_plan
from .truth_schema import read_truth_json

__all__ = ["FrameResult", "GenerateSummary", "produce_frame", "plan_run", "resolve_backends", "generate",
           "regenerate_frame"]


@dataclass(frozen=True, kw_only=True)
class GenerateSummary:
    """Outcome of :func:`generate`.

    Attributes
    ----------
    path : str
        The dataset folder.
    frames_total : int
        Frames of the dataset.
    frames_rendered, frames_reused : int
        Frames made by this run, and frames kept from an earlier run (resumed).
    draws : int or None
        Scenes drawn by the sampler to find the frames (None where the kind draws none).
    elapsed_s : float
        Wall time of the run, s.
    frames_per_s : float
        Frames made per second of wall time.
    workers : int
        Worker processes (1: in this process).
    executor : str
        ``in-process``, a local process pool, or Dask.
    mean_timings_s : dict
        Mean time per frame of each step (``sample``, ``render``, ``write``), s.

    Examples
    --------
    >>> import tempfile
    >>> from skynav.datasets import generate, preset_recipe
    >>> from skynav.renderer import RenderOptions
    >>> recipe = preset_recipe("montecarlo")
    >>> recipe.update(frames=2, camera={"preset": "paper", "width": 64, "height": 64, "fov_deg": 20})
    >>> tmp = tempfile.TemporaryDirectory()
    >>> summary = generate(recipe, tmp.name + "/ds", workers=1, progress=False,
    ...                    render_options=RenderOptions(backend="numpy"))
    >>> summary.frames_total, summary.frames_rendered, summary.frames_reused, summary.executor
    (2, 2, 0, 'in-process')
    >>> summary.lines()[0].endswith("(2 rendered, 0 already present)")
    True
    >>> tmp.cleanup()
    """

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
        """Printable summary lines (counts, rate, mean step times in ms)."""
        t = ", ".join(f"{k} {v * 1e3:.0f} ms" for k, v in self.mean_timings_s.items())
        out = [f"dataset {self.path}: {self.frames_total} frames complete "
               f"({self.frames_rendered} rendered, {self.frames_reused} already present)",
               f"{self.elapsed_s:.1f} s, {self.frames_per_s:.2f} frames/s on {self.workers} worker(s) ({self.executor})"]
        if t:
            out.append(f"mean per frame: {t}")
        if self.draws is not None:
            out.append(f"scenes drawn {self.draws}, kept {self.frames_total}")
        return out


# ----------------------------------------------------------------------------- plan
def _frame_present(root: Path, k: int, formats, recorded: dict):
    """``(files, record)`` if frame k can be kept, else None.

    Kept means: its checksum record exists (:mod:`skynav.datasets.journal`), every file matches
    the record and the manifest (where it recorded the file), and every file decodes (PNG, EXR,
    JSON). Anything else (interrupted, truncated, altered) is made again.
    """
    problem, files, record = frame_problem(root, k, formats, recorded=recorded)
    return None if problem is not None else (files, record)


def _existing_row(root: Path, k: int, files: dict, backends: dict):
    """``(index row, draws)`` of a present frame, or None if its truth shows another backend ran.

    A frame whose files were written but not yet checksummed in the manifest (a worker finished
    it as the run stopped) is kept only if its truth names no other sensor backend or Mitsuba
    variant than ``backends``.
    """
    truth = read_truth_json(root / layout.frame_relpaths(k, ["json"])["json"])
    sensor = (truth.get("render") or {}).get("backend_used")
    if sensor in ("llvm", "cuda", "numpy") and backends.get("sensor") not in (None, sensor):
        return None
    variants = {b.get("mitsuba_variant") for b in truth.get("bodies") or [] if b.get("mitsuba_variant")}
    if variants and variants != {backends.get("mitsuba_variant")}:
        return None
    return layout.index_row(truth, k, files), (truth.get("dataset") or {}).get("draws")


def _remove_frame(root, res) -> None:
    """Delete the files a refused frame wrote, so that a resume renders it again."""
    for rel in list(res.record) + list(res.files):  # the record first: the frame is no longer committed
        try:
            os.unlink(Path(root) / rel)
        except FileNotFoundError:
            pass


def resolve_backends(render_options) -> dict:
    """The sensor backend and the Mitsuba variant that ``render_options`` run with on this machine.

    ``"auto"`` is resolved as the renderer resolves it (:mod:`skynav.renderer.jit_backend`):
    sensor ``"llvm"``, ``"cuda"`` or ``"numpy"``; Mitsuba ``"cuda_ad_spectral"``, ``"llvm_ad_spectral"`` or
    ``"scalar_spectral"`` (None when ``render_options.resolved`` is False: nothing is ray-traced).
    """
    variant = jit_backend.select_mitsuba_variant()[0] if render_options.resolved else None
    return {"sensor": sensor_backend(render_options.backend), "mitsuba_variant": variant}


def connect_dask(address: str, *, timeout_s: float = 10.0):
    """A ``distributed.Client`` on ``address``; one line naming it if it cannot be reached.

    Raises
    ------
    DatasetError
        No scheduler answers at ``address`` within ``timeout_s`` (or the address is malformed),
        or ``distributed`` is not installed.
    """
    try:
        # dask.distributed (the optional 'dask' extra) only with a Dask scheduler
        from distributed import Client
    except ImportError:
        raise DatasetError(f"--dask-scheduler {address}: the 'distributed' package is not installed") from None
    try:
        return Client(address, timeout=f"{timeout_s}s")
    except (OSError, TimeoutError, ValueError, TypeError) as exc:
        raise DatasetError(f"--dask-scheduler {address}: no Dask scheduler reachable there within {timeout_s:g} s "
                           f"({exc.__class__.__name__}); check the address (tcp://HOST:8786)") from None


def make_folder(root) -> Path:
    """Create the dataset folder and its ``frames/``; one line naming the path otherwise.

    Raises
    ------
    DatasetError
        The path is a file, lies under a file, is not writable, or is in a system folder.
    """
    root = Path(root)
    check_output_dir(root, what="dataset folder")
    try:
        (root / layout.FRAMES_DIR).mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise DatasetError(f"{root}: cannot create the dataset folder ({exc.strerror or exc.__class__.__name__})") from None
    if not os.access(root / layout.FRAMES_DIR, os.W_OK | os.X_OK):
        raise DatasetError(f"{root}: the dataset folder is not writable")
    return root


def recipe_render_options(recipe: dict, options):
    """``options`` with the fields the recipe's ``render:`` mapping sets (``cosmic_rays_per_frame``,
    ``mitsuba_spp``) replaced: the recipe's keys win over the ``render_options`` argument, and the
    manifest records the result."""
    given = {k: v for k, v in (recipe.get("render") or {}).items() if k in RECIPE_RENDER_OPTIONS}
    return dataclasses.replace(options, **given) if given else options


def plan_run(recipe, out_dir, *, render_options=None, ephemeris=None, max_frames: int | None = None) -> RunPlan:
    """The *plan* step of :func:`generate`: what to make, with what, and what is there already.

    Creates the folder, refuses one that holds another dataset, removes stale temp files, writes
    the side files and the starting manifest (``"complete": false``, the checksums of the frames
    already present).

    Raises
    ------
    RecipeError, DatasetMismatchError, DatasetError
    """
    recipe = validate_recipe(recipe)
    options = recipe_render_options(recipe, render_options if render_options is not None else RenderOptions())
    root = Path(out_dir)
    make_folder(root)
    camera = recipe_camera(recipe)
    sampler = make_plan(recipe, ephemeris=ephemeris)
    manifest = base_manifest(recipe, sampler, camera, options, resolve_backends(options))
    recorded = {}
    if (root / layout.MANIFEST_NAME).exists():
        old = layout.read_manifest(root)
        layout.check_same_dataset(old, manifest, root)
        recorded = dict(old.get("files", {}))
    layout.clean_stale_temp_files(root)
    formats = list(recipe["formats"])

    # side files (deterministic) first
    side = sampler.side_files() if hasattr(sampler, "side_files") else {}
    for name, data in side.items():
        atomic_write_bytes(root / name, data)

    # what is there already
    present, rows, draws, todo = {}, {}, {}, []
    for k in range(sampler.n_frames):
        found = _frame_present(root, k, formats, recorded)
        existing = None if found is None else _existing_row(root, k, found[0], manifest["backends"])
        if existing is None:
            todo.append(k)
        else:
            present[k] = {**found[0], **found[1]}
            rows[k], draws[k] = existing
    if max_frames is not None:
        todo = todo[:max_frames]
    write_checkpoint(root, manifest, {rel: sha for f in present.values() for rel, sha in f.items()}, len(rows))
    return RunPlan(root=str(root), recipe=recipe, sampler=sampler, camera=camera, formats=tuple(formats),
                   master_seed=int(recipe["seed"]), catalog_limiting_v_mag=float(recipe["catalog_limiting_v_mag"]),
                   render_options=options, backends=manifest["backends"], manifest=manifest, present=present,
                   present_rows=rows, present_draws=draws, todo=tuple(todo), side_files=side)


def _make_progress(progress, total: int, initial: int):
    """(update(n), close()) for a tqdm bar, a callback ``progress(done, total)``, or nothing."""
    if progress is True:
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
        Address of a Dask scheduler; or pass ``client``.
    client : distributed.Client, optional
        A Dask client to run the frames on (not closed here).
    progress : bool or callable
        True: a tqdm bar with rate and ETA; a callable ``progress(done, total)``; False: silent.
    render_options : skynav.renderer.render.RenderOptions, optional
        Recorded in the manifest; a resume must pass the same. The recipe's ``render:`` keys
        (``cosmic_rays_per_frame``, ``mitsuba_spp``) replace the fields of the same name.
    flush_every_s : float
        Interval between manifest checkpoints while running, s.
    ephemeris : skynav.scenes.ephemeris_jpl.Ephemeris, optional
        The ephemeris of the in-process planning (default: DE421, ``default_ephemeris()``).
    max_frames : int, optional
        Stop after rendering this many new frames (the manifest stays incomplete; for tests and
        for splitting a long campaign into sessions).

    Returns
    -------
    GenerateSummary
        What was made, reused, and how fast.

    Raises
    ------
    RecipeError, DatasetMismatchError, DatasetError
        ``DatasetLockedError`` (a ``DatasetError``) when another generator is running on the
        folder (:mod:`skynav.datasets.lock`).

    Examples
    --------
    Two 64 x 64 px frames, then the same call again: a complete dataset is not made twice.

    >>> import tempfile
    >>> from skynav.datasets import generate, preset_recipe
    >>> from skynav.renderer import RenderOptions
    >>> recipe = preset_recipe("montecarlo")
    >>> recipe.update(frames=2, camera={"preset": "paper", "width": 64, "height": 64, "fov_deg": 20})
    >>> tmp = tempfile.TemporaryDirectory()
    >>> summary = generate(recipe, tmp.name + "/ds", workers=1, progress=False,
    ...                    render_options=RenderOptions(backend="numpy"))
    >>> summary.frames_rendered
    2
    >>> again = generate(recipe, tmp.name + "/ds", workers=1, progress=False,
    ...                  render_options=RenderOptions(backend="numpy"))
    >>> again.frames_rendered, again.frames_reused
    (0, 2)
    >>> tmp.cleanup()
    """
    t_start = time.perf_counter()
    use_dask = client is not None or dask_scheduler is not None
    if not use_dask:
        n_workers = int(workers) if workers is not None else (os.cpu_count() or 1)
        if n_workers < 1:
            raise RecipeError("workers", workers, "an integer >= 1")

    recipe = validate_recipe(recipe)  # a bad recipe is refused before anything is created
    make_folder(out_dir)
    own_client = None
    if use_dask and client is None:  # an unreachable scheduler is named before any work
        client = own_client = connect_dask(dask_scheduler)
    try:
        with dataset_lock(out_dir):
            return _generate_locked(recipe, out_dir, use_dask=use_dask, n_workers=None if use_dask else n_workers,
                                    client=client, progress=progress, render_options=render_options,
                                    flush_every_s=flush_every_s, ephemeris=ephemeris, max_frames=max_frames,
                                    t_start=t_start)
    finally:
        if own_client is not None:
            own_client.close()


def _generate_locked(recipe, out_dir, *, use_dask, n_workers, client, progress, render_options,
                     flush_every_s, ephemeris, max_frames, t_start) -> GenerateSummary:
    """:func:`generate` once the folder's lock is held."""
    plan = plan_run(recipe, out_dir, render_options=render_options, ephemeris=ephemeris, max_frames=max_frames)
    n = plan.n_frames
    reused = len(plan.present)
    update, close = _make_progress(progress, n, reused)

    def check(res):
        try:
            check_backends(res, plan.backends)
        except Exception:
            _remove_frame(plan.root, res)
            raise

    done = Progress(plan, flush_every_s=flush_every_s, update=update, check=check)
    try:
        if use_dask:
            n_workers, executor = execute.run_dask(plan, done.accept, client)
        elif n_workers == 1 or len(plan.todo) <= 1:
            n_workers, executor = execute.run_in_process(plan, done.accept)
        else:
            n_workers, executor = execute.run_process_pool(plan, done.accept, n_workers)
    finally:
        close()
        if not done.complete:
            done.checkpoint()

    if done.complete:
        finalise(plan, done)
    rendered = len(plan.todo)
    elapsed = time.perf_counter() - t_start
    mean = {k: v / rendered for k, v in done.timings.items()} if rendered else {}
    return GenerateSummary(path=plan.root, frames_total=n, frames_rendered=rendered, frames_reused=reused,
                           draws=done.total_draws(), elapsed_s=elapsed,
                           frames_per_s=rendered / elapsed if elapsed > 0 else math.nan,
                           workers=n_workers, executor=executor, mean_timings_s=mean)


def regenerate_frame(path, k: int, out_dir, *, render_options=None):
    """Re-make frame ``k`` of an existing dataset alone into ``out_dir`` (for checks and repairs).

    Parameters
    ----------
    path : str or os.PathLike
        The dataset folder (its manifest holds the recipe and seed).
    k : int
        Frame index.
    out_dir : str or os.PathLike
        Folder to write into (``frames/NNNNNN.*`` under it; created).
    render_options : skynav.renderer.render.RenderOptions, optional
        Default: the ones the manifest records.

    Returns
    -------
    FrameResult
        The frame's files and checksums; they equal the manifest's when the package, recipe,
        seed and backends are the same (frame k draws from ``SeedSequence([seed, k])`` alone).

    Examples
    --------
    >>> import tempfile
    >>> from skynav.datasets import generate, preset_recipe
    >>> from skynav.renderer import RenderOptions
    >>> recipe = preset_recipe("montecarlo")
    >>> recipe.update(frames=2, camera={"preset": "paper", "width": 64, "height": 64, "fov_deg": 20})
    >>> tmp = tempfile.TemporaryDirectory()
    >>> summary = generate(recipe, tmp.name + "/ds", workers=1, progress=False,
    ...                    render_options=RenderOptions(backend="numpy"))
    >>> from pathlib import Path
    >>> from skynav.datasets import regenerate_frame
    >>> _ = regenerate_frame(tmp.name + "/ds", 1, tmp.name + "/again")
    >>> a = Path(tmp.name, "ds", "frames", "000001.png").read_bytes()
    >>> a == Path(tmp.name, "again", "frames", "000001.png").read_bytes()
    True
    >>> tmp.cleanup()
    """
    m = layout.read_manifest(path)
    recipe = m["recipe"]
    if render_options is None and isinstance(m.get("render_options"), dict):
        render_options = RenderOptions(**m["render_options"])
    plan = make_plan(recipe)
    (Path(out_dir) / layout.FRAMES_DIR).mkdir(parents=True, exist_ok=True)
    return produce_frame(plan, k, out_dir, master_seed=int(recipe["seed"]), formats=recipe["formats"],
                         catalog_limiting_v_mag=float(recipe["catalog_limiting_v_mag"]), render_options=render_options)
