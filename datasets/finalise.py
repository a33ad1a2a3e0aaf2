"""The manifest's life through a run: started, checkpointed, completed (the *finalise* step).

Driver module. :func:`base_manifest` is what a run writes first (``"complete": false``);
:class:`Progress` gathers the frames' results and checkpoints the manifest every
``flush_every_s`` with the checksums of the frames done; :func:`finalise` writes ``index.csv``,
checksums it and the side files, and rewrites the manifest with ``"complete": true``, only once
every frame is there. Every write is atomic, so a folder whose manifest says complete is complete.

The manifest holds nothing that depends on how or when the dataset was made (no dates, hosts,
worker counts), so the same recipe gives the same bytes with any executor.
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

from skynav.infra.atomic_files import atomic_write_bytes, sha256_file

from . import frame_files, layout
from .plan import SEED_SCHEME

__all__ = ["base_manifest", "Progress", "write_checkpoint", "finalise"]


def base_manifest(recipe: dict, sampler, camera, render_options, backends: dict) -> dict:
    """The manifest of a run before any frame is done (``"complete": false``).

    Parameters
    ----------
    recipe : dict
        Validated recipe.
    sampler : SamplerPlan
    camera : Camera
        The recipe's camera.
    render_options : RenderOptions
        Recorded as ``render_options`` (``dataclasses.asdict``).
    backends : dict
        ``{"sensor": ..., "mitsuba_variant": ...}`` as resolved on this machine; recorded as
        ``backends``.
    """
    return {
        "schema": layout.MANIFEST_SCHEMA,
        "complete": False,
        "package": "skynav",
        "version": layout.package_version(),
        "recipe": recipe,
        "master_seed": int(recipe["seed"]),
        "seed_scheme": SEED_SCHEME,
        "camera": camera.to_dict(),
        "render_options": dataclasses.asdict(render_options),
        "backends": dict(backends),
        "formats": list(recipe["formats"]),
        # how frames/NNNNNN.png store the DN (datasets.frame_files.write_png; docs/conventions.md)
        "png_scaling": frame_files.PNG_SCALING,
        "layout": {"frames": "frames/NNNNNN.{" + ",".join(recipe["formats"]) + "}", "index": layout.INDEX_NAME},
        "plan": sampler.describe(),
        "counts": {"frames": sampler.n_frames, "frames_done": 0},
        "files": {},
    }


def write_checkpoint(root, manifest: dict, files: dict, frames_done: int) -> None:
    """Rewrite the (incomplete) manifest with the checksums of the frames done."""
    manifest["counts"]["frames_done"] = int(frames_done)
    manifest["files"] = dict(files)
    layout.write_manifest(root, manifest)


class Progress:
    """The frames' results as they arrive; checkpoints the manifest every ``flush_every_s``.

    Starts from the frames already present (``plan.present*``). :meth:`accept` is the executors'
    callback; ``check`` (if given) is called on each result first and may raise.
    """

    def __init__(self, plan, *, flush_every_s: float, update=None, check=None):
        self.plan = plan
        self.files: dict = {}
        for f in plan.present.values():
            self.files.update(f)
        self.rows: dict = dict(plan.present_rows)
        self.draws: dict = dict(plan.present_draws)
        self.timings = {"sample": 0.0, "render": 0.0, "write": 0.0}
        self.rendered = 0
        self.flush_every_s = float(flush_every_s)
        self._update = update or (lambda n=1: None)
        self._check = check
        self._last_flush = time.perf_counter()

    def accept(self, res) -> None:
        """Take one :class:`~skynav.datasets.execute.FrameResult`."""
        if self._check is not None:
            self._check(res)
        self.files.update(res.files)
        self.files.update(res.record)
        self.rows[res.frame] = res.index_row
        self.draws[res.frame] = res.draws
        for key, v in res.timings_s.items():
            self.timings[key] = self.timings.get(key, 0.0) + v
        self.rendered += 1
        self._update(1)
        if time.perf_counter() - self._last_flush > self.flush_every_s:
            self.checkpoint()
            self._last_flush = time.perf_counter()

    def checkpoint(self) -> None:
        """Write the manifest with what is done (still incomplete)."""
        write_checkpoint(self.plan.root, self.plan.manifest, self.files, len(self.rows))

    @property
    def complete(self) -> bool:
        return len(self.rows) == self.plan.n_frames

    def total_draws(self) -> int | None:
        """Monte Carlo draws of every frame done (None for the other kinds)."""
        if self.plan.recipe["kind"] != "montecarlo":
            return None
        return int(sum(d for d in self.draws.values() if d))


def finalise(plan, progress: Progress) -> None:
    """Write ``index.csv``, checksum it and the side files, and mark the manifest complete.

    Call only when every frame is done (``progress.complete``).
    """
    root = Path(plan.root)
    n = plan.n_frames
    files = dict(progress.files)
    atomic_write_bytes(root / layout.INDEX_NAME, layout.index_csv_bytes(progress.rows.values()))
    files[layout.INDEX_NAME] = sha256_file(root / layout.INDEX_NAME)
    for name in plan.side_files:
        files[name] = sha256_file(root / name)
    counts = {"frames": n, "frames_done": n}
    if plan.recipe["kind"] == "montecarlo":
        counts["scenes_drawn"] = progress.total_draws()
        counts["scenes_kept"] = n
    manifest = plan.manifest
    manifest["counts"] = counts
    manifest["files"] = files
    manifest["complete"] = True
    layout.write_manifest(root, manifest)
