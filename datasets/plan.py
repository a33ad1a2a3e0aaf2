"""The plan vocabulary shared by the samplers, the sequences and the runner.

Core module (imports the scene model only). A recipe kind's *sampler plan* (``MonteCarloPlan``,
``ScenesPlan`` in :mod:`skynav.datasets.samplers`, ``SequencePlan`` in
:mod:`skynav.datasets.sequence`) follows :class:`SamplerPlan`: it is computed once from a
validated recipe and answers ``frame_request(k, rng)`` with a :class:`FrameRequest`. Frame k's
random stream is :func:`frame_rng` (``SeedSequence([master_seed, k])``, docs/conventions.md
"Randomness"). :class:`RunPlan` is what a ``generate`` run resolved before it renders anything
(the recipe, the options, the backends, the frames to make, the files already there); the
executors (:mod:`skynav.datasets.execute`) and the finalising step
(:mod:`skynav.datasets.finalise`) read it.

The samplers and the sequences import this module and not each other's, so the two form no
import cycle.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from skynav.scenes.timescales import time_from_tdb_seconds

__all__ = ["SEED_SCHEME", "FrameRequest", "SamplerPlan", "RunPlan", "frame_seed", "frame_rng", "epoch_iso"]

SEED_SCHEME = "frame k: numpy.random.default_rng(SeedSequence([master_seed, k])); sampler draws, then renderer"
"""How frame k's random stream is made, as recorded in the manifest."""


def frame_seed(master_seed: int, k: int) -> np.random.SeedSequence:
    """The seed sequence of frame k: ``SeedSequence([master_seed, k])`` (docs/conventions.md).

    Examples
    --------
    >>> frame_seed(7, 3).entropy
    [7, 3]
    """
    return np.random.SeedSequence([int(master_seed), int(k)])


def frame_rng(master_seed: int, k: int) -> np.random.Generator:
    """Frame k's generator, ``default_rng(SeedSequence([master_seed, k]))``."""
    return np.random.default_rng(frame_seed(master_seed, k))


def epoch_iso(t_tdb_s: float) -> str:
    """ISO date (TDB) of TDB seconds past J2000, millisecond precision, for tables.

    Examples
    --------
    >>> epoch_iso(0.0)
    '2000-01-01T12:00:00.000'
    """
    return time_from_tdb_seconds(t_tdb_s).tdb.isot


@dataclass(frozen=True, kw_only=True, eq=False)
class FrameRequest:
    """What one frame looks at, before the sky is computed.

    Attributes
    ----------
    epoch_tdb_s : float
        Mid-exposure, TDB s past J2000.
    position_km, velocity_km_s : ndarray, shape (3,)
        Barycentric ICRS observer state.
    R_cam_icrs : ndarray, shape (3, 3)
    angular_velocity_rad_s : ndarray, shape (3,)
        Camera frame.
    meta : dict
        Recorded in the ground truth under ``"dataset"`` and in ``index.csv``
        (``draws``, ``leg``, ``phase``, ``target``...).
    sky : object or None
        ``sky_bodies(...)`` already computed for this epoch/observer (reused by ``build_scene``).
    camera : Camera or None
        This frame's camera when it is not the plan's (a ``scenes`` recipe's per-scene
        ``camera``); None: the plan's.
    catalog_limiting_v_mag : float or None
        This frame's faintest catalog V when it is not the recipe's (per-scene
        ``render.catalog_limiting_v_mag``); None: the recipe's.
    resolved_threshold_px : float or None
        This frame's resolved-body threshold (per-scene ``render.resolved_threshold_px``);
        None: the scene model's default.
    visibility : VisibilityCriteria or None
        This frame's visibility rule (per-scene ``visibility``); None: the plan's.
    cosmic_rays_per_frame : float or None
        This frame's cosmic-ray rate (per-scene ``render.cosmic_rays_per_frame``); None: the
        dataset's render options.
    mitsuba_spp : int or None
        This frame's Mitsuba samples per pixel (per-scene ``render.mitsuba_spp``); None: the
        dataset's render options.
    """

    epoch_tdb_s: float
    position_km: np.ndarray
    velocity_km_s: np.ndarray
    R_cam_icrs: np.ndarray
    angular_velocity_rad_s: np.ndarray = field(default_factory=lambda: np.zeros(3))
    meta: dict = field(default_factory=dict)
    sky: object = None
    camera: object = None
    catalog_limiting_v_mag: float | None = None
    resolved_threshold_px: float | None = None
    visibility: object = None
    cosmic_rays_per_frame: float | None = None
    mitsuba_spp: int | None = None


class SamplerPlan(Protocol):
    """What the runner needs of a recipe kind's plan (``make_plan(recipe)``)."""

    kind: str
    camera: object
    n_frames: int

    def frame_request(self, k: int, rng: np.random.Generator) -> FrameRequest:
        """Frame k, drawn from frame k's stream (documented order)."""

    def describe(self) -> dict:
        """Plan summary for the manifest (JSON types)."""


@dataclass(frozen=True, kw_only=True, eq=False)
class RunPlan:
    """Everything a ``generate`` run resolved before rendering (the *plan* step).

    Attributes
    ----------
    root : str
        The dataset folder.
    recipe : dict
        The validated (normalised) recipe.
    sampler : SamplerPlan
        The recipe kind's plan.
    camera : Camera
        The recipe's camera.
    formats : tuple of str
    master_seed : int
    catalog_limiting_v_mag : float
    render_options : RenderOptions
        What every frame is rendered with (recorded in the manifest).
    backends : dict
        ``{"sensor": ..., "mitsuba_variant": ...}`` resolved on this machine (recorded).
    manifest : dict
        The manifest as written at the start (``"complete": false``); the steps update it.
    present : dict
        ``{frame: {relpath: sha256}}`` of the frames already complete in the folder.
    present_rows : dict
        ``{frame: index row}`` of those frames.
    present_draws : dict
        ``{frame: draws or None}`` of those frames.
    todo : tuple of int
        The frames this run renders, in order.
    side_files : dict
        ``{name: bytes}`` written beside the frames (sequences: trajectory, legs).
    """

    root: str
    recipe: dict
    sampler: object
    camera: object
    formats: tuple
    master_seed: int
    catalog_limiting_v_mag: float
    render_options: object
    backends: dict
    manifest: dict
    present: dict
    present_rows: dict
    present_draws: dict
    todo: tuple
    side_files: dict

    @property
    def n_frames(self) -> int:
        """Frames in the whole dataset."""
        return int(self.sampler.n_frames)
